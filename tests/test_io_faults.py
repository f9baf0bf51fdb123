"""vtkillum.io under faults (issue 33): NaN in VTK transfer functions (conversion, filters,
refractive optics), masked arrays into VTK images, and the staged writes of
:mod:`vtkillum.io.writers` (clean-up, signals, full disks, companion files)."""

from __future__ import annotations

import errno
import os
import signal

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")

from vtkmodules.vtkCommonDataModel import vtkImageData, vtkPiecewiseFunction  # noqa: E402
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction  # noqa: E402

from vtkillum.core.volume import Volume  # noqa: E402
from vtkillum.io import writers  # noqa: E402
from vtkillum.io.convert import (  # noqa: E402
    add_point_array,
    transfer_function_from_vtk,
    volume_from_image_data,
)
from vtkillum.io.readers import read_volume  # noqa: E402


def opacity_function(points) -> vtkPiecewiseFunction:
    f = vtkPiecewiseFunction()
    for x, a in points:
        f.AddPoint(x, a)
    return f


# --- NaN in VTK transfer functions -----------------------------------------------------------
@pytest.mark.parametrize("points,node", [
    ([(0.0, 0.0), (0.5, np.nan), (1.0, 1.0)], 1),
    ([(0.0, 0.0), (1.0, np.inf)], 1),
])
def test_nan_in_a_vtk_opacity_function_names_the_node(points, node):
    with pytest.raises(ValueError, match=f"scalar opacity function .* at node {node} "):
        transfer_function_from_vtk(None, opacity_function(points))


def test_nan_in_a_vtk_colour_function_names_the_node():
    color = vtkColorTransferFunction()
    color.AddRGBPoint(0.0, 1.0, 1.0, 1.0)
    color.AddRGBPoint(1.0, np.nan, 0.0, 0.0)
    with pytest.raises(ValueError, match="colour transfer function .* at node 1 .*red = nan"):
        transfer_function_from_vtk(color, opacity_function([(0.0, 0.0), (1.0, 1.0)]))


def test_a_filter_refuses_a_nan_transfer_function():
    """Was: VTK took the NaN node and evaluated NaN between nodes, without a word."""
    from vtkillum.filters.light_transmittance import LightTransmittanceFilter

    image = vtkImageData()
    image.SetDimensions(5, 5, 5)
    add_point_array(image, "v", np.linspace(0, 1, 125).reshape(5, 5, 5), set_active=True)
    f = LightTransmittanceFilter()
    f.SetDevice("cpu")
    f.SetScalarOpacity(opacity_function([(0.0, 0.0), (0.5, np.nan), (1.0, 1.0)]))
    f.GetExecutive().AddObserver("ErrorEvent", lambda *args: None)
    with pytest.raises(ValueError, match="NaN or infinity at node 1"):
        f.execute(image)


def test_nan_in_the_refractive_optics_functions_is_refused():
    from vtkillum.io.optics import optics_from_vtk

    with pytest.raises(ValueError, match="refractive index function .* at node 0"):
        optics_from_vtk(opacity_function([(0.0, np.nan), (1.0, 1.5)]))
    medium = vtkColorTransferFunction()
    medium.AddRGBPoint(0.0, 1.0, np.inf, 1.0)
    with pytest.raises(ValueError, match="medium colour function .* at node 0"):
        optics_from_vtk(None, medium)


# --- masked arrays into VTK images ------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float32, np.int16, np.float64])
def test_masked_values_become_nan_in_a_vtk_image(dtype):
    """Was: the values under the mask were stored as data."""
    data = np.arange(60, dtype=dtype).reshape(5, 4, 3)
    masked = np.ma.masked_array(data, mask=data % 7 == 3)
    image = vtkImageData()
    image.SetDimensions(5, 4, 3)
    add_point_array(image, "v", masked, set_active=True)
    with pytest.raises(ValueError, match="NaN"):
        volume_from_image_data(image)
    filled = volume_from_image_data(image, nan_policy="fill")
    expected = Volume(masked, nan_policy="fill")
    np.testing.assert_array_equal(filled.scalars, expected.scalars)
    assert filled.value_range == (0.0, float(data[data % 7 != 3].max()))
    assert np.all(filled.scalars[data % 7 == 3] == 0.0)


