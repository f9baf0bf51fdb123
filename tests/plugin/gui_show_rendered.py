"""``ShowRendered(f)`` without a view in the real ParaView GUI, after a ``SaveScreenshot``
(the sequence that once hung inside ``AssignViewToLayout``); driven by
``test_refraction_ux.py``.

Run as ``xvfb-run -a paraview --dr --script=gui_show_rendered.py`` with the environment
of ``paraview_plugin/pvbatch_env.py`` and ``VTKILLUM_GUI_OUT`` naming an output
directory. Each step runs from a one-shot timer of the render view's interactor, so the
GUI's event loop runs in between (as for a user typing in the Python shell). Writes
``summary.json`` and, last, the marker ``done``; then closes the main window.
"""

import json
import os
import sys
import time
import traceback
from pathlib import Path

from paraview import simple

OUT = Path(os.environ["VTKILLUM_GUI_OUT"])
ROOT = Path(os.environ["VTKILLUM_ROOT"])
sys.path.insert(0, str(ROOT / "paraview_plugin"))
from vtkillum_paraview import x11

#: Part of the main window's title ("ParaView 5.11.0", "ParaView 6.1.1"): the largest
#: top-level window whose title has it is the main window.
WINDOW_TITLE = "ParaView"

summary = {"errors": [], "steps": []}
state = {}


def log(message: str) -> None:
    summary["steps"].append(message)
    with open(OUT / "progress.txt", "a") as f:
        f.write(message + "\n")


def step_apply():
    """As a user's Apply: the wavelet and its refraction render shown in the 3D view."""
    simple.LoadPlugin(str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"), ns=globals())
    wavelet = simple.Wavelet(registrationName="Wavelet1")
    wavelet.WholeExtent = [-8, 8, -8, 8, -8, 8]
    refraction = vtkIllumRefractionRender(Input=wavelet)  # noqa: F821 (from LoadPlugin)
    refraction.ImageSize = [48, 40]
    refraction.Exposure = 20.0
    view = simple.GetActiveViewOrCreate("RenderView")
    simple.Show(wavelet, view).SetRepresentationType("Outline")
    summary["apply_representation"] = str(simple.Show(refraction, view).Representation)
    simple.Render(view)
    state.update(refraction=refraction, view=view)
    log("applied")


def step_screenshot():
    simple.SaveScreenshot(str(OUT / "before.png"), state["view"], ImageResolution=[400, 300])
    log("screenshot")


def step_show_rendered():
    import vtkillum_plugin

    views = len(simple.GetViews())
    started = time.monotonic()
    log("ShowRendered: start")
    display = vtkillum_plugin.ShowRendered(state["refraction"])
    simple.Render()
    summary["show_rendered"] = {
        "seconds": time.monotonic() - started, "views_before": views,
        "views_after": len(simple.GetViews()),
        "same_view": simple.GetActiveView().GetGlobalID() == state["view"].GetGlobalID(),
        "representation": str(display.Representation).strip("'"),
        "map_scalars": int(display.MapScalars)}
    log("ShowRendered: returned")


def step_after():
    simple.SaveScreenshot(str(OUT / "after.png"), simple.GetActiveView(),
                          ImageResolution=[400, 300])
    with x11.Display() as display:
        x11.write_png(OUT / "window.png", display.grab(display.find_window(WINDOW_TITLE)))
    log("after")


def step_finish():
    (OUT / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    (OUT / "done").write_text("done\n")
    with x11.Display() as display:
        display.request_close(display.find_window(WINDOW_TITLE))


STEPS = [step_apply, step_screenshot, step_show_rendered, step_after, step_finish]


def run_next(interactor, event=None):
    if not STEPS or state.get("running"):
        return
    step = STEPS.pop(0)
    state["running"] = True
    try:
        step()
    except Exception:  # recorded; the pytest side fails on it
        summary["errors"].append(f"{step.__name__}: {traceback.format_exc()}")
        if step is not step_finish:
            STEPS[:] = [step_finish]
    finally:
        state["running"] = False
    if STEPS:
        interactor.CreateOneShotTimer(600)


OUT.mkdir(parents=True, exist_ok=True)
try:
    _interactor = simple.GetActiveViewOrCreate("RenderView").GetRenderWindow().GetInteractor()
    _interactor.AddObserver("TimerEvent", run_next)
    _interactor.CreateOneShotTimer(500)
except Exception:
    summary["errors"].append(f"driver: {traceback.format_exc()}")
    step_finish()
