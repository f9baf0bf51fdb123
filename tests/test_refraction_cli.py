"""``vtkillum render --method refraction``: scene files with refractive optics, the glass."""

from __future__ import annotations

import json

import numpy as np

from vtkillum.cli import main
from vtkillum.core.scene import load_scene, save_scene
from vtkillum.data.procedural import glass_preset, stemmed_glass


def glass_scene_file(tmp_path, preset="beer"):
    scene, _ = glass_preset(stemmed_glass(24), preset)
    path = tmp_path / f"{preset}.json"
    save_scene(scene, path)
    return path


def test_render_the_glass_from_the_cli(tmp_path, capsys):
    scene = glass_scene_file(tmp_path)
    d = json.loads(scene.read_text())
    assert "refractive_index" in d["transfer_function"]  # the scene file carries the optics
    assert load_scene(scene).optics is not None
    outputs = {}
    for name, path in (("refracting", scene), ("plain", glass_scene_file(tmp_path, "medium"))):
        out = tmp_path / f"{name}.npz"
        assert main(["render", "builtin:glass:24", "--scene", str(path), "--method", "refraction",
                     "--size", "16", "16", "-q", "--option", "softness=0.2",
                     "--output", str(out)]) == 0
        with np.load(out) as f:
            outputs[name] = f["radiance"]
    assert outputs["refracting"].shape == (16, 16, 3) and outputs["refracting"].max() > 0
    assert np.abs(outputs["refracting"] - outputs["plain"]).max() > 0.01  # the optics count
    # The built-in dataset's own scene refracts too (no --scene).
    assert main(["render", "builtin:glass:24", "--method", "refraction", "--size", "12", "12",
                 "-q", "--output", str(tmp_path / "default.png")]) == 0


def test_cli_reports_the_light_limit(tmp_path, capsys):
    scene = glass_scene_file(tmp_path)
    d = json.loads(scene.read_text())
    d["lights"] = [{"type": "point", "position": [0, -2, 1]}]
    scene.write_text(json.dumps(d))
    status = main(["render", "builtin:glass:24", "--scene", str(scene), "--method", "refraction",
                   "--size", "8", "8", "-q", "--output", str(tmp_path / "x.png")])
    assert status != 0
    assert "directional" in capsys.readouterr().err
