"""pvbatch script driven by ``test_many_lights_pv.py``: vtkIllum Many Lights in ParaView.

Run as ``xvfb-run -a pvbatch pvbatch_many_lights.py OUT_DIR`` with the environment of
``paraview_plugin/pvbatch_env.py``. It plays what a GUI user does and records, in
``OUT_DIR/summary.json``, what the pytest side judges (ParaView's warnings go to stderr,
which the test reads):

1. Wavelet -> vtkIllum Many Lights, shown the way the GUI's Apply shows a new filter
   (``ShowInPreferredView`` for every output port): which ports got a display;
2. a colour-only edit of the colour map (opacity unchanged), the same colour map set
   again, and an opacity edit, one render each: the warp kernels each one launched
   (``warp.launch`` is counted: same process, a builtin session);
3. the virtual lights shown with the Pipeline Browser's eye (``Show`` on port 1).
"""

import collections
import json
import sys
from pathlib import Path

import warp as wp
from paraview import simple
from paraview.modules.vtkRemotingViews import vtkSMParaViewPipelineControllerWithRendering

OUT = Path(sys.argv[1])
OUT.mkdir(parents=True, exist_ok=True)
ROOT = Path(__file__).resolve().parents[2]
simple.LoadPlugin(str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"), ns=globals())

launches = collections.Counter()
_launch = wp.launch


def counting_launch(kernel, *args, **kwargs):
    launches[getattr(kernel, "key", str(kernel))] += 1
    return _launch(kernel, *args, **kwargs)


wp.launch = counting_launch


def stage(name: str) -> None:
    """Mark the log (warnings printed after this line belong to ``name``)."""
    print(f"=== {name}", file=sys.stderr, flush=True)


summary = {"launches": {}}
source = simple.Wavelet(WholeExtent=[-7, 7, -7, 7, -7, 7])
many = vtkIllumManyLights(Input=source)  # noqa: F821 (from LoadPlugin)
many.Count = 32
many.AVSMResolution = 8
view = simple.CreateRenderView()
view.ViewSize = [200, 200]

stage("apply")
controller = vtkSMParaViewPipelineControllerWithRendering()
for port in range(2):  # what pqApplyBehavior does for each output port
    controller.ShowInPreferredView(many.SMProxy, port, view.SMProxy)
simple.Render(view)
summary["displays_after_apply"] = [
    bool(rep) and bool(simple.servermanager._getPyProxy(rep).Visibility)
    for rep in (view.SMProxy.FindRepresentation(many.SMProxy, port) for port in range(2))]
summary["launches"]["apply"] = dict(launches)
obj = many.GetClientSideObject()
state = obj.state



def scattered_range() -> list:
    """Per channel (min, max) of the filter's scattered fluence."""
    array = many.PointData["scattered_fluence"]
    return [list(array.GetRange(c)) for c in range(3)]


summary["scattered_range"] = {"apply": scattered_range()}
lut = simple.GetColorTransferFunction("RTData")
opacity = simple.GetOpacityTransferFunction("RTData")
points = list(lut.RGBPoints)
edited = []
for i in range(0, len(points), 4):  # new colours at the same nodes
    x = points[i]
    edited += [x, 1.0, 0.3 + 0.5 * (i % 8 == 0), 0.2]
for name, change in (("colour", lambda: setattr(lut, "RGBPoints", edited)),
                     ("same colour", lambda: setattr(lut, "RGBPoints", list(edited))),
                     ("opacity", lambda: setattr(opacity, "Points", [
                         p * 0.5 if i % 4 == 1 else p for i, p in enumerate(opacity.Points)]))):
    stage(name)
    launches.clear()
    change()
    simple.Render(view)
    summary["launches"][name] = dict(launches)
    summary.setdefault("scattered_range", {})[name] = scattered_range()
    if name == "colour":
        summary["state_kept_after_colour_edit"] = obj.state is state

stage("show virtual lights")
controller.Show(many.SMProxy, 1, view.SMProxy)  # the eye in the Pipeline Browser
simple.Render(view)
rep = view.SMProxy.FindRepresentation(many.SMProxy, 1)
summary["virtual_lights_shown"] = bool(rep) and bool(simple.servermanager._getPyProxy(rep).Visibility)
summary["virtual_lights_points"] = many.GetDataInformation(1).GetNumberOfPoints()
stage("end")
(OUT / "summary.json").write_text(json.dumps(summary, indent=1))
