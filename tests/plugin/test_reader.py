"""The plugin's medical image readers in Debian's ParaView 5.11 (issue 32).

Files with a rotated grid (non-identity direction, off-origin, anisotropic spacing)
are written here as NIfTI (``.nii.gz``), NRRD, MetaImage (``.mha``), a DICOM series
and a 4-D NIfTI; a pvbatch script (``PVBATCH_SCRIPT`` below, run once) opens each
with the plugin's readers and saves what ParaView holds. Each must equal what
vtkillum's own reader (:func:`vtkillum.io.readers.read_volume`, the CLI's) returns:
dimensions, spacing, origin, direction matrix and values. vtkIllum Light
Transmittance must run on the NIfTI, bad files must give one clear line naming the
file (no traceback), and in the GUI (``paraview --script``) ``OpenDataFile`` of a
``.nii.gz`` must work and the reader must be in File → Open's filter list.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "paraview_plugin"))
sys.path.insert(0, str(ROOT / "tests"))
import pvbatch_env

pytestmark = pytest.mark.plugin

SHAPE = (20, 16, 12)
SPACING = np.array([0.8, 1.1, 1.5])
ORIGIN = np.array([10.0, -20.0, 30.0])
_c, _s = np.cos(0.5), np.sin(0.5)
#: A proper rotation that is not a permutation (so a transposed matrix shows).
ROTATION = np.array([[_c, -_s, 0.0], [_s, _c, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
    [[1.0, 0.0, 0.0], [0.0, np.cos(0.3), -np.sin(0.3)], [0.0, np.sin(0.3), np.cos(0.3)]])

#: Name -> how the pvbatch script opens it ("open": OpenDataFile, "file": the file reader
#: by name, "dir": the DICOM directory reader).
CASES = {"nifti": ("ct.nii.gz", "open"), "nrrd": ("ct.nrrd", "file"),
         "metaimage": ("ct.mha", "file"), "dicom_dir": ("series", "dir"),
         "dicom_file": ("series/slice003.dcm", "file")}
BAD = {"garbage": "garbage.nii.gz", "truncated_nrrd": "truncated.nrrd",
       "missing": "missing.nii.gz"}

PVBATCH_SCRIPT = r'''
import json, sys
import numpy as np
from paraview import servermanager
from paraview.simple import *
from vtkmodules.util.numpy_support import vtk_to_numpy

data, out, plugin = sys.argv[1:4]
cases, bad = json.loads(sys.argv[4]), json.loads(sys.argv[5])
LoadPlugin(plugin, ns=globals())
session = servermanager.ActiveConnection.Session
factory = servermanager.vtkSMProxyManager.GetProxyManager().GetReaderFactory()
summary = {"cases": {}, "bad": {}}


def possible(path):
    readers = factory.GetPossibleReaders(path, session)
    return [readers.GetString(i) for i in range(1, readers.GetLength(), 3)]


def open_case(path, how):
    if how == "open":
        return OpenDataFile(path)
    if how == "file":
        return vtkIllumMedicalImageReader(FileName=path)
    return vtkIllumDICOMDirectoryReader(DirectoryName=path)


def save(name, proxy, time=None):
    proxy.UpdatePipeline(time) if time is not None else proxy.UpdatePipeline()
    image = servermanager.Fetch(proxy)
    m = image.GetDirectionMatrix()
    scalars = image.GetPointData().GetScalars()
    np.savez(f"{out}/{name}.npz", dims=image.GetDimensions(), spacing=image.GetSpacing(),
             origin=image.GetOrigin(),
             direction=[[m.GetElement(r, c) for c in range(3)] for r in range(3)],
             scalars=vtk_to_numpy(scalars), bounds=proxy.GetDataInformation().GetBounds())
    return {"class": image.GetClassName(), "array": scalars.GetName()}


for name, (relative, how) in cases.items():
    path = f"{data}/{relative}"
    record = {"possible": possible(path)}
    if factory.CanReadFile(path, session):
        record["default_reader"] = factory.GetReaderName()
    reader = open_case(path, how)
    record["proxy"] = reader.GetXMLName()
    record.update(save(name, reader))
    summary["cases"][name] = record

# The 4-D NIfTI: one time step per volume.
reader = OpenDataFile(f"{data}/t4.nii.gz")
reader.UpdatePipelineInformation()
times = list(reader.TimestepValues)
summary["t4"] = {"times": times, "scene_times": list(GetAnimationScene().TimeKeeper.TimestepValues)}
for t, time in enumerate(times):
    save(f"t4_{t}", reader, time)

# Illumination on the NIfTI: vtkIllum Light Transmittance runs and lights it.
nifti = OpenDataFile(f"{data}/ct.nii.gz")
lit = vtkIllumLightTransmittance(Input=nifti)
lit.Lights = [0, 0, -1, -1, 1, 1, 1, 0]
lit.UpdatePipeline()
image = servermanager.Fetch(lit)
transmittance = image.GetPointData().GetArray("transmittance")
summary["lit"] = {
    "arrays": [image.GetPointData().GetArrayName(i)
               for i in range(image.GetPointData().GetNumberOfArrays())],
    "transmittance_range": list(transmittance.GetRange()) if transmittance else None,
    "dims": list(image.GetDimensions()),
}
view = CreateRenderView()
view.ViewSize = [240, 240]
display = Show(lit, view)
view.ResetCamera()
Render(view)
SaveScreenshot(f"{out}/lit.png", view, ImageResolution=[240, 240])

# Orientation as drawn: the volume (and, for the record, the outline) of the NIfTI, seen
# along -z with a parallel camera: pixel = 120 + 3 * (x, -y).
Hide(lit, view)
view.Background = [0, 0, 0]
if hasattr(view, "UseColorPaletteForBackground"):
    view.UseColorPaletteForBackground = 0
view.OrientationAxesVisibility = 0
for representation in ("Outline", "Volume", "Lit"):
    source = lit if representation == "Lit" else nifti
    shown = Show(source, view)
    if representation != "Lit":  # the lit output is a volume, lit per sample
        shown.SetRepresentationType(representation)
    view.CameraPosition = [0, 0, 200]
    view.CameraFocalPoint = [0, 0, 0]
    view.CameraViewUp = [0, 1, 0]
    view.CameraParallelProjection = 1
    view.CameraParallelScale = 40
    Render(view)
    SaveScreenshot(f"{out}/{representation.lower()}_fixed.png", view, ImageResolution=[240, 240])
    Hide(source, view)

# Bad files: one error line each (stderr), no output, nothing raised.
for name, relative in bad.items():
    sys.stderr.write(f"@@bad {name}\n")
    sys.stderr.flush()
    reader = vtkIllumMedicalImageReader(FileName=f"{data}/{relative}")
    try:
        reader.UpdatePipeline()
        summary["bad"][name] = {"points": reader.GetDataInformation().GetNumberOfPoints()}
    except Exception as err:  # noqa: BLE001 - recorded for the test
        summary["bad"][name] = {"raised": repr(err)}
    sys.stderr.flush()
# Files read with a warning: several components (their magnitude), NaN samples (filled).
for name in ("rgb", "nan"):
    sys.stderr.write(f"@@warn {name}\n")
    sys.stderr.flush()
    save(name, vtkIllumMedicalImageReader(FileName=f"{data}/{name}.mha"))
    sys.stderr.flush()
sys.stderr.write("@@end\n")

# A state file keeps the reader: saved, the session reset, loaded, it reads the file again.
SaveState(f"{out}/state.pvsm")
ResetSession()
LoadState(f"{out}/state.pvsm")
loaded = next((proxy for proxy in GetSources().values()
               if proxy.GetXMLName() == "vtkIllumMedicalImageReader"
               and str(proxy.FileName).endswith("ct.nii.gz")), None)
summary["state"] = {"proxy": loaded.GetXMLName() if loaded else None}
if loaded:
    loaded.UpdatePipeline()
    summary["state"]["points"] = loaded.GetDataInformation().GetNumberOfPoints()

with open(f"{out}/summary.json", "w") as f:
    json.dump(summary, f)
'''

GUI_SCRIPT = r'''
import json, os
from paraview import servermanager
from paraview.simple import *

out, data, plugin = (os.environ[k] for k in ("VTKILLUM_GUI_OUT", "VTKILLUM_DATA",
                                              "VTKILLUM_PLUGIN"))
result = {}
try:
    LoadPlugin(plugin, ns=globals())
    session = servermanager.ActiveConnection.Session
    factory = servermanager.vtkSMProxyManager.GetProxyManager().GetReaderFactory()
    result["filters"] = factory.GetSupportedFileTypes(session)
    path = f"{data}/ct.nii.gz"
    result["can_read"] = bool(factory.CanReadFile(path, session))
    result["reader"] = factory.GetReaderName()
    reader = OpenDataFile(path)
    reader.UpdatePipeline()
    result["points"] = reader.GetDataInformation().GetNumberOfPoints()
    result["bounds"] = list(reader.GetDataInformation().GetBounds())
    Show(reader)
    SetActiveSource(reader)  # its Properties panel is built
    Render()
    # The DICOM directory reader from Sources → vtkIllum: its panel (a directory chooser).
    series = vtkIllumDICOMDirectoryReader(DirectoryName=f"{data}/series")
    SetActiveSource(series)
    series.UpdatePipeline()
    result["series_points"] = series.GetDataInformation().GetNumberOfPoints()
    definitions = session.GetProxyDefinitionManager()
    hints = definitions.GetProxyDefinition("sources", "vtkIllumDICOMDirectoryReader"
                                           ).FindNestedElementByName("Hints")
    result["series_menu"] = hints.FindNestedElementByName("ShowInMenu").GetAttribute("category")
    # The reader is listed by the dialog's own code path: pqFileDialog takes its filter
    # list from pqLoadDataReaction / the reader factory (GetSupportedFileTypes).
except Exception as err:  # noqa: BLE001 - reported to the test
    result["error"] = repr(err)
with open(os.path.join(out, "gui.json"), "w") as f:
    json.dump(result, f)


def close(caller, event):
    # Once the event loop runs: close the main window as a window manager would, so
    # ParaView exits through its normal shutdown (as gui_session.py does).
    from vtkillum_paraview import x11

    with x11.Display() as display:
        display.request_close(display.find_window("ParaView"))


interactor = GetActiveViewOrCreate("RenderView").GetRenderWindow().GetInteractor()
interactor.AddObserver("TimerEvent", close)
interactor.CreateOneShotTimer(500)
'''


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The test files (a rotated grid in every format) and what read_volume makes of each."""
    from test_readers import write_dicom_series
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkCommonMath import vtkMatrix4x4
    from vtkmodules.vtkIOImage import vtkMetaImageWriter, vtkNIFTIImageWriter

    from vtkillum.cli import write_volume
    from vtkillum.core.volume import Volume
    from vtkillum.io.convert import add_point_array
    from vtkillum.io.readers import read_volume

    data = tmp_path_factory.mktemp("medical")
    rng = np.random.default_rng(32)
    values = rng.permutation(np.prod(SHAPE)).reshape(SHAPE).astype(np.float32)
    volume = Volume(values, SPACING, ORIGIN, ROTATION)
    write_volume(volume, data / "ct.nii.gz", frame="LPS")
    write_volume(volume, data / "ct.mha", frame="LPS")
    # NRRD in RAS (the reader converts to LPS), gzip encoded, float.
    ras = np.diag([-1.0, -1.0, 1.0])
    dirs = " ".join("(" + ",".join(f"{v:.17g}" for v in col) + ")"
                    for col in (ras @ ROTATION * SPACING).T)
    header = ("NRRD0004\ntype: float\ndimension: 3\nspace: right-anterior-superior\n"
              f"sizes: {' '.join(map(str, SHAPE))}\nspace directions: {dirs}\n"
              f"space origin: ({','.join(f'{v:.17g}' for v in ras @ ORIGIN)})\n"
              "kinds: domain domain domain\nendian: little\nencoding: gzip\n\n")
    import gzip

    (data / "ct.nrrd").write_bytes(header.encode() + gzip.compress(
        values.astype("<f4").tobytes(order="F")))
    # A DICOM series: rows and columns along the rotation's first two axes.
    write_dicom_series(data / "series", values.astype(np.int16), SPACING, ORIGIN,
                       ROTATION[:, 0], ROTATION[:, 1], slope=2.0, intercept=-10.0)
    # A 4-D NIfTI: 3 volumes (v, v + 100, v + 200), 2.5 s apart, placed by an sform.
    image = vtkImageData()
    image.SetDimensions(*SHAPE)
    add_point_array(image, "t", np.stack([values + 100 * t for t in range(3)], -1), set_active=True)
    affine = vtkMatrix4x4()
    for r in range(3):
        for c in range(3):
            affine.SetElement(r, c, (ras @ ROTATION * SPACING)[r, c])
        affine.SetElement(r, 3, (ras @ ORIGIN)[r])
    writer = vtkNIFTIImageWriter()
    writer.SetInputData(image)
    writer.SetTimeDimension(3)
    writer.SetTimeSpacing(2.5)
    writer.SetSFormMatrix(affine)
    writer.SetFileName(str(data / "t4.nii.gz"))
    writer.Write()
    # Three components per voxel, and a NaN sample.
    rgb = np.stack([values, 2 * values, values[::-1]], -1)
    from vtkillum.io.convert import image_data_from_volume

    for name, array in (("rgb", rgb), ("nan", np.where(values == 7, np.nan, values))):
        image = image_data_from_volume(volume)
        image.GetPointData().RemoveArray("scalars")
        add_point_array(image, name, array.astype(np.float32), set_active=True)
        writer = vtkMetaImageWriter()
        writer.SetInputData(image)
        writer.SetFileName(str(data / f"{name}.mha"))
        writer.Write()
    # Bad files.
    (data / "garbage.nii.gz").write_bytes(b"this is not a NIfTI file\n" * 20)
    (data / "truncated.nrrd").write_bytes(header.encode() + b"\x1f\x8b\x08\x00cut")
    expected = {name: read_volume(data / relative) for name, (relative, _) in CASES.items()}
    return data, expected


