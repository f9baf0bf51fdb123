"""A session in the real ParaView GUI, driven by ``test_gui.py``.

Run as ``xvfb-run -a paraview --dr --script=gui_session.py --test-script=gui_menu.xml``
with the environment of ``paraview_plugin/pvbatch_env.py`` and ``VTKILLUM_GUI_OUT``
naming an output directory. The script runs inside the GUI's Python: it loads the
plugin; then ParaView's test player clicks through ``gui_menu.xml`` (Sources ->
Wavelet, Apply, Filters -> vtkIllum -> vtkIllum Light Transmittance, Apply, Filters ->
vtkIllum -> vtkIllum Refraction Render, Apply) while
the script plays a list of steps, each from a one-shot timer of the render view's
interactor, so that between two steps the GUI runs its event loop (builds the
Properties panel of the active source, paints the window) exactly as it does for a
user:

0. wait until the filters picked from the menu are shown; the refraction render (an
   image) is made active, its refractive-index and medium-colour tables are set, the
   view's camera copied in, and its picture checked;
1. every vtkIllum filter is created on a Wavelet, made active (the Properties
   panel is built for it), shown, a property is changed and applied;
2. the colour map of the coloured array is edited (a preset applied) and the
   picture taken before and after (``SaveScreenshot`` of the view);
3. a light of Type 2 is entered: the error must name the Lights row;
4. the state is saved (.pvsm), every vtkIllum filter deleted, the state loaded
   again and every filter selected again;
5. the whole window is grabbed from the X server (panels included).

It writes ``summary.json`` and, as its very last action, the marker ``done``, then
closes the main window like a window manager would, so that ParaView exits through
its normal shutdown. The pytest side asserts the exit status, the marker and the
pictures.
"""

import json
import os
import sys
import time
import traceback
from pathlib import Path

from paraview import simple

OUT = Path(os.environ["VTKILLUM_GUI_OUT"])
ROOT = Path(os.environ["VTKILLUM_ROOT"])  # ``paraview --script`` defines no __file__
PLUGIN = ROOT / "paraview_plugin" / "vtkillum_plugin.py"
sys.path.insert(0, str(ROOT / "paraview_plugin"))
from vtkillum_paraview import x11

#: Part of the main window's title ("ParaView 5.11.0", "ParaView 6.1.1"): the largest
#: top-level window whose title has it is the main window.
WINDOW_TITLE = "ParaView"

LABELS = ["vtkIllum Optical Properties", "vtkIllum Light Transmittance",
          "vtkIllum Convection-Diffusion Light", "vtkIllum Ambient Extinction",
          "vtkIllum Photon Density", "vtkIllum Many Lights"]
VIEW_SIZE = [400, 400]
summary = {"steps": [], "filters": {}, "errors": []}


def log(message: str) -> None:
    summary["steps"].append(message)
    with open(OUT / "progress.txt", "a") as f:
        f.write(message + "\n")


def constructor(label: str):
    return globals()[label.replace(" ", "").replace("-", "")]  # from LoadPlugin(ns=globals())


def preset(*names: str) -> str:
    """The first of ``names`` that is a colour-map preset of this ParaView ("Inferno
    (matplotlib)" in 5.x is "Inferno" in 6.x; ``ApplyPreset`` of an unknown name returns
    True in 5.11 and changes nothing)."""
    from paraview import servermanager

    presets = servermanager.vtkSMTransferFunctionPresets.GetInstance()
    found = [name for name in names if presets.HasPreset(name)]
    if not found:
        raise RuntimeError(f"none of the presets {names} exists in this ParaView")
    return found[0]


def view():
    return simple.GetActiveViewOrCreate("RenderView")


def grab_window(name: str) -> None:
    with x11.Display() as display:
        window = display.find_window(WINDOW_TITLE)
        image = display.grab(window)
    x11.write_png(OUT / name, image)
    summary.setdefault("window_grabs", []).append(name)


