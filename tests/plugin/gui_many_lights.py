"""vtkIllum Many Lights applied in the real ParaView GUI, driven by ``test_many_lights_pv.py``.

Run as ``xvfb-run -a paraview --dr --script=gui_many_lights.py
--test-script=gui_many_lights.xml`` with the environment of
``paraview_plugin/pvbatch_env.py`` and ``VTKILLUM_GUI_OUT`` naming an output directory.
The test player clicks Sources -> Wavelet, Apply, Filters -> vtkIllum -> vtkIllum Many
Lights, Apply (the GUI's Apply shows every output port it is told to); this script then,
from one-shot timers of the render view (the GUI's event loop in between):

1. waits until the filter is shown and records which of its ports have a visible
   display;
2. edits the colours of the colour map (opacity unchanged), renders, and records the
   warp kernels launched (``warp.launch`` counted);
3. shows the virtual lights as the Pipeline Browser's eye does (``Show`` on port 1);
4. writes ``summary.json`` and ``done`` and closes the window.

Warnings of ParaView's Output Messages are echoed on the terminal; the markers
``=== stage`` this script prints to stderr split them by stage for the test.
"""

import collections
import json
import os
import sys
import time
import traceback
from pathlib import Path

from paraview import simple

OUT = Path(os.environ["VTKILLUM_GUI_OUT"])
ROOT = Path(os.environ["VTKILLUM_ROOT"])  # ``paraview --script`` defines no __file__
sys.path.insert(0, str(ROOT / "paraview_plugin"))
from vtkillum_paraview import x11

summary = {"errors": [], "launches": {}}
state = {}
launches = collections.Counter()


def stage(name: str) -> None:
    print(f"=== {name}", file=sys.stderr, flush=True)


def view():
    return simple.GetActiveViewOrCreate("RenderView")


def load_plugin():
    simple.LoadPlugin(str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"), ns=globals())
    import warp as wp

    launch = wp.launch

    def counting(kernel, *args, **kwargs):
        launches[getattr(kernel, "key", str(kernel))] += 1
        return launch(kernel, *args, **kwargs)

    wp.launch = counting
    stage("apply")


def step_applied():
    """Wait (at most two minutes) for the clicked filter's display, then record the ports."""
    many = simple.FindSource("vtkIllumManyLights1")
    rep = view().SMProxy.FindRepresentation(many.SMProxy, 0) if many is not None else None
    if rep is None and time.monotonic() - state.setdefault("since", time.monotonic()) < 120:
        return "again"
    simple.Render(view())
    state["many"] = many
    summary["displays_after_apply"] = [
        bool(r) and bool(simple.servermanager._getPyProxy(r).Visibility)
        for r in (view().SMProxy.FindRepresentation(many.SMProxy, p) for p in range(2))]
    summary["launches"]["apply"] = dict(launches)
    stage("colour")
    return None


def step_colour_edit():
    launches.clear()
    lut = simple.GetColorTransferFunction("RTData")
    points = list(lut.RGBPoints)
    lut.RGBPoints = [v if i % 4 == 0 else (1.0, 0.4, 0.2)[i % 4 - 1]
                     for i, v in enumerate(points)]
    simple.Render(view())
    summary["launches"]["colour"] = dict(launches)
    stage("show virtual lights")


def step_show_virtual_lights():
    """What the Pipeline Browser's eye does for port 1."""
    from paraview.modules.vtkRemotingViews import vtkSMParaViewPipelineControllerWithRendering

    many = state["many"]
    controller = vtkSMParaViewPipelineControllerWithRendering()
    controller.Show(many.SMProxy, 1, view().SMProxy)
    simple.Render(view())
    rep = view().SMProxy.FindRepresentation(many.SMProxy, 1)
    summary["virtual_lights_shown"] = bool(rep) and \
        bool(simple.servermanager._getPyProxy(rep).Visibility)
    stage("end")


def step_finish():
    (OUT / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    (OUT / "done").write_text("the GUI session reached its end\n")
    with x11.Display() as display:
        display.request_close(display.find_window("ParaView"))


STEPS = [step_applied, step_colour_edit, step_show_virtual_lights, step_finish]


def run_next(interactor, event=None):
    if not STEPS or state.get("running"):
        return
    step = STEPS[0]
    state["running"] = True
    try:
        if step() == "again":
            interactor.CreateOneShotTimer(600)
            return
        STEPS.pop(0)
    except Exception:  # noqa: BLE001 - recorded; the pytest side fails on it
        summary["errors"].append(f"{step.__name__}: {traceback.format_exc()}")
        STEPS[:] = [] if step is step_finish else [step_finish]
    finally:
        state["running"] = False
    if STEPS:
        interactor.CreateOneShotTimer(600)


OUT.mkdir(parents=True, exist_ok=True)
try:
    load_plugin()
    _interactor = view().GetRenderWindow().GetInteractor()
    _interactor.AddObserver("TimerEvent", run_next)
    _interactor.CreateOneShotTimer(500)
except Exception:  # noqa: BLE001 - recorded; the pytest side fails on it
    summary["errors"].append(f"driver: {traceback.format_exc()}")
    step_finish()
