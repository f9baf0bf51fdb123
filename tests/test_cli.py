"""The ``vtkillum`` command line, run in-process through ``main([...])`` at tiny sizes."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")

from vtkillum.cli import main  # noqa: E402
from vtkillum.core.render import METHODS  # noqa: E402
from vtkillum.core.scene import load_scene  # noqa: E402
from vtkillum.core.tonemap import read_png, tonemap  # noqa: E402


def run(capsys, *argv):
    """Run the CLI; returns (exit status, stdout, stderr)."""
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def test_demo_writes_a_picture_with_shading(tmp_path, capsys):
    out = tmp_path / "demo.png"
    status, stdout, _ = run(capsys, "demo", "--output", out, "--size", 40, 32,
                            "--dataset", "builtin:plume:24", "--device", "cpu")
    assert status == 0
    assert "demo.png" in stdout and "single" in stdout
    rgb = read_png(out)
    assert rgb.shape == (32, 40, 3)
    background = rgb[0, 0].astype(int)
    differs = np.abs(rgb.astype(int) - background).max(-1) > 10
    assert 0.05 < differs.mean() < 0.9  # the plume covers part of the picture
    lum = rgb.astype(float).mean(-1)[differs]
    assert lum.max() - lum.min() > 40  # lit and shadowed parts differ


def test_render_npy_and_npz(tmp_path, capsys):
    npy = tmp_path / "r.npy"
    status, _, _ = run(capsys, "render", "builtin:ct:20", "--method", "emission", "--size", 24,
                       16, "--output", npy, "--quiet")
    assert status == 0
    radiance, alpha = np.load(npy), np.load(tmp_path / "r.alpha.npy")
    assert radiance.shape == (16, 24, 3) and radiance.dtype == np.float32
    assert alpha.shape == (16, 24) and alpha.dtype == np.float32
    assert radiance.max() > 0 and 0 <= alpha.min() and alpha.max() <= 1

    npz = tmp_path / "r.npz"
    assert main(["render", "builtin:ct:20", "--method", "emission", "--size", "24", "16",
                 "--output", str(npz), "-q"]) == 0
    with np.load(npz) as f:
        np.testing.assert_array_equal(f["radiance"], radiance)  # same render, same result
        np.testing.assert_array_equal(f["alpha"], alpha)
        assert f["background"].shape == (3,)


def test_png_is_the_documented_tone_map(tmp_path, capsys):
    """PNG = tonemap(radiance over background, exposure, gamma 2.2) of the .npz render."""
    scene = tmp_path / "s.json"
    assert main(["scene", "--dataset", "builtin:marschner-lobb:12", "--output", str(scene)]) == 0
    common = ["render", "builtin:marschner-lobb:12", "--scene", str(scene), "--method",
              "emission", "--size", "20", "20", "-q", "--exposure", "1.7"]
    assert main(common + ["--output", str(tmp_path / "a.png")]) == 0
    assert main(common + ["--output", str(tmp_path / "a.npz")]) == 0
    with np.load(tmp_path / "a.npz") as f:
        expected = tonemap(f["radiance"], f["alpha"], f["background"], 1.7, gamma=2.2)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), expected)


def test_render_a_file_with_a_scene(tmp_path, capsys):
    image = vtk.vtkImageData()
    image.SetDimensions(12, 12, 12)
    image.SetSpacing(0.5, 0.5, 0.5)
    x = np.linspace(-1, 1, 12)
    field = np.exp(-4 * (x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2))
    from vtkmodules.util.numpy_support import numpy_to_vtk

    array = numpy_to_vtk(field.ravel(order="F").astype(np.float32), deep=True)
    array.SetName("blob")
    image.GetPointData().SetScalars(array)
    writer = vtk.vtkXMLImageDataWriter()
    writer.SetFileName(str(tmp_path / "blob.vti"))
    writer.SetInputData(image)
    writer.Write()

    scene = tmp_path / "blob.json"
    status, stdout, _ = run(capsys, "scene", "--dataset", tmp_path / "blob.vti", "--output", scene)
    assert status == 0 and "blob.json" in stdout
    written = json.loads(scene.read_text())
    assert {"transfer_function", "camera", "opacity_unit_distance", "lights"} <= set(written)
    load_scene(scene)  # valid
    status, _, _ = run(capsys, "render", tmp_path / "blob.vti", "--scene", scene, "--size", 16,
                       16, "--output", tmp_path / "blob.npy", "-q")
    assert status == 0
    assert np.load(tmp_path / "blob.alpha.npy")[8, 8] > 0.1  # the blob is in the middle


def test_scene_for_a_builtin_is_its_default_scene(tmp_path, capsys):
    from vtkillum.data.builtin import builtin_scene, load_builtin

    path = tmp_path / "plume.json"
    assert main(["scene", "--dataset", "builtin:plume:16", "--output", str(path)]) == 0
    scene = load_scene(path)
    default = builtin_scene("builtin:plume:16", load_builtin("builtin:plume:16"))
    np.testing.assert_allclose(scene.transfer_function.opacity, default.transfer_function.opacity)
    np.testing.assert_allclose(scene.camera.position, default.camera.position)
    assert scene.anisotropy == default.anisotropy


def test_method_choices_come_from_the_registry(capsys):
    assert main(["render", "--help"]) == 0
    out = capsys.readouterr().out
    unwrapped = re.sub(r"-\n\s*", "-", out)  # argparse may wrap a name after its hyphen
    for name in METHODS:
        assert name in unwrapped
    assert "gamma 2.2" in " ".join(out.split())  # the tone map is documented


# --- user errors: one line, exit status 2 ------------------------------------------------------
def assert_user_error(status, err, *fragments):
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vtkillum: error:"), err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0]


def test_bad_scene_field(tmp_path, capsys):
    scene = tmp_path / "bad.json"
    scene.write_text(json.dumps({"albedo": 0.9, "ligths": []}))
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", scene, "--output",
                         tmp_path / "x.png", "--size", 8, 8)
    assert_user_error(status, err, "bad.json", "ligths")
    scene.write_text(json.dumps({"albedo": 1.5}))
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", scene, "--output",
                         tmp_path / "x.png", "--size", 8, 8)
    assert_user_error(status, err, "albedo")
    scene.write_text("{not json")
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", scene, "--output",
                         tmp_path / "x.png", "--size", 8, 8)
    assert_user_error(status, err, "not valid JSON")
    assert not (tmp_path / "x.png").exists()


def test_unknown_builtin(tmp_path, capsys):
    status, _, err = run(capsys, "render", "builtin:teapot", "--output", tmp_path / "x.png")
    assert_user_error(status, err, "teapot", "plume", "cornell", "ct", "marschner-lobb")
    status, _, err = run(capsys, "demo", "--dataset", "nothing.vti", "--output",
                         tmp_path / "x.png")
    assert_user_error(status, err, "builtin:NAME")


def test_unknown_method(tmp_path, capsys):
    status, _, err = run(capsys, "render", "builtin:ct:16", "--method", "raytrace", "--output",
                         tmp_path / "x.png")
    assert_user_error(status, err, "raytrace", "emission", "single", "path")


@pytest.mark.parametrize("args,fragments", [
    (["render", "missing.vti", "--output", "{tmp}/x.png"], ["missing.vti", "no such file"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.jpg"], [".png, .npy, .npz"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/nodir/x.png"], ["does not exist"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--size", "0", "5"], ["--size"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--exposure", "-1"], ["--exposure"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--spp", "4"],
     ["--spp", "'single'"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--option", "nonsense"],
     ["KEY=VALUE"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--size", "8", "8",
      "--option", "warp_speed=9"], ["warp_speed"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--device", "tpu"], ["tpu"]),
    (["render", "builtin:ct:16", "--output", "{tmp}/x.png", "--array", "a"], ["--array"]),
    (["render", "{tmp}/volume.xyz", "--output", "{tmp}/x.png"], ["unknown volume format"]),
    (["render", "--output", "{tmp}/x.png"], ["input"]),
    (["scene", "--dataset", "builtin:ct:16", "--output", "{tmp}/scene.txt"], [".json"]),
])
def test_user_errors(tmp_path, capsys, args, fragments):
    (tmp_path / "volume.xyz").write_text("1 2 3")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    status, _, err = run(capsys, *argv)
    assert_user_error(status, err, *fragments)


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(ValueError, match="teapot"):
        main(["--debug", "render", "builtin:teapot", "--output", str(tmp_path / "x.png")])


def test_progress_bar_follows_the_render():
    import io

    from vtkillum.cli import _progress_bar
    from vtkillum.core.render import render
    from vtkillum.data.builtin import builtin_scene, load_builtin

    volume = load_builtin("builtin:ct:16")
    stream = io.StringIO()
    bar = _progress_bar(False, "single 8x4000", stream=stream)
    with bar as progress:
        render(volume, builtin_scene("builtin:ct:16", volume), "single", 8, 4000, "cpu", progress)
        assert bar.bar.n == 100  # the render reported completion
    assert "single 8x4000" in stream.getvalue()
    assert _progress_bar(True, "quiet").__enter__() is None