def swapped_volumes(v) -> int:
    """How many of the view's volumes the plugin draws illuminated."""
    from vtkillum_paraview import display

    hook = display._views.get(v.GetGlobalID())
    return 0 if hook is None else len(hook.volumes)


def vtkillum_sources() -> dict:
    return {name: proxy for (name, _), proxy in simple.GetSources().items()
            if proxy.GetXMLName().startswith("vtkIllum")}


# === the steps ==============================================================================
state = {}


def load_plugin_and_data():
    """Before the GUI plays ``gui_menu.xml`` (the menu clicks): the plugin and the CT file."""
    simple.LoadPlugin(str(PLUGIN), ns=globals())
    import numpy as np
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    from vtkillum.core.volume import Volume
    from vtkillum.data.procedural import ct_phantom
    from vtkillum.io.convert import image_data_from_volume

    phantom = ct_phantom(96)
    # A CT's partial-volume blur (about two voxels): the phantom's materials meet within one
    # voxel, whose terraces a sharp opacity peak would show as rings.
    values = phantom.scalars.astype(np.float64)
    for _ in range(2):
        for axis in range(3):
            padded = np.pad(values, [(1, 1) if a == axis else (0, 0) for a in range(3)], "edge")
            lo, hi = (padded.take(range(k, k + values.shape[axis]), axis) for k in (0, 2))
            values = 0.25 * (lo + 2 * values + hi)
    phantom = Volume(values.astype(np.float32), phantom.spacing, phantom.origin)
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(OUT / "ct_phantom.vti"))
    writer.SetInputData(image_data_from_volume(phantom, "density"))
    writer.Write()


def step_wait_for_the_menu_clicks():
    """``gui_menu.xml`` clicks Sources -> Wavelet, Apply, Filters -> vtkIllum -> vtkIllum Light
    Transmittance, Apply. Wait until that filter is shown (at most a minute)."""
    clicked = simple.FindSource("vtkIllumLightTransmittance1")
    shown = clicked is not None and simple.GetDisplayProperties(clicked, view()) is not None \
        and simple.GetDisplayProperties(clicked, view()).Visibility
    if not shown and time.monotonic() - state.setdefault("waiting_since", time.monotonic()) < 60:
        return "again"
    summary["menu_created"] = clicked.GetXMLLabel() if clicked is not None else None
    if clicked is not None:
        simple.Render(view())
        display = simple.GetDisplayProperties(clicked, view())
        summary["menu_display"] = {"representation": str(display.Representation).strip("'"),
                                   "color_array": list(display.ColorArrayName),
                                   "illuminated_volumes": swapped_volumes(view())}
        state.setdefault("proxies", {})["vtkIllum Light Transmittance"] = clicked
    log("menu clicks done")


