"""World units (issue 33): the same scene in any length unit gives the same image.

A scene scaled by ``s`` (spacing, origin, opacity unit distance, camera, point-light
positions; point intensities by ``s²``) must render like the original with every
method: render() maps it into canonical units (vtkillum/core/units.py). Before this,
many-lights gave 579 non-finite pixels at spacing 1e12 and did not finish at 3e18,
photon lost 45 % of the image at 1e15, convection-diffusion gained 3.2x at 1e20 and path
refused spacings from 1e17 on.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtkillum.core.camera import Camera
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.many_lights.render import ManyLightsRenderer
from vtkillum.core.pathtrace import PathTracer
from vtkillum.core.render import METHODS, render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.units import SPACING_RANGE, WorldUnits, canonical
from vtkillum.core.volume import Volume

N = 12
WIDTH, HEIGHT = 14, 10
SPACING = np.array([1.0, 1.15, 0.85])
ORIGIN = np.array([-3.0, 2.0, 1.0])
#: Scales every method is checked at (the acceptance range of issue 33, and cgs astrophysics).
SCALES = (1e-12, 1e12, 1e20)
#: Cheap settings for the slow methods (the same at every scale).
OPTIONS = {"path": {"spp": 2, "seed": 3}, "photon": {"photons": 4000},
           "many-lights": {"count": 16, "avsm_resolution": 8, "sets": 1}}
#: Relative tolerance (max |difference| / max): deterministic methods differ by float32
#: rounding of the scaled inputs; Monte Carlo methods with the same seed by a decision
#: that rounding flips now and then (measured <= 1.4e-4).
TOLERANCE = {"path": 2e-3, "photon": 2e-3, "many-lights": 2e-3}


def field() -> np.ndarray:
    x = np.linspace(-1.0, 1.0, N)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return (np.exp(-((X + 0.15) ** 2 + Y ** 2 + (Z - 0.1) ** 2) / 0.3)
            + 0.8 * np.exp(-((X - 0.5) ** 2 + (Y - 0.4) ** 2 + (Z + 0.3) ** 2) / 0.06))


def centre() -> np.ndarray:
    return ORIGIN + 0.5 * (N - 1) * SPACING


def scaled_scene(s: float, light: str = "directional", camera: str = "outside"):
    """The test scene with every length times ``s`` and point intensities times ``s²``."""
    volume = Volume(field(), spacing=SPACING * s, origin=ORIGIN * s)
    tf = TransferFunction([0.0, 0.15, 0.45, 0.75, 1.0], [0.0, 0.0, 0.3, 0.5, 0.7],
                          [[0.1, 0.2, 1.0], [0.1, 0.2, 1.0], [0.2, 1.0, 0.4],
                           [1.0, 0.8, 0.1], [1.0, 0.1, 0.1]])
    c = centre()
    if camera == "outside":
        cam = Camera((c + [-10, -7, 25]) * s, c * s, (0, 1, 0), 30.0)
    else:  # inside, parallel projection
        cam = Camera(c * s, (c + [0, 0, -1]) * s, (0, 1, 0), 30.0, True, 3.0 * s)
    if light == "directional":
        lights = [DirectionalLight((1.0, -1.0, -1.0), (2.0, 2.0, 2.0))]
    else:
        lights = [PointLight((c + [8.0, 8.0, 8.0]) * s, np.full(3, 200.0) * s * s)]
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0 * s, lights=lights,
                  camera=cam)
    return volume, scene


def relative_difference(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-30))


def render_at(method, s, light, **kwargs):
    volume, scene = scaled_scene(s, light)
    options = dict(OPTIONS.get(method, {}), **kwargs)
    if method == "illumination":  # a uniform scattered fluence and full transmittance
        options["illumination"] = IlluminationVolume.for_volume(
            volume, np.full((6, 6, 6, 3), 0.5, np.float32), np.ones((1, 6, 6, 6), np.float32))
    return render(volume, scene, method, WIDTH, HEIGHT, "cpu", **options)


# --- the mapping ------------------------------------------------------------------------------
def test_canonical_length_is_the_power_of_two_nearest_the_mean_spacing():
    for mean, length in ((1.0, 1.0), (0.75, 1.0), (1.4, 1.0), (0.7, 0.5), (1.5, 2.0),
                         (1e12, 2.0**40), (3e-7, 2.0**-22)):
        volume = Volume(np.zeros((2, 2, 2)), spacing=(mean,) * 3)
        assert WorldUnits.for_volume(volume).length == length
    far = Volume(np.zeros((2, 2, 2)), origin=(1e9, 0.0, 0.0))
    assert WorldUnits.for_volume(far).origin == (1e9, 0.0, 0.0)  # beyond 2^24 voxels


def test_unit_scene_passes_through_untouched_and_the_mapping_is_idempotent():
    volume, scene = scaled_scene(1.0, "point")
    v, sc, opts, units = canonical(volume, scene, {"step_size": 0.3})
    assert units.is_identity and v is volume and sc is scene and opts["step_size"] == 0.3
    volume, scene = scaled_scene(1e18, "point")
    v, sc, opts, units = canonical(volume, scene, {"step_size": 0.3e18})
    assert units.length == 2.0**60 and not units.is_identity
    again = canonical(v, sc, opts)
    assert again[3].is_identity and again[0] is v and again[1] is sc
    # Lengths divide by L, point intensities by L², directional irradiance stays.
    assert sc.opacity_unit_distance == pytest.approx(1e18 / 2.0**60, rel=1e-15)
    assert opts["step_size"] == pytest.approx(0.3e18 / 2.0**60, rel=1e-15)
    np.testing.assert_allclose(sc.lights[0].intensity, 200.0 * 1e36 / 2.0**120, rtol=1e-15)
    np.testing.assert_allclose(sc.camera.position, scene.camera.position / 2.0**60, rtol=1e-15)
    # The canonical volume is kept with the volume (its caches survive re-renders).
    assert canonical(volume, scene)[0] is v


# --- every method, directional and point light ------------------------------------------------
@pytest.mark.parametrize("light", ["directional", "point"])
@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_gives_the_same_image_at_every_scale(method, light):
    if method == "refraction" and light == "point":
        pytest.skip("refraction takes one directional light only")
    if method == "illumination" and light == "point":
        pytest.skip("the illumination volume is the same for either light")
    reference = render_at(method, 1.0, light)
    assert np.all(np.isfinite(reference.radiance)) and reference.radiance.max() > 0
    tol = TOLERANCE.get(method, 1e-4)
    for s in SCALES:
        result = render_at(method, s, light)
        assert np.all(np.isfinite(result.radiance)), (method, s)
        d = relative_difference(result.radiance, reference.radiance)
        assert d < tol, (method, light, s, d)
        assert relative_difference(result.alpha, reference.alpha) < tol, (method, s)
        assert result.info["world_units"]["length"] == WorldUnits.for_volume(
            scaled_scene(s)[0]).length


@pytest.mark.parametrize("s", [1e-12, 1e18])
def test_progressive_renderers_follow_the_world_camera(s):
    """PathTracer and ManyLightsRenderer (CLI, interactive windows) work in canonical units
    too; a camera given to reset() is in world units."""
    ref_volume, ref_scene = scaled_scene(1.0, "point")
    volume, scene = scaled_scene(s, "point")
    moved = Camera(scene.camera.position * 1.1, scene.camera.focal_point, (0, 1, 0), 30.0)
    ref_moved = Camera(ref_scene.camera.position * 1.1, ref_scene.camera.focal_point,
                       (0, 1, 0), 30.0)
    a = PathTracer(volume, scene, WIDTH, HEIGHT, "cpu", seed=4).reset(moved).run(2).result()
    b = PathTracer(ref_volume, ref_scene, WIDTH, HEIGHT, "cpu", seed=4).reset(ref_moved) \
        .run(2).result()
    assert relative_difference(a.radiance, b.radiance) < 2e-3
    ml = ManyLightsRenderer(volume, scene, WIDTH, HEIGHT, "cpu", count=16, avsm_resolution=8)
    ref = ManyLightsRenderer(ref_volume, ref_scene, WIDTH, HEIGHT, "cpu", count=16,
                             avsm_resolution=8)
    for r, cam in ((ml, moved), (ref, ref_moved)):
        r.run(1)
        r.reset(cam).run(1)
    assert ml.camera is moved  # kept in world units
    assert relative_difference(ml.result().radiance, ref.result().radiance) < 2e-3


def test_the_probe_cases_finish_and_are_finite():
    """The issue's cases: many-lights at spacing 3e18 (did not finish in 900 s) and 1e12
    (non-finite pixels), path at 1e17 (refused), photon at 1e15 (0.55x)."""
    ref = {m: render_at(m, 1.0, "directional").radiance for m in ("many-lights", "path",
                                                                  "photon")}
    for method, s in (("many-lights", 3e18), ("many-lights", 1e12), ("path", 1e17),
                      ("photon", 1e15)):
        img = render_at(method, s, "directional").radiance
        assert np.all(np.isfinite(img))
        assert relative_difference(img, ref[method]) < 2e-3, (method, s)


# --- what cannot be represented is refused before anything runs --------------------------------
def test_unrepresentable_scales_are_refused_before_the_render_starts():
    calls = []
    for s in (SPACING_RANGE[0] / 10, SPACING_RANGE[1] * 10):
        volume = Volume(field(), spacing=SPACING * s)
        scene = Scene(lights=[DirectionalLight((0, 0, -1))])
        with pytest.raises(ValueError, match="cannot be represented.*another length unit"):
            render(volume, scene, "single", 8, 8, "cpu", progress=calls.append)
    assert calls == []


def test_a_point_light_too_far_for_the_volume_is_refused_with_the_reason():
    """A light 1e20 voxels away cannot be rendered in float32 (and is a directional light);
    the same light next to a volume of spacing 1e18 is fine."""
    calls = []
    volume, scene = scaled_scene(1.0)
    scene.lights = [PointLight((1e20, 0.0, 0.0), (1.0, 1.0, 1.0))]
    for method in ("single", "many-lights", "path"):
        with pytest.raises(ValueError, match="directional light"):
            render(volume, scene, method, 8, 8, "cpu", progress=calls.append)
    assert calls == []
    volume, scene = scaled_scene(1e18)
    scene.lights = [PointLight(centre() * 1e18 + [1e20, 0.0, 0.0], (1e40,) * 3)]
    assert np.all(np.isfinite(render(volume, scene, "single", 8, 8, "cpu").radiance))


def test_errors_about_lengths_say_what_a_canonical_unit_is():
    volume, scene = scaled_scene(1e12)
    with pytest.raises(ValueError, match=r"canonical units of 1\.09951e\+12 world units"):
        render(volume, scene, "single", 8, 8, "cpu", step_size=1e-3)  # too many samples


# --- property: any scale ----------------------------------------------------------------------
_REFERENCES: dict = {}


@settings(max_examples=10, deadline=None, derandomize=True, database=None)
@given(exponent=st.integers(-20, 21), mantissa=st.floats(1.0, 9.99),
       method=st.sampled_from(["emission", "single"]),
       light=st.sampled_from(["directional", "point"]),
       camera=st.sampled_from(["outside", "inside"]))
def test_a_scaled_world_renders_the_same_image(exponent, mantissa, method, light, camera):
    """Any factor from 1e-20 to 1e22, perspective from outside or parallel from inside."""
    key = (method, light, camera)
    if key not in _REFERENCES:
        volume, scene = scaled_scene(1.0, light, camera)
        _REFERENCES[key] = render(volume, scene, method, WIDTH, HEIGHT, "cpu").radiance
    volume, scene = scaled_scene(mantissa * 10.0**exponent, light, camera)
    img = render(volume, scene, method, WIDTH, HEIGHT, "cpu").radiance
    assert relative_difference(img, _REFERENCES[key]) < 1e-4
