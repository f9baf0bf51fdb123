"""pvbatch script driven by ``test_refraction_ux.py``: what a new user of vtkIllum Refraction
Render meets in pvpython.

Run as ``xvfb-run -a pvbatch pvbatch_refraction_ux.py OUT_DIR`` with the environment of
``paraview_plugin/pvbatch_env.py``. Records to ``OUT_DIR/summary.json`` (and pictures);
the pytest side judges.

1. Table properties given a list that is not a whole number of rows (RefractiveIndex,
   MediumColor, and a Lights table): refused with an error, the previous value kept in
   the property and in the filter, the filter not modified; a good value still goes in.
2. The picture shown in the 3D view beside its input (as the GUI's Apply shows it): it
   faces the camera it was rendered from, at the data's size.
3. ShowRendered without a view: the active render view is reused (no new view).
"""

import json
import sys
from pathlib import Path

from paraview import simple

OUT = Path(sys.argv[1])
OUT.mkdir(parents=True, exist_ok=True)
ROOT = Path(__file__).resolve().parents[2]
simple.LoadPlugin(str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"), ns=globals())
import numpy as np
import vtkillum_plugin as plugin

summary = {}
wavelet = simple.Wavelet(registrationName="Wavelet1")
wavelet.WholeExtent = [-8, 8, -8, 8, -8, 8]
refraction = vtkIllumRefractionRender(Input=wavelet)  # noqa: F821 (from LoadPlugin)
refraction.ImageSize = [48, 40]
refraction.Exposure = 20.0
refraction.RefractiveIndex = [37.0, 1.0, 276.0, 1.3]
refraction.MediumColor = [37.0, 1.0, 1.0, 1.0, 276.0, 0.9, 0.6, 0.3]
vtk_filter = refraction.GetClientSideObject()


def table_record(proxy, name, bad, getter=None):
    before = list(proxy.GetPropertyValue(name))
    obj = proxy.GetClientSideObject()
    rows_before = getter(obj) if getter else None
    mtime = obj.GetMTime()
    print(f"--- setting {name} to {bad}", file=sys.stderr, flush=True)
    setattr(proxy, name, bad)
    print(f"--- {name} set", file=sys.stderr, flush=True)
    return {"before": before, "after": list(proxy.GetPropertyValue(name)),
            "rows_before": rows_before, "rows_after": getter(obj) if getter else None,
            "filter_modified": obj.GetMTime() != mtime}


def points(obj):
    return [list(map(float, row)) for row in obj.GetRefractiveIndexPoints()]


def medium(obj):
    return [list(map(float, row)) for row in obj.GetMediumColorPoints()]


summary["eta_odd"] = table_record(refraction, "RefractiveIndex", [0.0, 1.0, 1.0], points)
summary["eta_one_number"] = table_record(refraction, "RefractiveIndex", 1.5, points)
summary["medium_short"] = table_record(refraction, "MediumColor", [0.0, 1.0, 1.0], medium)
transmittance = vtkIllumLightTransmittance(Input=wavelet)  # noqa: F821 (from LoadPlugin)
summary["lights_nine"] = table_record(transmittance, "Lights",
                                      [0, 1, -1, -1, 1, 1, 1, 0, 5])
refraction.RefractiveIndex = [37.0, 1.0, 276.0, 1.5]  # a good value still goes in
summary["eta_good"] = points(vtk_filter)
refraction.RefractiveIndex = []  # an empty table (the default, eta = 1) is a whole table
summary["eta_empty"] = points(vtk_filter)
refraction.RefractiveIndex = [37.0, 1.0, 276.0, 1.3]
simple.Delete(transmittance)

# --- 2. shown in the 3D view beside the data, as Apply shows it -------------------------------
view = simple.GetActiveViewOrCreate("RenderView")
view.ViewSize = [400, 300]
view.OrientationAxesVisibility = 0
volume = simple.Show(wavelet, view)
volume.SetRepresentationType("Outline")
view.CameraPosition = [40.0, -30.0, 50.0]
view.CameraFocalPoint = [0.0, 0.0, 0.0]
view.CameraViewUp = [0.0, 0.0, 1.0]
plugin.CopyViewCamera(refraction, view)
picture = simple.Show(refraction, view)
simple.Render(view)
image = vtk_filter.GetOutputDataObject(0)
matrix = image.GetDirectionMatrix()
summary["shown"] = {
    "representation": str(picture.Representation).strip("'"),
    "map_scalars": int(picture.MapScalars),
    "error": vtk_filter.GetLastError(),
    "place_facing_camera": (int(refraction.GetPropertyValue("PlaceFacingCamera"))
                            if refraction.GetProperty("PlaceFacingCamera") else None),
    "bounds": list(refraction.GetDataInformation().GetBounds()),
    "data_bounds": list(wavelet.GetDataInformation().GetBounds()),
    "normal": [matrix.GetElement(i, 2) for i in range(3)],
    "up": [matrix.GetElement(i, 1) for i in range(3)],
    "view_direction": list(np.subtract(view.CameraFocalPoint, view.CameraPosition)),
    "view_up": list(view.CameraViewUp),
    "spacing": list(image.GetSpacing()),
}
simple.SaveScreenshot(str(OUT / "picture_in_3d_view.png"), view, ImageResolution=[400, 300])
view.CameraPosition = [60.0, 40.0, 20.0]  # orbit: the picture is a card in the scene
simple.Render(view)
simple.SaveScreenshot(str(OUT / "picture_in_3d_view_orbit.png"), view,
                      ImageResolution=[400, 300])

# --- 3. ShowRendered without a view: the active render view -----------------------------------
views_before = len(simple.GetViews())
simple.SetActiveView(view)
display = plugin.ShowRendered(refraction)
simple.Render(view)
summary["show_rendered"] = {
    "views_before": views_before, "views_after": len(simple.GetViews()),
    "same_view": simple.GetActiveView().GetGlobalID() == view.GetGlobalID(),
    "representation": str(display.Representation).strip("'"),
    "map_scalars": int(display.MapScalars),
    "input_visible": int(simple.GetDisplayProperties(wavelet, view).Visibility),
    "interaction_mode": str(view.InteractionMode).strip("'"),
    "camera_direction": list(np.subtract(view.CameraFocalPoint, view.CameraPosition)),
}
simple.SaveScreenshot(str(OUT / "show_rendered.png"), view, ImageResolution=[480, 400])
rgb = image.GetPointData().GetArray("refraction_rgb")
summary["picture_std"] = float(np.std([rgb.GetTuple3(i) for i in range(rgb.GetNumberOfTuples())]))
(OUT / "summary.json").write_text(json.dumps(summary, indent=1))
print("pvbatch_refraction_ux: done")
