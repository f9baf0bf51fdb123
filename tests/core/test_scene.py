"""Scene-file validation: good files round-trip, bad ones name the offending field."""

import json

import numpy as np
import pytest

from vtkillum.core.scene import Scene, load_scene, save_scene

GOOD = {
    "transfer_function": {"scalars": [0.0, 0.5, 1.0], "opacity": [0.0, 0.3, 0.9],
                          "colors": [[1, 1, 1], [1, 0.8, 0.6], [1, 1, 1]]},
    "opacity_unit_distance": 1.0,
    "albedo": 0.9,
    "anisotropy": 0.0,
    "lights": [
        {"type": "directional", "direction": [0, -1, 0], "irradiance": [1, 1, 1]},
        {"type": "point", "position": [0, 0, 0], "intensity": [10, 10, 10]},
    ],
    "camera": {"position": [0, 0, 5], "focal_point": [0, 0, 0], "view_up": [0, 1, 0],
               "view_angle": 30},
    "background": [0, 0, 0],
}


def test_design_example_loads_and_round_trips(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(GOOD))
    scene = load_scene(p)
    assert scene.lights[1].kind == 1 and np.allclose(scene.lights[1].intensity, 10)
    assert np.allclose(scene.lights[0].direction, [0, -1, 0])
    save_scene(scene, tmp_path / "again.json")
    again = load_scene(tmp_path / "again.json")
    assert again.to_dict() == scene.to_dict()


def test_defaults_when_fields_are_missing():
    scene = Scene.from_dict({})
    assert scene.albedo == 0.9 and scene.anisotropy == 0.0 and len(scene.lights) == 1
    assert scene.options["path"]["spp"] == 64


def test_parallel_camera():
    d = dict(GOOD, camera={"position": [0, 0, 5], "focal_point": [0, 0, 0],
                           "view_up": [0, 1, 0], "parallel_scale": 2.0})
    cam = Scene.from_dict(d).camera
    assert cam.parallel_projection and cam.parallel_scale == 2.0


@pytest.mark.parametrize("patch, field", [
    ({"albedo": 1.5}, "albedo"),
    ({"albedo": "high"}, "albedo"),
    ({"anisotropy": 1.0}, "anisotropy"),
    ({"opacity_unit_distance": 0}, "opacity_unit_distance"),
    ({"colour": [1, 1, 1]}, "colour"),
    ({"background": [0, 0]}, "background"),
    ({"lights": []}, "lights"),
    ({"lights": [{"type": "spot"}]}, "lights[0].type"),
    ({"lights": [{"type": "point", "intensity": [1, 1, 1]}]}, "lights[0]"),
    ({"lights": [{"type": "directional", "direction": [0, 0, 0]}]}, "lights[0]"),
    ({"lights": [{"type": "directional", "direction": [0, 0, 1], "power": 3}]}, "lights[0]"),
    ({"camera": {"position": [0, 0, 0], "focal_point": [0, 0, 0]}}, "camera"),
    ({"camera": {"position": [0, 0, 1], "view_angle": 30, "parallel_scale": 1}}, "camera"),
    ({"transfer_function": {"scalars": [1, 0], "opacity": [0, 1]}}, "transfer_function.scalars"),
    ({"transfer_function": {"scalars": [0, 1], "opacity": [0]}}, "transfer_function.opacity"),
    ({"transfer_function": {"scalars": [0, 1], "opacity": [0, 2]}}, "transfer_function.opacity"),
    ({"transfer_function": {"scalars": [0, 1], "opacity": [0, 1], "colors": [[1, 1, 1]]}},
     "transfer_function.colors"),
    ({"path": {"spp": "many"}}, "path.spp"),
    ({"path": {"bounces": 3}}, "path"),
    ({"shading": {"diffuse": True}}, "shading.diffuse"),
    # issue 15 row 10: strings where numbers belong ("albedo": "0.5" was refused, these were not)
    ({"transfer_function": {"scalars": ["0", "1"], "opacity": [0, 1]}},
     "transfer_function.scalars"),
    ({"transfer_function": {"scalars": [0, 1], "opacity": [0, "0.5"]}},
     "transfer_function.opacity"),
    ({"background": ["0", 0, 0]}, "background"),
    ({"lights": [{"type": "point", "position": [0, "1", 0]}]}, "lights[0].position"),
    ({"lights": [{"type": "directional", "direction": [0, 0, 1], "irradiance": "1"}]},
     "lights[0].irradiance"),
    ({"camera": {"position": [0, 0, "5"], "focal_point": [0, 0, 0], "view_up": [0, 1, 0]}},
     "camera.position"),
    ({"camera": {"position": [0, 0, 5], "focal_point": [0, 0, 0], "view_up": [0, 1, 0],
                 "view_angle": "30"}}, "camera.view_angle"),
    # issue 15 row 10: ranges of the shading and method sections, checked at load
    ({"shading": {"ambient": -1}}, "shading.ambient"),
    ({"shading": {"shininess": 0}}, "shading.shininess"),
    ({"path": {"spp": 0}}, "path.spp"),
    ({"path": {"spp": 2.5}}, "path.spp"),
    ({"path": {"max_bounces": -1}}, "path.max_bounces"),
    ({"convection_diffusion": {"scattering": [1, -1, 0]}}, "convection_diffusion.scattering"),
    ({"convection_diffusion": {"scattering": [1, "1", 0]}}, "convection_diffusion.scattering"),
    ({"convection_diffusion": {"iterations": -2}}, "convection_diffusion.iterations"),
    ({"convection_diffusion": {"tolerance": 0}}, "convection_diffusion.tolerance"),
    ({"convection_diffusion": {"source_radius": -1}}, "convection_diffusion.source_radius"),
    ({"ambient_scattering": {"radius": 0}}, "ambient_scattering.radius"),
    ({"ambient_scattering": {"radius_units": "miles"}}, "ambient_scattering.radius_units"),
    ({"ambient_scattering": {"radiance_cache_scale": 1.5}},
     "ambient_scattering.radiance_cache_scale"),
    ({"ambient_scattering": {"specular": -0.1}}, "ambient_scattering.specular"),
    ({"ambient_scattering": {"ambient_occlusion_strength": -1}},
     "ambient_scattering.ambient_occlusion_strength"),
])
def test_bad_fields_are_named(tmp_path, patch, field):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(dict(GOOD, **patch)))
    with pytest.raises(ValueError) as err:
        load_scene(p)
    assert field in str(err.value) and str(p) in str(err.value)


def test_not_json(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_scene(p)


def test_binary_file_is_named(tmp_path):
    """Issue 15 row 10: a bare UTF-8 decode error without the file's name."""
    p = tmp_path / "scene.json"
    p.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    with pytest.raises(ValueError, match=r"scene\.json: not a JSON scene file \(binary data"):
        load_scene(p)


def test_the_checked_ranges_accept_every_default():
    from vtkillum.core.scene import METHOD_OPTIONS, OPTION_CHECKS, SHADING_DEFAULTS

    sections = dict(METHOD_OPTIONS, shading=SHADING_DEFAULTS)
    for (section, key), (check, _) in OPTION_CHECKS.items():
        if key in sections.get(section, {}):
            assert check(sections[section][key]), (section, key)
    scene = Scene.from_dict({"path": {"spp": 4.0, "seed": -3}, "shading": {"specular": 0}})
    assert scene.options["path"]["spp"] == 4.0
