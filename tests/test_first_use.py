"""Issue 13: a good first picture of one's own data without flags, export, quiet start.

Renders run at small sizes (the CLI's default is 256² on a CPU); the criteria are the issue's:
the PNG uses the dynamic range (99th percentile above 200/255), is not blank, and a
medical image is seen from the front with superior up and the patient's left on the
right of the picture.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("vtk")

from vtkillum.cli import load_input, main, write_volume
from vtkillum.core.defaults import (
    analyse_histogram,
    auto_exposure,
    default_camera,
    default_transfer_function,
    key_light,
)
from vtkillum.core.tonemap import read_png
from vtkillum.core.volume import Volume
from vtkillum.io.readers import read_volume

ROOT = Path(__file__).resolve().parents[1]


def run_cli(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def synthetic_head(direction, n=40) -> Volume:
    """A head in RAS millimetres: skin 0.3, brain 0.6, an ear on the patient's left (-x),
    a nose in front (+y), a narrow neck below (-z); sampled on a grid whose axes are
    ``direction``'s columns (world = origin + direction @ (spacing * ijk))."""
    direction = np.asarray(direction, dtype=np.float64)
    spacing = 200.0 / (n - 1)
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1) * spacing
    origin = -direction @ np.full(3, 100.0)
    world = ijk @ direction.T + origin
    x, y, z = world[..., 0], world[..., 1], world[..., 2]
    values = np.zeros((n, n, n), np.float32)
    head = (x / 60) ** 2 + (y / 70) ** 2 + ((z - 20) / 65) ** 2 <= 1
    neck = (x ** 2 + y ** 2 <= 22 ** 2) & (z < -20) & (z > -95)
    ear = ((x + 66) / 16) ** 2 + (y / 18) ** 2 + ((z - 15) / 20) ** 2 <= 1
    nose = (x / 10) ** 2 + ((y - 72) / 14) ** 2 + ((z - 5) / 16) ** 2 <= 1
    values[head | neck | ear | nose] = 0.3
    brain = (x / 50) ** 2 + (y / 60) ** 2 + ((z - 25) / 52) ** 2 <= 1
    values[brain] = 0.6
    rng = np.random.default_rng(0)
    values += rng.normal(0, 0.01, values.shape).astype(np.float32)
    return Volume(np.clip(values, 0, 1), (spacing,) * 3, origin, direction)


#: Grid axes of the synthetic scan in RAS: i -> superior, j -> patient's left, k -> anterior
#: (a permuted, flipped layout; determinant +1) and one with determinant -1.
ODD_AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
MIRRORED = np.diag([-1.0, 1.0, 1.0])