@pytest.fixture(scope="module")
def run(files, tmp_path_factory):
    """Run the pvbatch script once (as conftest's ``pvbatch_summary`` does, with the
    data directory and cases as arguments); returns data, expected, out, summary, log."""
    data, expected = files
    script = tmp_path_factory.mktemp("reader_script") / "pvbatch_reader.py"
    script.write_text(PVBATCH_SCRIPT)
    out = tmp_path_factory.mktemp("reader_out")
    proc, log = pvbatch_env.run_pvbatch_logged(
        script, data, out, ROOT / "paraview_plugin" / "vtkillum_plugin.py",
        json.dumps(CASES), json.dumps(BAD), shim_dir=tmp_path_factory.mktemp("pvshim"),
        timeout=300)
    assert proc.returncode == 0 and (out / "summary.json").exists(), log[-4000:]
    return data, expected, out, json.loads((out / "summary.json").read_text()), log


def load(out, name):
    return dict(np.load(out / f"{name}.npz"))


@pytest.mark.parametrize("name", list(CASES))
def test_paraview_holds_what_vtkillum_reads(run, name):
    """Dimensions, spacing, origin, direction matrix and values equal read_volume's."""
    _, expected, out, summary, _ = run
    got, want = load(out, name), expected[name]
    assert summary["cases"][name]["class"] == "vtkImageData"
    np.testing.assert_array_equal(got["dims"], want.dims)
    np.testing.assert_allclose(got["spacing"], want.spacing, rtol=1e-6)
    np.testing.assert_allclose(got["origin"], want.origin, atol=1e-5)
    np.testing.assert_allclose(got["direction"], want.direction, atol=1e-6)
    np.testing.assert_array_equal(got["scalars"], want.scalars.reshape(-1, order="F"))
    # And what read_volume gives is the file's grid (the geometry written).
    np.testing.assert_allclose(want.direction, ROTATION, atol=1e-5)
    np.testing.assert_allclose(want.origin, ORIGIN, atol=1e-4)
    # ParaView's bounds are those of the rotated grid (its corners), not of an unrotated box.
    corners = np.array([[i, j, k] for i in (0, SHAPE[0] - 1) for j in (0, SHAPE[1] - 1)
                        for k in (0, SHAPE[2] - 1)]) * SPACING @ ROTATION.T + ORIGIN
    np.testing.assert_allclose(got["bounds"][0::2], corners.min(0), atol=1e-4)
    np.testing.assert_allclose(got["bounds"][1::2], corners.max(0), atol=1e-4)