def step_refraction_from_the_menu():
    """The vtkIllum Refraction Render the menu created (on the Light Transmittance): its
    Properties panel (the two tables), the tables edited, the view's camera copied in."""
    import numpy as np
    import vtkillum_plugin
    from vtkmodules.util.numpy_support import vtk_to_numpy

    clicked = simple.FindSource("vtkIllumRefractionRender1")
    if clicked is None and time.monotonic() - state.setdefault("refraction_since",
                                                               time.monotonic()) < 60:
        return "again"
    record = summary["refraction"] = {"created": clicked.GetXMLLabel() if clicked else None}
    if clicked is None:
        return None
    state.setdefault("proxies", {})["vtkIllum Refraction Render"] = clicked
    simple.SetActiveSource(clicked)  # the Properties panel is built for it
    display = simple.GetDisplayProperties(clicked, view())
    record["representation"] = str(display.Representation).strip("'")
    record["color_array"] = list(display.ColorArrayName)
    record["map_scalars"] = int(display.MapScalars)
    record["default_error"] = clicked.GetClientSideObject().GetLastError()

    def picture():
        clicked.UpdatePipeline()
        data = clicked.GetClientSideObject().GetOutputDataObject(0)
        if data.GetNumberOfPoints() == 0:
            return None
        return vtk_to_numpy(data.GetPointData().GetArray("refraction_rgb")).astype(float)

    record["default_dims"] = list(clicked.GetDataInformation().GetExtent())
    v = view()
    v.CameraPosition = [30.0, -50.0, 60.0]
    v.CameraFocalPoint = [0.0, 0.0, 0.0]
    v.CameraViewUp = [0.0, 0.0, 1.0]
    vtkillum_plugin.CopyViewCamera(clicked, v)
    clicked.LightDirection = [-0.3, 0.5, -0.8]
    clicked.ImageSize = [96, 80]
    clicked.Exposure = 20.0
    straight = picture()
    clicked.RefractiveIndex = [37.0, 1.0, 150.0, 1.0, 276.0, 1.6]
    clicked.MediumColor = [37.0, 1.0, 1.0, 1.0, 276.0, 0.9, 0.5, 0.2]
    bent = picture()
    record["camera_position"] = list(clicked.CameraPosition)
    record["pictures"] = None if straight is None or bent is None else {
        "straight_std": float(straight.std()), "bent_std": float(bent.std()),
        "difference": float(np.abs(bent - straight).mean()), "pixels": len(bent)}
    simple.Render(v)
    # The picture in a view of its own beside the 3D view (ShowRendered), for the grab.
    picture_view = simple.CreateRenderView()
    simple.AssignViewToLayout(picture_view, hint=0)
    vtkillum_plugin.ShowRendered(clicked, picture_view)
    simple.Hide(clicked, v)
    state["refraction_view"] = picture_view
    simple.SetActiveView(v)
    simple.SetActiveSource(clicked)
    simple.Render(v)
    simple.Render(picture_view)
    log("refraction render from the menu")


def step_grab_refraction():
    grab_window("window_refraction.png")
    picture_view = state.pop("refraction_view")
    layout = simple.GetLayout(picture_view)
    location = layout.GetViewLocation(picture_view) if layout is not None else None
    simple.Delete(picture_view)
    if location is not None:
        layout.Collapse(location)  # the split goes too: later grabs show one view
    simple.SetActiveView(view())
    log("window grabbed with the refraction render")


def step_window_size():
    with x11.Display() as display:  # room for the panels and the view
        display.move_resize(display.find_window(WINDOW_TITLE), 0, 0, 1600, 1000)


def step_setup():
    step_window_size()
    wavelet = simple.FindSource("Wavelet1") or simple.Wavelet(registrationName="Wavelet1")
    state["wavelet"] = wavelet
    v = view()
    v.ViewSize = VIEW_SIZE
    v.OrientationAxesVisibility = 0
    display = simple.Show(wavelet, v)
    display.SetRepresentationType("Outline")
    simple.Render(v)
    log("setup")


def make_create_step(label):
    def step():
        proxy = state.get("proxies", {}).get(label) or constructor(label)(Input=state["wavelet"])
        simple.SetActiveSource(proxy)  # the Properties panel is built for it
        display = simple.Show(proxy, view())
        simple.Render(view())
        state.setdefault("proxies", {})[label] = proxy
        summary["filters"][label] = {
            "representation": str(display.Representation),
            "color_array": list(display.ColorArrayName),
            "arrays": [proxy.PointData[i].GetName() for i in range(len(proxy.PointData))],
        }
        log(f"created {label}")
    return step


def make_edit_step(label):
    def step():
        proxy = state["proxies"][label]
        simple.SetActiveSource(proxy)
        proxy.Albedo = 0.6
        proxy.UpdatePipeline()
        simple.Render(view())
        summary["filters"][label]["albedo_after_edit"] = float(proxy.Albedo)
        log(f"edited {label}")
    return step


