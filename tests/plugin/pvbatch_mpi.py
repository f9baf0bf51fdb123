"""pvbatch script driven by ``test_mpi.py``: every vtkIllum filter on ParaView's MPI engine.

Run as ``mpirun -np N pvbatch pvbatch_mpi.py OUT`` (and once with one rank, the
reference). A Wavelet split into pieces across the ranks is illuminated by each
filter with two lights (a diagonal directional light and a point light inside the
volume); every filter's output is written as a parallel ``.pvti`` (one piece per
rank) so the test can compare it with the one-rank result, and the baked RGBA route
(``ShowIlluminated``) and the render view are screenshot. ``summary.json`` lists what
was written and what ParaView printed about the parallel mode.
"""

import json
import sys
from pathlib import Path

from paraview import simple

OUT = Path(sys.argv[1])
PLUGIN = Path(__file__).resolve().parents[2] / "paraview_plugin" / "vtkillum_plugin.py"
simple.LoadPlugin(str(PLUGIN), ns=globals())
import pvbatch_env  # noqa: E402  (paraview_plugin, on the path with the plugin)
import vtkillum_plugin  # noqa: E402  (loaded by LoadPlugin above)
from paraview.modules.vtkRemotingCore import vtkProcessModule  # noqa: E402

#: Filter label -> settings small enough for a CPU (seeds fixed: the Monte Carlo filters
#: give the same estimator on every rank).
FILTERS = {
    "vtkIllum Light Transmittance": {},
    "vtkIllum Convection-Diffusion Light": {"LightVolumeScale": 1.0},
    "vtkIllum Ambient Extinction": {"Radius": 2.0},
    "vtkIllum Photon Density": {"Photons": 2000},
    "vtkIllum Many Lights": {"Count": 8, "AVSMResolution": 8},
    "vtkIllum Optical Properties": None,
}
LIGHTS = [0, 1, 0.6, -0.4, 1, 1, 1, 0,   # directional, diagonal
          1, 4, -3, 2, 30, 30, 30, 0]    # point light inside the volume

summary = {"ranks": vtkProcessModule.GetProcessModule().GetNumberOfLocalPartitions(),
           "outputs": {}, "screenshots": {}}
source = simple.Wavelet()
source.WholeExtent = [-10, 10, -10, 10, -10, 10]
view = simple.CreateRenderView()
view.ViewSize = [200, 200]
view.OrientationAxesVisibility = 0
view.Background = [0, 0, 0]
if hasattr(view, "UseColorPaletteForBackground"):
    view.UseColorPaletteForBackground = 0
view.CameraPosition = [0, 0, 70]
view.CameraFocalPoint = [0, 0, 0]
view.CameraViewUp = [0, 1, 0]
if summary["ranks"] > 1 and not view.GetClientSideObject().GetRemoteRenderingAvailable():
    # A rank could not reach the X server when ParaView probed it (Xvfb refuses a few
    # per cent of simultaneous connections). ParaView 5.11 then waits forever in the first
    # volume render; end at once, for run_pvbatch_logged to try again.
    print(pvbatch_env.NO_REMOTE_RENDERING, flush=True)
    sys.exit(75)

for k, (label, settings) in enumerate(FILTERS.items()):
    make = globals()[label.replace(" ", "").replace("-", "")]
    lit = make(Input=source)
    lit.Scalars = ["POINTS", "RTData"]
    if settings is not None:
        lit.Lights = LIGHTS
        for name, value in settings.items():
            setattr(lit, name, value)
    name = f"f{k}"
    simple.SaveData(str(OUT / f"{name}.pvti"), proxy=lit)
    summary["outputs"][label] = f"{name}.pvti"
    if settings is None:
        continue
    display = vtkillum_plugin.ShowIlluminated(lit, view)
    simple.Render(view)
    simple.SaveScreenshot(str(OUT / f"{name}_rgba.png"), view, ImageResolution=[200, 200])
    simple.Hide(lit, view)
    summary["screenshots"][label] = f"{name}_rgba.png"

# The Properties panel's switch: Distributed off runs the whole volume on every rank.
switched = globals()["vtkIllumAmbientExtinction"](Input=source)
switched.Scalars = ["POINTS", "RTData"]
switched.Lights = LIGHTS
switched.Radius = 2.0
switched.Distributed = 0
simple.SaveData(str(OUT / "switched_off.pvti"), proxy=switched)
summary["switched_off"] = "switched_off.pvti"

# The render view's own (per-sample) display of a filter: lit on one rank; on several
# ranks ParaView's own volume on every rank (never half lit) and one message.
lit = globals()["vtkIllumLightTransmittance"](Input=source)
lit.Scalars = ["POINTS", "RTData"]
lit.Lights = LIGHTS
shown = simple.Show(lit, view)
simple.ColorBy(shown, ("POINTS", "RTData"))
simple.Render(view)
simple.SaveScreenshot(str(OUT / "render_view.png"), view, ImageResolution=[200, 200])
summary["render_view"] = "render_view.png"
from vtkillum_paraview import display as _display  # noqa: E402

summary["render_view_lit"] = bool(_display._views)
simple.Delete(view)
del view
(OUT / "summary.json").write_text(json.dumps(summary, indent=1))
