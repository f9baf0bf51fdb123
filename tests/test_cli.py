"""The ``vtkillum`` command line, run in-process through ``main([...])`` at tiny sizes."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")

from vtkillum.cli import main  # noqa: E402
from vtkillum.core.render import METHODS  # noqa: E402
from vtkillum.core.scene import load_scene  # noqa: E402
from vtkillum.core.tonemap import read_png, tonemap  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


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
    from vtkillum.cli import HIDDEN_METHODS

    assert main(["render", "--help"]) == 0
    out = capsys.readouterr().out
    unwrapped = re.sub(r"-\n\s*", "-", out)  # argparse may wrap a name after its hyphen
    for name in METHODS:
        assert (name in unwrapped) == (name not in HIDDEN_METHODS)
    assert "gamma 2.2" in " ".join(out.split())  # the tone map is documented
    assert "--exposure" in out and "auto" in out


def test_illumination_is_not_offered_by_the_cli(tmp_path, capsys):
    """Issue 13: ``--method illumination`` was offered by --help but always failed."""
    status, _, err = run(capsys, "render", "builtin:ct:16", "--method", "illumination",
                         "--output", tmp_path / "x.png")
    assert_user_error(status, err, "illumination")


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
    bar = _progress_bar(False, "single 8x4000", stream=stream, mode="bar")
    with bar as progress:
        render(volume, builtin_scene("builtin:ct:16", volume), "single", 8, 4000, "cpu", progress)
        assert bar.bar.n == 100  # the render reported completion
    assert "single 8x4000" in stream.getvalue()
    assert _progress_bar(True, "quiet").__enter__() is None


def test_progress_lines_when_output_is_not_a_terminal():
    """Issue 13: with stderr redirected, progress is a line every few seconds."""
    import io

    from vtkillum.cli import _progress_bar

    now = [0.0]
    stream = io.StringIO()  # not a tty: lines
    bar = _progress_bar(False, "path 64x64", stream=stream, interval=0.0, heartbeat=False,
                        clock=lambda: now[0])
    with bar as progress:
        for k in range(1, 5):
            now[0] += 2.0
            progress(k / 4, f"{k}/4 spp")
    lines = stream.getvalue().splitlines()
    assert len(lines) == 3  # not at 100 %: the summary line says that
    # The first pass only sets the baseline (it may hold a compile): no estimate yet.
    assert lines[0] == "path 64x64: rendering, 25 %, 1/4 spp, 2 s spent"
    assert lines[1] == "path 64x64: rendering, 50 %, 2/4 spp, 4 s spent, about 4 s left"
    quiet = io.StringIO()
    with _progress_bar(False, "slow", stream=quiet, interval=3600.0, first_line=3600.0,
                       heartbeat=False) as progress:
        progress(0.5)
    assert quiet.getvalue() == ""  # at most one line per interval


# --- issue 15: reliability -----------------------------------------------------------------------
def _nrrd(path, encoding, payload):
    path.write_bytes(b"NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 4\nendian: little\n"
                     + f"encoding: {encoding}\n\n".encode() + payload)
    return path


@pytest.mark.parametrize("encoding,payload", [
    ("gzip", None),  # truncated
    ("gzip", b"not gzip at all" * 8),
    ("bzip2", b"BZh9" + b"\x00garbage" * 16),
])
def test_corrupt_compressed_nrrd_is_a_one_line_error(tmp_path, capsys, encoding, payload):
    """Row 4: a traceback and exit 1 before."""
    import gzip

    if payload is None:
        payload = gzip.compress(np.arange(64, dtype=np.float32).tobytes())[:30]
    path = _nrrd(tmp_path / "broken.nrrd", encoding, payload)
    status, _, err = run(capsys, "render", path, "--output", tmp_path / "a.png", "--size", 8, 8)
    assert_user_error(status, err, "broken.nrrd", "corrupt or truncated")
    assert not (tmp_path / "a.png").exists()


@pytest.mark.parametrize("name,written", [
    ("UP.NPY", ["UP.NPY", "UP.alpha.NPY"]),
    ("X.NPZ", ["X.NPZ"]),
    ("Pic.PNG", ["Pic.PNG"]),
    ("mixed.Npy", ["mixed.Npy", "mixed.alpha.Npy"]),
])
def test_output_extension_is_case_insensitive_and_the_name_is_kept(tmp_path, capsys, name,
                                                                  written):
    """Row 5: ``-o UP.NPY`` printed "wrote UP.NPY" but wrote ``UP.NPY.npy``."""
    status, out, _ = run(capsys, "render", "builtin:plume:12", "--size", 8, 6, "-o",
                         tmp_path / name, "--device", "cpu")
    assert status == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(written)
    for n in written:
        assert n in out
    first = tmp_path / written[0]
    if name.lower().endswith(".npy"):
        assert np.load(first).shape == (6, 8, 3) and np.load(tmp_path / written[1]).shape == (6, 8)
    elif name.lower().endswith(".npz"):
        with np.load(first) as f:
            assert f["radiance"].shape == (6, 8, 3)
    else:
        assert read_png(first).shape == (6, 8, 3)


@pytest.fixture
def no_render(monkeypatch):
    """Make any render fail loudly: errors must come before it."""
    import vtkillum.core.render as render_module

    def forbidden(*args, **kwargs):
        raise AssertionError("the output should have been refused before rendering")

    monkeypatch.setattr(render_module, "render", forbidden)


def test_directory_in_the_way_of_the_alpha_file_is_refused_before_rendering(tmp_path, capsys,
                                                                           no_render):
    """Row 6: the old radiance file was replaced, then the alpha write failed."""
    (tmp_path / "h.alpha.npy").mkdir()
    (tmp_path / "h.npy").write_text("old")
    status, _, err = run(capsys, "render", "builtin:plume:12", "--size", 8, 8, "-o",
                         tmp_path / "h.npy")
    assert_user_error(status, err, "h.alpha.npy", "directory")
    assert (tmp_path / "h.npy").read_text() == "old"


def test_dangling_symlink_and_directory_outputs_are_refused_before_rendering(tmp_path, capsys,
                                                                             no_render):
    link = tmp_path / "dangling.png"
    link.symlink_to(tmp_path / "nowhere" / "x.png")
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", link)
    assert_user_error(status, err, "dangling.png", "dangling symbolic link")
    (tmp_path / "d.png").mkdir()
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", tmp_path / "d.png")
    assert_user_error(status, err, "d.png", "is a directory")
    (tmp_path / "file").write_text("x")
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", tmp_path / "file" / "a.png")
    assert_user_error(status, err, "is not a directory")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc (never writable)")
def test_unwritable_directory_is_refused_before_rendering(capsys, no_render):
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", "/proc/a.npy")
    assert_user_error(status, err, "/proc", "cannot write")


def test_symlink_to_a_file_is_written_through(tmp_path, capsys):
    target = tmp_path / "real.png"
    target.write_bytes(b"old")
    link = tmp_path / "link.png"
    link.symlink_to(target)
    assert main(["render", "builtin:plume:12", "--size", "8", "8", "-o", str(link), "-q",
                 "--device", "cpu"]) == 0
    assert link.is_symlink() and read_png(target).shape == (8, 8, 3)


def test_alpha_names_are_reserved(tmp_path, capsys, no_render):
    """Row 6: ``-o col.alpha.npy`` then ``-o col.npy`` overwrote the first radiance."""
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", tmp_path / "col.alpha.npy")
    assert_user_error(status, err, "col.alpha.npy", "alpha file")
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", tmp_path / "col.ALPHA.NPY")
    assert_user_error(status, err, "alpha file")


@pytest.mark.parametrize("failure", [OSError(28, "No space left on device"), KeyboardInterrupt])
def test_a_failed_write_leaves_the_old_pair_and_no_temporary_files(tmp_path, capsys,
                                                                   monkeypatch, failure):
    """Row 6: files are written to temporaries and renamed only when all are complete."""
    (tmp_path / "p.npy").write_text("old radiance")
    (tmp_path / "p.alpha.npy").write_text("old alpha")
    real_save, calls = np.save, []

    def save(file, array, *args, **kwargs):
        calls.append(file)
        if len(calls) == 2:  # the alpha file
            raise failure
        return real_save(file, array, *args, **kwargs)

    monkeypatch.setattr(np, "save", save)
    status, _, err = run(capsys, "render", "builtin:plume:12", "--size", 8, 8, "-o",
                         tmp_path / "p.npy", "--device", "cpu", "-q")
    assert status == (130 if failure is KeyboardInterrupt else 2)
    assert (tmp_path / "p.npy").read_text() == "old radiance"
    assert (tmp_path / "p.alpha.npy").read_text() == "old alpha"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.alpha.npy", "p.npy"]


def test_new_files_get_the_usual_permissions(tmp_path, capsys):
    old = os.umask(0o022)
    try:
        assert main(["render", "builtin:plume:12", "--size", "8", "8", "-o",
                     str(tmp_path / "m.npz"), "-q", "--device", "cpu"]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "m.npz").stat().st_mode & 0o777 == 0o644


def test_image_too_large_for_the_memory_is_refused_before_rendering(tmp_path, capsys,
                                                                    monkeypatch, no_render):
    """Row 7: accepted, then a MemoryError traceback after the whole render."""
    import vtkillum.core.device as device_module

    monkeypatch.setattr(device_module, "available_memory", lambda device=None: (2 << 30, None))
    status, _, err = run(capsys, "render", "builtin:plume:12", "-m", "emission", "--size",
                         16384, 8192, "-o", tmp_path / "b.png", "--device", "cpu")
    assert_user_error(status, err, "--size 16384 8192", "2.0 GB is available",
                      "largest image of this shape that fits is about --size")
    w, h = (int(v) for v in err.split("--size")[-1].split()[:2])
    assert abs(w - 2 * h) <= 1 and 7000 < w < 8000  # 2 GB less the reserve, 64 bytes a pixel
    assert not (tmp_path / "b.png").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ulimit -v")
def test_memory_check_under_an_address_space_limit(tmp_path):
    """Row 7 as reported: ``ulimit -v`` and a huge size fail fast with the one-line error."""
    out = tmp_path / "b.png"
    command = (f"ulimit -v 4000000; exec {sys.executable} -m vtkillum.cli render "
               f"builtin:plume:12 -m emission --size 16384 16384 -o {out} --device cpu")
    # No CUDA: its driver reserves more address space than the limit allows.
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               CUDA_VISIBLE_DEVICES="")
    done = subprocess.run(["bash", "-c", command], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 2, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("vtkillum: error: --size 16384 16384") and "largest" in last
    assert "Traceback" not in done.stderr and not out.exists()


def test_tone_mapping_needs_no_float64_copies():
    """Row 7: the tone map made several float64 copies of the image (8x its float32 size)."""
    import tracemalloc

    radiance = np.random.default_rng(0).random((1024, 1024, 3), dtype=np.float32)
    alpha = np.full((1024, 1024), 0.5, np.float32)
    tracemalloc.start()
    try:
        rgb = tonemap(radiance, alpha, (0.1, 0.2, 0.3), 1.5)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert rgb.dtype == np.uint8 and rgb.shape == radiance.shape
    assert peak < rgb.nbytes + 16 * 2**20, peak / 2**20  # the result and a few MB of bands


def test_empty_device_variable_means_automatic(tmp_path, capsys, monkeypatch):
    """Row 10: ``VTKILLUM_DEVICE=`` failed with "device '' is not available"."""
    monkeypatch.setenv("VTKILLUM_DEVICE", "")
    assert main(["render", "builtin:plume:12", "--size", "8", "8", "-o",
                 str(tmp_path / "a.npz"), "-q"]) == 0


def test_binary_scene_file_is_named(tmp_path, capsys):
    """Row 10: a UTF-8 decode error that named no file."""
    scene = tmp_path / "scene.bin"
    scene.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe")
    status, _, err = run(capsys, "render", "builtin:plume:12", "--scene", scene, "-o",
                         tmp_path / "a.png")
    assert_user_error(status, err, "scene.bin", "not a JSON scene file")


@pytest.mark.parametrize("section,fragment", [
    ({"ambient_scattering": {"radius": 0}}, "ambient_scattering.radius"),
    ({"path": {"spp": 0}}, "path.spp"),
    ({"convection_diffusion": {"tolerance": 2}}, "convection_diffusion.tolerance"),
    ({"shading": {"shininess": -1}}, "shading.shininess"),
    ({"convection_diffusion": {"solver": "magic"}}, "magic"),
    ({"transfer_function": {"scalars": ["0", 1], "opacity": [0, 1]}},
     "transfer_function.scalars must hold numbers"),
])
def test_errors_in_a_scene_s_sections_name_the_file(tmp_path, capsys, section, fragment):
    """Row 10: method-section errors surfaced from the render without the file's name."""
    scene = tmp_path / "mine.json"
    scene.write_text(json.dumps(section))
    method = {"ambient_scattering": "ambient-scattering", "path": "path",
              "convection_diffusion": "convection-diffusion"}.get(next(iter(section)), "single")
    status, _, err = run(capsys, "render", "builtin:plume:12", "--scene", scene, "-m", method,
                         "--size", 8, 8, "-o", tmp_path / "a.png", "--device", "cpu")
    assert_user_error(status, err, "mine.json", fragment)


def test_radiance_and_alpha_must_be_different_files(tmp_path, capsys, no_render):
    (tmp_path / "r.npy").write_text("old")
    (tmp_path / "r.alpha.npy").symlink_to(tmp_path / "r.npy")
    status, _, err = run(capsys, "render", "builtin:plume:12", "-o", tmp_path / "r.npy")
    assert_user_error(status, err, "same file")


def test_auto_exposure_of_the_composite_in_bands():
    from vtkillum.core.render import RenderResult
    from vtkillum.core.tonemap import auto_exposure

    rng = np.random.default_rng(1)
    result = RenderResult(rng.random((700, 500, 3), dtype=np.float32) * 3,
                          rng.random((700, 500), dtype=np.float32))
    background = (0.2, 0.5, 0.1)
    expected = 1.0 / np.percentile(result.composite(background).max(-1), 99.5)
    got = auto_exposure(result.radiance, alpha=result.alpha, background=background)
    assert got == pytest.approx(expected, rel=1e-6)
    result.radiance[0, 0] = np.nan  # ignored, not a NaN exposure
    assert np.isfinite(auto_exposure(result.radiance, alpha=result.alpha))
