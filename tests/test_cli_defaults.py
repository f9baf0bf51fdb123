"""Issue 34: one set of defaults for ``vtkillum render`` and ``grid.illum.render``.

The same data, transfer function and method give the same picture from the shell and
from Python: the data-aware camera (medical data from the front), the key light, the
automatic exposure and the image size (256² on a CPU, 512² with CUDA) come from one
place, :mod:`vtkillum.core.defaults`. A camera inside the data warns, in one line.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")

import vtkillum.pyvista_accessor  # noqa: F401,E402  (registers grid.illum)
from vtkillum.cli import main, write_volume  # noqa: E402
from vtkillum.core.defaults import camera_inside_warning, default_camera, default_image_size  # noqa: E402
from vtkillum.core.tonemap import read_png  # noqa: E402
from vtkillum.core.transfer_function import TransferFunction  # noqa: E402
from vtkillum.data.builtin import load_builtin  # noqa: E402
from vtkillum.io.convert import image_data_from_volume  # noqa: E402
from vtkillum.io.readers import read_volume  # noqa: E402

#: A transfer function given to both (the CLI's own default comes from the histogram,
#: the accessor's from cmap/opacity: the defaults compared here are the rest).
TF = TransferFunction([0.1, 0.3, 0.5, 0.9], [0.0, 0.1, 0.3, 0.9],
                      [[1, 1, 1], [1, 0.8, 0.6], [1, 0.9, 0.8], [1, 1, 1]])
UNIT = 4.0


def _scene_file(tmp_path, **extra):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"transfer_function": TF.to_dict(),
                                "opacity_unit_distance": UNIT, **extra}))
    return path


def _grid(path):
    """The file as the accessor gets it: through vtkillum's reader (LPS for NIfTI)."""
    return pv.wrap(image_data_from_volume(read_volume(path)))


@pytest.mark.parametrize("name, frame", [("ct.vti", None), ("ct.nii.gz", "LPS")])
def test_cli_and_accessor_write_the_same_png(tmp_path, capsys, name, frame):
    """Same data, transfer function and method, nothing else given: the same PNG."""
    data = tmp_path / name
    write_volume(load_builtin("builtin:ct:24"), data, frame="RAS")
    cli_png, py_png = tmp_path / "cli.png", tmp_path / "py.png"
    assert main(["render", str(data), "--scene", str(_scene_file(tmp_path)), "--size", "40",
                 "32", "--device", "cpu", "-q", "-o", str(cli_png)]) == 0
    assert main(["render", str(data), "--scene", str(_scene_file(tmp_path)), "--size", "40",
                 "32", "--device", "cpu", "-q", "-o", str(tmp_path / "cli.npz")]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the default camera is outside: no warning
        result = _grid(data).illum.render("single", transfer_function=TF,
                                          opacity_unit_distance=UNIT, width=40, height=32,
                                          device="cpu", frame=frame, filename=py_png)
    with np.load(tmp_path / "cli.npz") as f:
        np.testing.assert_allclose(result.radiance, f["radiance"], rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(result.alpha, f["alpha"], rtol=1e-5, atol=1e-7)
    assert cli_png.read_bytes() == py_png.read_bytes()
    rgb = read_png(py_png)
    assert np.percentile(rgb, 99) > 200  # exposed automatically, not dim


def test_medical_data_seen_from_the_front_in_both(tmp_path):
    """NIfTI (LPS) from the CLI and ``frame="LPS"`` from Python: the anterior view, the
    data-aware default camera of :func:`default_camera`."""
    data = tmp_path / "ct.nii.gz"
    write_volume(load_builtin("builtin:ct:24"), data, frame="RAS")
    volume = read_volume(data)
    camera = default_camera(volume, "LPS")
    right, up, forward = camera.basis()
    np.testing.assert_allclose(forward, [0, 1, 0], atol=1e-9)  # looking posterior
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)
    from vtkillum.cli import load_input

    _, scene = load_input(str(data))
    np.testing.assert_allclose(scene.camera.position, camera.position)


def test_default_image_size(tmp_path, capsys, monkeypatch):
    assert default_image_size("cpu") == (256, 256)
    assert default_image_size("cuda") == default_image_size("cuda:1") == (512, 512)
    out = tmp_path / "e.npy"
    assert main(["render", "builtin:ct:16", "-m", "emission", "--device", "cpu", "-q",
                 "-o", str(out)]) == 0
    assert np.load(out).shape == (256, 256, 3)
    grid = pv.wrap(image_data_from_volume(load_builtin("builtin:ct:16")))
    result = grid.illum.render("emission", transfer_function=TF, device="cpu")
    assert result.radiance.shape == (256, 256, 3)
    assert grid.illum.render("emission", transfer_function=TF, device="cpu",
                             width=20).radiance.shape == (20, 20, 3)  # one side: a square
    with pytest.raises(ValueError, match="height must be a positive integer"):
        grid.illum.render("emission", transfer_function=TF, device="cpu", width=8, height=0)
    # with CUDA the default doubles (the size is picked after the device)
    from vtkillum import cli

    monkeypatch.setattr("vtkillum.core.device.resolve_device", lambda device=None: "cuda:0")
    seen = {}

    def stop(args, *rest, **kwargs):
        seen["size"] = (args, rest)
        raise cli.UserError("stopped before rendering")

    monkeypatch.setattr(cli, "check_memory", lambda method, w, h, *a, **k: stop((w, h)))
    assert main(["render", "builtin:ct:16", "-q", "-o", str(tmp_path / "x.png")]) == 2
    assert seen["size"][0] == (512, 512)


def test_a_camera_inside_the_data_warns_in_one_line(tmp_path, capsys):
    """The README's old scene: a camera at (0, 0, 5) in a head measured in millimetres."""
    data = tmp_path / "ct.nii.gz"
    write_volume(load_builtin("builtin:ct:24"), data, frame="RAS")
    inside = {"position": [0, 0, 5], "focal_point": [0, 0, 0], "view_up": [0, 1, 0],
              "view_angle": 30}
    scene = _scene_file(tmp_path, camera=inside)
    status = main(["render", str(data), "--scene", str(scene), "--size", "16", "16",
                   "--device", "cpu", "-q", "-o", str(tmp_path / "in.png")])
    _, err = capsys.readouterr()
    assert status == 0  # a warning, not an error
    (line,) = [x for x in err.splitlines() if "warning" in x]
    assert line.startswith("vtkillum: warning: the camera at (0, 0, 5) is inside the data")
    assert "x: -120 to 120" in line and "units" in line
    from vtkillum import Camera

    with pytest.warns(UserWarning, match=r"the camera at \(0, 0, 5\) is inside the data"):
        _grid(data).illum.render("emission", transfer_function=TF, width=8, height=8,
                                 device="cpu", camera=Camera((0, 0, 5), (0, 0, 0), (0, 1, 0)))
    # outside (also just outside a face): no warning
    volume = read_volume(data)
    assert camera_inside_warning(Camera((0, -500, 0), (0, 0, 0), (0, 0, 1)), volume) is None
    assert camera_inside_warning(Camera((0, -121, 0), (0, 0, 0), (0, 0, 1)), volume) is None
    assert camera_inside_warning(Camera((0, -119, 0), (0, 0, 0), (0, 0, 1)), volume)