def test_readers_are_offered_for_their_files(run):
    """.nii.gz opens with the plugin's reader by default (ParaView has none); for the
    formats ParaView reads itself (without the direction) the plugin's reader is offered
    too (the GUI asks which one), and the DICOM file reads the whole series."""
    _, _, _, summary, _ = run
    cases = summary["cases"]
    assert cases["nifti"]["default_reader"] == "vtkIllumMedicalImageReader"
    assert cases["nifti"]["proxy"] == "vtkIllumMedicalImageReader"
    assert cases["nifti"]["array"] == "ct"
    for name in ("nrrd", "metaimage", "dicom_file"):
        assert "vtkIllumMedicalImageReader" in cases[name]["possible"], name
    assert cases["dicom_dir"]["proxy"] == "vtkIllumDICOMDirectoryReader"


def test_state_file_keeps_the_reader(run):
    _, _, _, summary, _ = run
    assert summary["state"] == {"proxy": "vtkIllumMedicalImageReader",
                                "points": int(np.prod(SHAPE))}


def test_4d_nifti_has_a_time_step_per_volume(run):
    data, _, out, summary, _ = run
    from vtkillum.io.readers import read_volume

    assert summary["t4"]["times"] == [0.0, 2.5, 5.0]
    first = read_volume(data / "t4.nii.gz")  # read_volume: the first volume
    for t in range(3):
        got = load(out, f"t4_{t}")
        np.testing.assert_allclose(got["direction"], first.direction, atol=1e-6)
        np.testing.assert_allclose(got["origin"], first.origin, atol=1e-5)
        np.testing.assert_allclose(got["scalars"], first.scalars.reshape(-1, order="F") + 100 * t)