# --- staged writes ----------------------------------------------------------------------------
def test_write_staged_removes_everything_on_an_error(tmp_path):
    (tmp_path / "b.txt").write_text("old b")

    def write(staged):
        for path in staged.values():
            path.write_text("new")
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        writers.write_staged([tmp_path / "a.txt", tmp_path / "b.txt"], write)
    assert sorted(os.listdir(tmp_path)) == ["b.txt"]
    assert (tmp_path / "b.txt").read_text() == "old b"


def test_write_staged_refuses_a_file_the_writer_left_out(tmp_path):
    with pytest.raises(OSError, match="was not written"):
        writers.write_staged([tmp_path / "a.txt"], lambda staged: None)
    assert os.listdir(tmp_path) == []


def test_a_full_disk_is_a_one_line_disk_full_error(tmp_path):
    def write(staged):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with pytest.raises(writers.DiskFullError) as caught:
        writers.write_staged([tmp_path / "x.npy"], write)
    assert caught.value.errno == errno.ENOSPC
    assert str(caught.value) == (f"cannot write {tmp_path / 'x.npy'}: no space left on device "
                                 "(nothing was written; existing files are kept)")
    assert os.listdir(tmp_path) == []


def test_terminated_is_a_system_exit_with_the_conventional_status():
    stop = writers.Terminated(signal.SIGTERM)
    assert isinstance(stop, SystemExit) and stop.code == 143 and stop.name == "SIGTERM"
    assert writers.Terminated(signal.SIGHUP).code == 129


def test_handlers_are_installed_only_over_the_default_action_and_restored():
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as under nohup
    try:
        with writers.terminating_raises():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is writers._raise_terminated
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    finally:
        signal.signal(signal.SIGHUP, previous)


def test_signals_held_delivers_after_the_block():
    seen = []
    previous = signal.signal(signal.SIGUSR1, lambda signum, frame: seen.append(signum))
    try:
        held = {signal.SIGUSR1}
        before = signal.pthread_sigmask(signal.SIG_BLOCK, held)  # SIGUSR1 stands in ...
        try:
            with writers.signals_held():  # ... and the mask is restored as it was
                pass
            assert signal.SIGUSR1 in signal.pthread_sigmask(signal.SIG_BLOCK, [])
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)
        with writers.signals_held():
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, [])
        assert {signal.SIGINT, signal.SIGTERM, signal.SIGHUP} <= blocked
    finally:
        signal.signal(signal.SIGUSR1, previous)


@pytest.mark.parametrize("name", ["ct.mhd", "CT.MHD", "ct.mha", "CT.Mha", "ct.vti", "ct.nii",
                                  "ct.nii.gz", "CT.NII.GZ"])
def test_write_volume_writes_exactly_its_files(tmp_path, name):
    volume = Volume(np.random.default_rng(1).random((5, 4, 3)).astype(np.float32),
                    spacing=(0.5, 1.0, 2.0), origin=(1.0, 2.0, 3.0))
    writers.write_volume(volume, tmp_path / name)
    expected = sorted(p.name for p in writers.volume_files(tmp_path / name))
    assert sorted(os.listdir(tmp_path)) == expected
    if name.lower().endswith(".mhd"):
        header = (tmp_path / name).read_text()
        assert f"ElementDataFile = {name[:-4]}.raw" in header
    if name.lower().endswith(".gz"):
        assert (tmp_path / name).read_bytes()[:2] == b"\x1f\x8b"  # compressed as named
    readable = tmp_path / name
    if name.lower().endswith((".mhd", ".mha")) and not name.endswith((".mhd", ".mha")):
        # (VTK's MetaImage reader knows lower-case extensions only)
        readable = tmp_path / (name[:-4] + name[-4:].lower())
        os.link(tmp_path / name, readable)
    np.testing.assert_allclose(read_volume(readable).scalars, volume.scalars, rtol=1e-6)