@pytest.mark.parametrize("direction", [np.eye(3), ODD_AXES, MIRRORED])
def test_oriented_nifti_gets_an_anterior_view_superior_up(tmp_path, capsys, direction):
    path = tmp_path / "head.nii.gz"
    write_volume(synthetic_head(direction), path, frame="RAS")
    _, scene = load_input(str(path))
    right, up, forward = scene.camera.basis()
    # the readers give LPS: posterior is +y, superior +z, the patient's left +x
    np.testing.assert_allclose(forward, [0, 1, 0], atol=1e-9)  # looking posterior
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-9)  # patient's left on the right

    png = tmp_path / "head.png"
    npz = tmp_path / "head.npz"
    assert main(["render", str(path), "--size", "64", "64", "-q", "--device", "cpu",
                 "--output", str(png)]) == 0
    assert main(["render", str(path), "--size", "64", "64", "-q", "--device", "cpu",
                 "--output", str(npz)]) == 0
    rgb = read_png(png)
    assert np.percentile(rgb, 99) > 200  # the dynamic range is used
    with np.load(npz) as f:
        alpha = f["alpha"]
    covered = alpha > 0.5
    assert 0.1 < covered.mean() < 0.9  # framed: neither blank nor all volume
    widths = covered.sum(axis=1)
    rows = np.flatnonzero(widths)
    top, bottom = rows[: len(rows) // 3], rows[-len(rows) // 4:]
    assert widths[top].mean() > 1.5 * widths[bottom].mean()  # head above, neck below
    neck = np.flatnonzero(covered[bottom].any(axis=0))
    middle = 0.5 * (neck[0] + neck[-1])  # the neck is centred on the head (x = 0)
    cols = np.flatnonzero(covered[np.argmax(widths)])  # the widest row: the ears' height
    # the ear (patient's left) sticks out on the right of the picture
    assert cols[-1] - middle > middle - cols[0] + 2


def test_key_light_comes_from_the_upper_front_left():
    volume = synthetic_head(np.eye(3), n=16)
    camera = default_camera(volume, "LPS")
    light = key_light(camera)
    right, up, forward = camera.basis()
    towards = -light.direction
    assert towards @ right < -0.3 and towards @ up > 0.3 and towards @ forward < -0.5


def test_histogram_classes_of_the_ct_phantom():
    from vtkillum.data.builtin import load_builtin

    volume = load_builtin("builtin:ct:64")
    h = analyse_histogram(volume)
    assert h.air is not None and h.threshold < 0.15  # air (0) transparent
    centres = [c for c, _, _ in h.classes]
    for material in (0.3, 0.5, 0.9):  # skin, tissue, bone are classes
        assert min(abs(c - material) for c in centres) < 0.03
    tf = default_transfer_function(volume, h)
    assert tf.alpha(0.0) == 0 and tf.alpha(h.threshold) == 0
    assert 0 < tf.alpha(0.3) < tf.alpha(0.5) < tf.alpha(0.9)  # denser: more opaque


def test_histogram_without_air_and_constant_data():
    x = np.linspace(0, 1, 20)
    ramp = Volume(np.broadcast_to(x[:, None, None], (20, 20, 20)).copy())
    tf = default_transfer_function(ramp)
    assert tf.alpha(0.0) == 0 and tf.alpha(1.0) > 0
    const = Volume(np.full((4, 4, 4), 3.0, np.float32))
    default_transfer_function(const)  # no error
    default_camera(const)


def test_camera_of_unknown_data_follows_the_direction_matrix():
    volume = synthetic_head(ODD_AXES, n=16)
    camera = default_camera(volume, None)
    _, up, forward = camera.basis()
    local_forward = ODD_AXES.T @ forward
    expected = np.array([-0.4, -0.3, -1.0]) / np.linalg.norm([-0.4, -0.3, -1.0])
    np.testing.assert_allclose(local_forward, expected, atol=1e-9)
    assert (ODD_AXES.T @ up)[1] > 0.9  # the grid's y is up


def test_auto_exposure_looks_at_the_covered_pixels():
    radiance = np.zeros((100, 100, 3), np.float32)
    alpha = np.zeros((100, 100), np.float32)
    radiance[:10, :10] = 0.25  # a small object: 1 % of the picture
    alpha[:10, :10] = 1.0
    assert auto_exposure(radiance, alpha) == pytest.approx(4.0)
    assert auto_exposure(np.zeros_like(radiance), alpha) == 1.0


def test_builtin_ct_default_png_uses_the_range(tmp_path, capsys):
    png = tmp_path / "ct.png"
    status, _, _ = run_cli(capsys, "render", "builtin:ct:48", "--size", 96, 96, "-q",
                           "--device", "cpu", "--output", png)
    assert status == 0
    rgb = read_png(png)
    assert np.percentile(rgb, 99) > 200
    assert (np.abs(rgb.astype(int) - rgb[0, 0]).max(-1) > 10).mean() > 0.1  # not blank


def test_mni152_template(tmp_path, capsys):
    """The issue's real data set, where nilearn (a test-only tool) is installed."""
    datasets = pytest.importorskip("nilearn.datasets")
    path = tmp_path / "mni152.nii.gz"
    datasets.load_mni152_template().to_filename(str(path))
    _, scene = load_input(str(path))
    assert scene.camera.forward @ np.array([0, 1, 0]) > 0.99  # anterior view
    png = tmp_path / "mni.png"
    npz = tmp_path / "mni.npz"
    for out in (png, npz):
        assert run_cli(capsys, "render", path, "--size", 80, 80, "-q", "--device", "cpu",
                       "--output", out)[0] == 0
    rgb = read_png(png)
    assert np.percentile(rgb, 99) > 200
    with np.load(npz) as f:
        covered = f["alpha"] > 0.5
    assert covered.mean() > 0.15
    widths = covered.sum(axis=1)
    rows = np.flatnonzero(widths)
    # the cerebrum (top) is wider than the brain stem and cerebellum (bottom)
    assert widths[rows[: len(rows) // 3]].mean() > widths[rows[-len(rows) // 6:]].mean()


# --- export ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["ct.vti", "ct.nii.gz", "ct.nii", "ct.mha", "ct.mhd"])
def test_export_builtin_round_trip(tmp_path, capsys, name):
    from vtkillum.data.builtin import load_builtin

    out = tmp_path / name
    status, stdout, _ = run_cli(capsys, "export", "builtin:ct:20", "-o", out)
    assert status == 0 and name in stdout
    back = read_volume(out)
    ref = load_builtin("builtin:ct:20")
    np.testing.assert_array_equal(back.scalars, ref.scalars)
    np.testing.assert_allclose(back.spacing, ref.spacing, rtol=1e-6)
    if name.endswith(".vti"):  # as stored
        np.testing.assert_allclose(back.origin, ref.origin, atol=1e-6)
        np.testing.assert_allclose(back.direction, ref.direction, atol=1e-9)
    else:  # the phantom's RAS-like frame, read back as LPS: x and y negated
        flip = np.diag([-1.0, -1.0, 1.0])
        np.testing.assert_allclose(back.origin, flip @ ref.origin, atol=1e-4)
        np.testing.assert_allclose(back.direction, flip @ ref.direction, atol=1e-6)


@pytest.mark.parametrize("direction", [ODD_AXES, MIRRORED])
def test_export_keeps_the_placement_of_a_read_file(tmp_path, capsys, direction):
    source = tmp_path / "in.nii.gz"
    write_volume(synthetic_head(direction, n=12), source, frame="RAS")
    first = read_volume(source)
    for name in ("again.nii.gz", "again.mha", "again.vti"):
        assert run_cli(capsys, "export", source, "-o", tmp_path / name)[0] == 0
        back = read_volume(tmp_path / name)
        np.testing.assert_array_equal(back.scalars, first.scalars)
        np.testing.assert_allclose(back.origin, first.origin, atol=1e-4)
        np.testing.assert_allclose(back.direction, first.direction, atol=1e-6)


def test_export_errors(tmp_path, capsys):
    status, _, err = run_cli(capsys, "export", "builtin:ct:20", "-o", tmp_path / "x.png")
    assert status == 2 and "extension" in err
    status, _, err = run_cli(capsys, "export", "builtin:ct:20", "-o", tmp_path / "no" / "x.vti")
    assert status == 2 and "does not exist" in err


# --- quiet start, info ----------------------------------------------------------------------------
def _cli(*args, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               VTK_DEFAULT_OPENGL_WINDOW="vtkOSOpenGLRenderWindow")
    env.pop("VTKILLUM_DEVICE", None)
    return subprocess.run([sys.executable, "-m", "vtkillum.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, env=env,
                          check=False)


def test_nothing_alarming_on_stderr(tmp_path):
    """Issue 13: no 'Warp CUDA warning' (or anything else) on a machine without a GPU."""
    for args in (["scene", "--dataset", "builtin:ct:16", "-o", tmp_path / "s.json"],
                 ["render", "builtin:ct:16", "--size", 16, 16, "--device", "cpu", "-q",
                  "-o", tmp_path / "r.png"],
                 ["export", "builtin:ct:16", "-o", tmp_path / "h.vti"]):
        done = _cli(*args)
        assert done.returncode == 0, done.stderr
        assert done.stderr == "", done.stderr


def test_info_lists_the_devices():
    done = _cli("info")
    assert done.returncode == 0 and done.stderr == ""
    out = done.stdout
    assert "vtkillum" in out and "warp" in out and "devices" in out
    assert "cpu" in out and "(default)" in out and "cuda" in out
    assert "ambient-scattering tables" in out and "albedo 0.9" in out


# --- long path renders ----------------------------------------------------------------------------
def test_path_estimate_and_ctrl_c_write_the_partial_image(tmp_path, capsys, monkeypatch):
    import signal

    from vtkillum import cli
    from vtkillum.core import pathtrace

    monkeypatch.setattr(cli, "LONG_RENDER_SECONDS", 0.0)  # always print the estimate
    real_run = pathtrace.PathTracer.run

    def run_then_interrupt(self, passes=1):
        real_run(self, passes)
        if self.passes == 3:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C during the render
        return self

    monkeypatch.setattr(pathtrace.PathTracer, "run", run_then_interrupt)
    out = tmp_path / "p.npz"
    status, _, err = run_cli(capsys, "render", "builtin:ct:16", "--method", "path", "--spp", 50,
                             "--size", 12, 10, "--device", "cpu", "--output", out)
    assert status == 130
    assert "about" in err and "samples per pixel" in err and "Ctrl-C" in err  # the estimate
    assert "interrupted" in err and "3 of 50 samples per pixel" in err
    with np.load(out) as f:
        assert f["radiance"].shape == (10, 12, 3) and np.isfinite(f["radiance"]).all()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