def test_light_transmittance_runs_on_the_nifti(run):
    _, _, out, summary, _ = run
    lit = summary["lit"]
    assert {"transmittance", "fluence", "ct"} <= set(lit["arrays"])
    assert lit["dims"] == list(SHAPE)
    low, high = lit["transmittance_range"]
    assert 0.0 <= low < high <= 1.0 + 1e-6
    shot = np.asarray(Image.open(out / "lit.png").convert("RGB")).astype(float)
    assert shot.std() > 3.0, "the lit volume draws nothing"


def pixel_box(corners):
    """Pixel bounding box (row min, row max, col min, col max) of world points in the
    script's view (parallel, along -z, scale 40, 240 pixels)."""
    cols, rows = 120 + 3 * corners[:, 0], 120 - 3 * corners[:, 1]
    return np.array([rows.min(), rows.max(), cols.min(), cols.max()])


def mask_box(out, name):
    shot = np.asarray(Image.open(out / f"{name}.png").convert("L")).astype(float)
    rows, cols = np.nonzero(shot > 8)  # the background is black
    assert rows.size, f"{name}: nothing drawn"
    return np.array([rows.min(), rows.max(), cols.min(), cols.max()])


def test_volume_is_drawn_where_the_oriented_grid_is(run):
    """ParaView 5.11's volume mapper honours the direction matrix: the volume covers the
    rotated grid's projection, not the box the grid would fill without its direction.
    (Its Outline representation does not: see the README.)"""
    _, _, out, _, _ = run
    index = np.array([[i, j, k] for i in (0, SHAPE[0] - 1) for j in (0, SHAPE[1] - 1)
                      for k in (0, SHAPE[2] - 1)]) * SPACING
    rotated, unrotated = pixel_box(index @ ROTATION.T + ORIGIN), pixel_box(index + ORIGIN)
    for name in ("volume_fixed", "lit_fixed"):  # ParaView's volume, the illuminated one
        drawn = mask_box(out, name)
        assert np.abs(drawn - rotated).max() <= 3, (name, drawn, rotated)
        assert np.abs(drawn - unrotated).max() > 10, (name, drawn, unrotated)


