"""ParaView's time controls step through a 4-D NIfTI as vtkillum does (issue 34).

A 4-D NIfTI (a ball moving along +x, 2.5 s between volumes) is opened in pvbatch with
the plugin's *vtkIllum Medical Image Reader*; the animation scene is moved to times on,
between, before and after the steps, and ParaView's data at each time must equal what
:class:`vtkillum.io.time_series.TimeSeriesSource` (the package's source, the CLI's
reading) gives at that time: the same step (at or before the time), the same values.
A *vtkIllum Light Transmittance* filter on the reader, stepped through twice by the
time controls, computes each step once: the second pass is served by its time cache.
"""

import json
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "paraview_plugin"))
import pvbatch_env  # noqa: E402

pytestmark = pytest.mark.plugin

SHAPE = (14, 10, 8)
STEPS = 3
DT = 2.5
#: Animation times asked for: steps, between them, before the first, after the last.
REQUESTS = [0.0, 2.5, 5.0, 1.0, 3.7, -1.0, 9.0]

SCRIPT = r'''
import json, sys
import numpy as np
from paraview import servermanager
from paraview.simple import *
from vtkmodules.util.numpy_support import vtk_to_numpy

nifti, out, plugin, requests = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
LoadPlugin(plugin, ns=globals())
reader = OpenDataFile(nifti)
reader.UpdatePipelineInformation()
scene = GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
summary = {"proxy": reader.GetXMLName(), "times": list(reader.TimestepValues),
           "scene_times": list(scene.TimeKeeper.TimestepValues), "steps": []}
for n, time in enumerate(requests):
    scene.AnimationTime = time  # the time controls
    reader.UpdatePipeline(time)
    image = servermanager.Fetch(reader)
    np.save(f"{out}/request_{n}.npy", vtk_to_numpy(image.GetPointData().GetScalars()))
    info = image.GetInformation()
    summary["steps"].append(info.Get(image.DATA_TIME_STEP()) if info.Has(image.DATA_TIME_STEP())
                            else None)

light = vtkIllumLightTransmittance(Input=reader)
light.Lights = [0, 1, 0, 0, 1, 1, 1, 0]
algorithm = light.GetClientSideObject()
for _ in range(2):  # forward twice through the time steps
    for time in summary["times"]:
        scene.AnimationTime = time
        light.UpdatePipeline(time)
stats = algorithm.GetCacheStatistics()
summary["cache"] = {"hits": stats.hits, "misses": stats.misses, "entries": stats.entries}
with open(f"{out}/summary.json", "w") as f:
    json.dump(summary, f)
'''


def ball(step: int) -> np.ndarray:
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in SHAPE), indexing="ij")
    r = np.sqrt((i - 4.0 - 2.0 * step) ** 2 + (j - 5.0) ** 2 + (k - 4.0) ** 2)
    return np.round(np.clip(500.0 * (4.0 - r), 0.0, 1000.0))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkIOImage import vtkNIFTIImageWriter

    from vtkillum.io.convert import add_point_array

    data = tmp_path_factory.mktemp("pv_series")
    image = vtkImageData()
    image.SetDimensions(*SHAPE)
    image.SetSpacing(1.0, 1.2, 1.5)
    add_point_array(image, "ball", np.stack([ball(t) for t in range(STEPS)], -1).astype(np.int16),
                    set_active=True)
    writer = vtkNIFTIImageWriter()
    writer.SetInputData(image)
    writer.SetTimeDimension(STEPS)
    writer.SetTimeSpacing(DT)
    writer.SetFileName(str(data / "moving.nii"))
    writer.Write()
    script = data / "pv_series.py"
    script.write_text(textwrap.dedent(SCRIPT))
    out = tmp_path_factory.mktemp("pv_series_out")
    proc, log = pvbatch_env.run_pvbatch_logged(
        script, data / "moving.nii", out, ROOT / "paraview_plugin" / "vtkillum_plugin.py",
        json.dumps(REQUESTS), shim_dir=tmp_path_factory.mktemp("pvshim"), timeout=300)
    assert proc.returncode == 0 and (out / "summary.json").exists(), log[-4000:]
    return data / "moving.nii", out, json.loads((out / "summary.json").read_text())


def test_paraview_times_are_vtkillums(run):
    from vtkillum.io.readers import time_steps

    path, _, summary = run
    assert summary["proxy"] == "vtkIllumMedicalImageReader"
    assert summary["times"] == time_steps(path) == [DT * t for t in range(STEPS)]
    assert summary["scene_times"] == summary["times"]


def test_each_time_shows_what_the_package_source_shows(run):
    """The reader in ParaView and TimeSeriesSource here: the same step for every time
    (the one at or before it), the same values."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    from vtkillum.io.time_series import TimeSeriesSource

    path, out, summary = run
    source = TimeSeriesSource(path)
    for n, time in enumerate(REQUESTS):
        source.UpdateTimeStep(time)
        image = source.GetOutputDataObject(0)
        step = image.GetInformation().Get(image.DATA_TIME_STEP())
        assert summary["steps"][n] == step, (time, summary["steps"][n], step)
        np.testing.assert_array_equal(np.load(out / f"request_{n}.npy"),
                                      vtk_to_numpy(image.GetPointData().GetScalars()))
    assert summary["steps"] == [0.0, 2.5, 5.0, 0.0, 2.5, 0.0, 5.0]


def test_time_controls_use_the_filters_time_cache(run):
    _, _, summary = run
    assert summary["cache"]["misses"] == STEPS
    assert summary["cache"]["hits"] >= STEPS - 1  # the pass back to step 0 and on