def step_show_one():
    """Hide all but the Light Transmittance volume; picture; edit the colour map; picture."""
    lt = state["proxies"]["vtkIllum Light Transmittance"]
    for label, proxy in state["proxies"].items():
        if proxy is not lt:
            simple.Hide(proxy, view())
    simple.Hide(state["wavelet"], view())
    simple.SetActiveSource(lt)
    v = view()
    v.CameraPosition = [0.0, -60.0, 25.0]
    v.CameraFocalPoint = [0.0, 0.0, 0.0]
    v.CameraViewUp = [0.0, 0.0, 1.0]
    simple.Render(v)
    simple.SaveScreenshot(str(OUT / "view_before_colour_edit.png"), v, ImageResolution=VIEW_SIZE)
    misses = lt.GetClientSideObject().GetCacheStatistics().misses
    summary["illuminated_volumes_in_view"] = swapped_volumes(v)
    lut = simple.GetColorTransferFunction("RTData")
    lut.ApplyPreset(preset("Inferno (matplotlib)", "Inferno"), True)
    simple.GetOpacityTransferFunction("RTData").Points = [37.35, 0.0, 0.5, 0.0, 120.0, 0.0, 0.5, 0.0,
                                                          200.0, 0.3, 0.5, 0.0, 276.8, 1.0, 0.5, 0.0]
    simple.Render(v)
    simple.SaveScreenshot(str(OUT / "view_after_colour_edit.png"), v, ImageResolution=VIEW_SIZE)
    summary["recomputed_after_colour_edit"] = \
        lt.GetClientSideObject().GetCacheStatistics().misses - misses
    log("colour map edited")


def step_grab_1():
    grab_window("window_filters.png")
    log("window grabbed")


def step_bad_light():
    lt = state["proxies"]["vtkIllum Light Transmittance"]
    lt.Lights = [2, 1, 0, 0, 1, 1, 1, 0]
    lt.UpdatePipeline()
    summary["bad_light_error"] = lt.GetClientSideObject().GetLastError()
    lt.Lights = [0, 1, -1, -1, 1, 1, 1, 0]
    lt.UpdatePipeline()
    summary["good_light_error"] = lt.GetClientSideObject().GetLastError()
    log("bad light")


def step_save_delete():
    path = OUT / "session.pvsm"
    simple.SaveState(str(path))
    for name, proxy in vtkillum_sources().items():
        simple.Delete(proxy)
    summary["after_delete"] = sorted(vtkillum_sources())
    simple.Render(view())
    log("saved and deleted")


def step_load():
    # Everything goes, then the state comes back (the GUI builds its items again).
    for proxy in list(simple.GetSources().values()):
        simple.Delete(proxy)
    simple.LoadState(str(OUT / "session.pvsm"))
    summary["after_load"] = sorted(vtkillum_sources())
    log("state loaded")


def step_select_loaded():
    for name, proxy in vtkillum_sources().items():
        simple.SetActiveSource(proxy)
    lit = 0
    for v in simple.GetViews():
        if v.GetXMLName() == "RenderView":
            simple.Render(v)
            lit += swapped_volumes(v)
    summary["illuminated_volumes_after_load"] = lit
    log("loaded filters selected")


def step_grab_2():
    grab_window("window_after_load.png")
    log("window grabbed after load")