@pytest.mark.parametrize("name,options,what", [
    ("rgb", {"component": "magnitude"}, "their magnitude (Euclidean norm) is read"),
    ("nan", {"nan_policy": "fill"}, "NaN/Inf samples were replaced by the smallest finite"),
])
def test_components_and_nan_are_read_with_a_warning(run, name, options, what):
    """What ParaView has no setting for is read as vtkillum would be told to, with one
    warning naming the file."""
    data, _, out, _, log = run
    from vtkillum.io.readers import read_volume

    want = read_volume(data / f"{name}.mha", **options)
    got = load(out, name)
    np.testing.assert_allclose(got["direction"], ROTATION, atol=1e-6)
    np.testing.assert_allclose(got["scalars"], want.scalars.reshape(-1, order="F"), rtol=1e-6)
    section = log.split(f"@@warn {name}\n", 1)[1].split("@@", 1)[0]
    assert f"vtkIllum Medical Image Reader: {data / name}.mha: " in section, section
    assert what in section and "Traceback" not in section, section


@pytest.mark.parametrize("name,what", [
    ("garbage", "garbage.nii.gz: not a readable NIfTI file"),
    ("truncated_nrrd", "truncated.nrrd: the NRRD data (gzip encoding) is corrupt or truncated"),
    ("missing", "missing.nii.gz: no such file or directory"),
])
def test_bad_files_give_one_clear_line(run, name, what):
    _, _, _, summary, log = run
    assert summary["bad"][name] == {"points": 0}
    section = log.split(f"@@bad {name}\n", 1)[1].split("@@", 1)[0]
    assert section.count("vtkIllum Medical Image Reader: ") == 1 and what in section, section
    # Nothing else: no traceback, no VTK executive dump.
    assert "Traceback" not in section and "File \"" not in section, section
    assert "returned failure" not in section and "ERR|" not in section, section


def test_gui_opens_a_nifti(files, tmp_path):
    """The real GUI (``paraview --script``): the reader is in File → Open's filter list
    and OpenDataFile of a .nii.gz reads it."""
    if shutil.which("paraview") is None:
        pytest.skip("paraview not found")
    data, _ = files
    script = tmp_path / "gui_reader.py"
    script.write_text(textwrap.dedent(GUI_SCRIPT))
    env = pvbatch_env.pvbatch_environment(pvbatch_env.make_shim_dir(tmp_path / "shim"))
    env.update(VTKILLUM_GUI_OUT=str(tmp_path), VTKILLUM_DATA=str(data),
               VTKILLUM_PLUGIN=str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"),
               XDG_CONFIG_HOME=str(tmp_path / "config"))
    env.setdefault("QT_QPA_PLATFORM", "xcb")
    for _attempt in range(2):
        proc = subprocess.Popen(["xvfb-run", "-a", "paraview", "--dr", f"--script={script}"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
        try:
            log, _ = proc.communicate(timeout=240)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            log = proc.communicate()[0] + "\n[killed]"
        if "bad X server connection" not in log:
            break
    result_file = tmp_path / "gui.json"
    assert result_file.exists(), log[-4000:]
    assert proc.returncode == 0, log[-4000:]
    result = json.loads(result_file.read_text())
    assert "error" not in result, result.get("error")
    assert result["can_read"] and result["reader"] == "vtkIllumMedicalImageReader"
    assert "*.nii.gz" in result["filters"]
    assert "Medical images, oriented (vtkIllum" in result["filters"]
    assert result["points"] == int(np.prod(SHAPE))
    assert result["series_points"] == int(np.prod(SHAPE))
    assert result["series_menu"] == "vtkIllum"