def step_ct():
    """A CT-like volume with Light Transmittance: the picture of the README."""
    for proxy in simple.GetSources().values():
        for v in simple.GetViews():
            simple.Hide(proxy, v)
    reader = simple.XMLImageDataReader(registrationName="ct_phantom.vti",
                                       FileName=[str(OUT / "ct_phantom.vti")])
    lit = constructor("vtkIllum Light Transmittance")(Input=reader)
    # A key light from the front left and above, a dim blue fill light from the right.
    lit.Lights = [0, 0.6, 0.9, -0.5, 1.0, 0.96, 0.9, 0, 0, -0.9, 0.2, 0.1, 0.25, 0.27, 0.35, 0]
    simple.SetActiveSource(lit)
    v = view()
    display = simple.Show(lit, v)
    lut = simple.GetColorTransferFunction("density")
    lut.RGBPoints = [0.0, 1.0, 1.0, 1.0, 0.3, 0.95, 0.75, 0.6, 0.5, 0.85, 0.45, 0.4,
                     0.65, 0.9, 0.8, 0.2, 0.9, 0.95, 0.93, 0.88, 1.0, 0.95, 0.93, 0.88]
    # Skin faint, the lesion, bone on a ramp as wide as the tissue-bone border.
    simple.GetOpacityTransferFunction("density").Points = [
        0.0, 0.0, 0.5, 0.0, 0.12, 0.0, 0.5, 0.0, 0.3, 0.05, 0.5, 0.0, 0.42, 0.0, 0.5, 0.0,
        0.58, 0.0, 0.5, 0.0, 0.65, 0.4, 0.5, 0.0, 0.7, 0.0, 0.5, 0.0,
        0.72, 0.0, 0.5, 0.0, 0.9, 0.8, 0.5, 0.0, 1.0, 0.9, 0.5, 0.0]
    v.ViewSize = [900, 800]
    v.CameraPosition = [-260.0, -520.0, 110.0]
    v.CameraFocalPoint = [0.0, 0.0, 0.0]
    v.CameraViewUp = [0.0, 0.0, 1.0]
    simple.Render(v)
    summary["ct"] = {"color_array": list(display.ColorArrayName),
                     "illuminated_volumes_in_view": swapped_volumes(v)}
    log("CT phantom shown")


def step_grab_ct():
    grab_window("window_ct.png")
    log("window grabbed with the CT phantom")


def step_finish():
    (OUT / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    (OUT / "done").write_text("the GUI session reached its end\n")
    with x11.Display() as display:
        display.request_close(display.find_window(WINDOW_TITLE))


STEPS = ([step_wait_for_the_menu_clicks, step_refraction_from_the_menu, step_grab_refraction,
          step_setup]
         + [make_create_step(label) for label in LABELS]
         + [make_edit_step(label) for label in LABELS[1:]]
         + [step_show_one, step_grab_1, step_bad_light, step_save_delete, step_load,
            step_select_loaded, step_grab_2, step_ct, step_grab_ct, step_finish])
if os.environ.get("VTKILLUM_GUI_ONLY_CT"):  # make_gui_screenshot.py: only the CT picture
    STEPS = [step_window_size, step_ct, step_grab_ct, step_finish]


# === the driver: one step per timer tick, the GUI's event loop in between ====================
def run_next(interactor, event=None):
    # A step that lets Qt process events (deleting a view, grabbing the window) may see a
    # timer event of its own interactor: never start a step inside another.
    if not STEPS or time.monotonic() < state.get("due", 0.0) or state.get("running"):
        return
    step = STEPS[0]
    state["running"] = True
    try:
        if step() == "again":  # not ready yet: the same step at the next tick
            interactor.CreateOneShotTimer(600)
            return
        STEPS.pop(0)
    except Exception:  # recorded; the pytest side fails on it
        STEPS.pop(0)
        summary["errors"].append(f"{step.__name__}: {traceback.format_exc()}")
        log(f"FAILED {step.__name__}")
        if step is not step_finish:
            STEPS[:] = [step_finish]
    finally:
        state["running"] = False
    state["due"] = time.monotonic() + 0.5
    if STEPS:
        interactor.CreateOneShotTimer(600)


OUT.mkdir(parents=True, exist_ok=True)
try:
    load_plugin_and_data()
    _interactor = view().GetRenderWindow().GetInteractor()
    _interactor.AddObserver("TimerEvent", run_next)
    _interactor.CreateOneShotTimer(500)
except Exception:
    summary["errors"].append(f"driver: {traceback.format_exc()}")
    step_finish()
