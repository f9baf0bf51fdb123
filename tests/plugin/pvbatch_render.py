"""pvbatch script driven by ``test_render.py``: the illumination rendered in ParaView's view.

Run as ``xvfb-run -a pvbatch pvbatch_render.py OUT_DIR`` with the environment of
``paraview_plugin/pvbatch_env.py``. Writes screenshots, the filter output (.vti)
and ``render.json`` (the scene: camera, transfer function, lights) to OUT_DIR; the
pytest side renders the same scene with the plain-VTK ``IlluminatedVolume`` and
compares, and judges the other pictures.

1. A smoke plume, Light Transmittance, one directional light, Anisotropy 0: the
   render view's picture (``pv_g0.png``) and the filter output (``lit.vti``).
2. The same with Anisotropy 0.6 (``pv_g06.png``): the phase function at work.
3. The colour map edited (another preset) and the opacity function edited: the
   pictures change, the filter re-executed.
4. The display colours by ``fluence``: ParaView's own volume is drawn again.
5. The baked RGBA route (OutputRGBA, ShowIlluminated) of two filters in one view:
   each keeps its own opacity function.
6. Convection-Diffusion Light (scattering on), Ambient Extinction and Photon Density
   render too.
"""

import json
import sys
from pathlib import Path

from paraview import simple

OUT = Path(sys.argv[1])
OUT.mkdir(parents=True, exist_ok=True)
ROOT = Path(__file__).resolve().parents[2]
simple._DisableFirstRenderCameraReset()  # the camera is the scene's, see shot()
simple.LoadPlugin(str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"), ns=globals())
import vtkillum_plugin as plugin
from vtkillum_paraview import display as _display

_display.JITTER = False  # sampled exactly as ParaView's own mapper and the VTK reference
from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

from vtkillum.data.procedural import smoke_plume
from vtkillum.io.convert import image_data_from_volume

SIZE = [200, 200]
SHAPE = (24, 24, 36)
OPACITY = [0.0, 0.0, 0.5, 0.0, 0.05, 0.0, 0.5, 0.0, 0.35, 0.4, 0.5, 0.0, 1.0, 0.9, 0.5, 0.0]
COLORS = [0.0, 1.0, 1.0, 1.0, 0.5, 1.0, 0.8, 0.6, 1.0, 0.9, 0.9, 1.0]
LIGHT = [0, 1.0, 0.4, -0.5, 1.0, 1.0, 1.0, 0]
CAMERA = {"position": [0.3, -6.5, 1.8], "focal_point": [0.0, 0.0, 1.4], "view_up": [0, 0, 1],
          "view_angle": 30.0}
record = {"camera": CAMERA, "opacity": OPACITY, "colors": COLORS, "light": LIGHT, "size": SIZE}


def write_vti(image, path: Path) -> None:
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(image)
    if not writer.Write():
        raise RuntimeError(f"could not write {path}")


def new_view():
    view = simple.CreateRenderView()
    view.ViewSize = SIZE
    view.OrientationAxesVisibility = 0
    if hasattr(view, "UseColorPaletteForBackground"):
        view.UseColorPaletteForBackground = 0
    view.Background = [0.0, 0.0, 0.0]
    view.CameraPosition = CAMERA["position"]
    view.CameraFocalPoint = CAMERA["focal_point"]
    view.CameraViewUp = CAMERA["view_up"]
    view.CameraViewAngle = CAMERA["view_angle"]
    return view


def shot(view, name: str) -> None:
    view.CameraPosition = CAMERA["position"]
    view.CameraFocalPoint = CAMERA["focal_point"]
    view.CameraViewUp = CAMERA["view_up"]
    view.CameraViewAngle = CAMERA["view_angle"]
    simple.Render(view)
    simple.SaveScreenshot(str(OUT / name), view, ImageResolution=SIZE)


def swapped(view) -> int:
    from vtkillum_paraview import display

    hook = display._views.get(view.GetGlobalID())
    return 0 if hook is None else len(hook.volumes)


write_vti(image_data_from_volume(smoke_plume(SHAPE), "density"), OUT / "plume.vti")
reader = simple.XMLImageDataReader(FileName=[str(OUT / "plume.vti")])
lut = simple.GetColorTransferFunction("density")
lut.ColorSpace = "RGB"
lut.Discretize = 0
lut.RGBPoints = COLORS
simple.GetOpacityTransferFunction("density").Points = OPACITY

# --- 1 and 2: Light Transmittance, g = 0 and 0.6 --------------------------------------------------
lit = vtkIllumLightTransmittance(Input=reader)  # noqa: F821 (from LoadPlugin)
lit.Lights = LIGHT
view = new_view()
display = simple.Show(lit, view)
record["representation"] = str(display.Representation).strip("'")
record["color_array"] = list(display.ColorArrayName)
record["linked_lut"] = lit.LookupTable == lut
shot(view, "pv_g0.png")
record["swapped_g0"] = swapped(view)
# ParaView fitted both functions to the data range when it showed the filter: the scene is
# what it rendered with.
record["colors"] = list(lut.RGBPoints)
record["opacity"] = list(simple.GetOpacityTransferFunction("density").Points)
record["unit_distance"] = float(display.ScalarOpacityUnitDistance)
record["filter_unit_distance"] = float(lit.ScalarOpacityUnitDistance)
simple.SaveData(str(OUT / "lit.vti"), proxy=lit)
lit.Anisotropy = 0.6
shot(view, "pv_g06.png")
lit.Anisotropy = 0.0

# --- 3: the colour map and the opacity function edited --------------------------------------------
obj = lit.GetClientSideObject()
stats_before = obj.GetCacheStatistics().misses
lut.RGBPoints = [0.0, 0.2, 0.4, 1.0, 0.5, 0.3, 0.9, 0.5, 1.0, 1.0, 1.0, 0.2]
shot(view, "pv_colour_edit.png")
record["misses_after_colour_edit"] = obj.GetCacheStatistics().misses - stats_before
opacity = simple.GetOpacityTransferFunction("density")
opacity.Points = [0.0, 0.0, 0.5, 0.0, 0.05, 0.0, 0.5, 0.0, 0.35, 0.9, 0.5, 0.0, 1.0, 1.0, 0.5, 0.0]
shot(view, "pv_opacity_edit.png")
record["misses_after_opacity_edit"] = obj.GetCacheStatistics().misses - stats_before
lut.RGBPoints = record["colors"]
opacity.Points = record["opacity"]
lit.Lights = [0, -1.0, 0.4, -0.5, 1.0, 1.0, 1.0, 0]
shot(view, "pv_light_moved.png")
lit.Lights = LIGHT

# --- 4: coloured by another array: ParaView's own volume --------------------------------------------
simple.ColorBy(display, ("POINTS", "fluence", "Magnitude"))
shot(view, "pv_coloured_by_fluence.png")
record["swapped_fluence"] = swapped(view)
simple.ColorBy(display, ("POINTS", "density"))
shot(view, "pv_back_to_density.png")
record["swapped_back"] = swapped(view)
record["linked_lut_back"] = lit.LookupTable == lut
simple.Delete(view)

# --- 5: baked RGBA of two filters, each with its own opacity function --------------------------------
view = new_view()
first = vtkIllumLightTransmittance(Input=reader)  # noqa: F821
first.Lights = LIGHT
plugin.ShowIlluminated(first, view)
shot(view, "rgba_first_alone.png")
shifted = image_data_from_volume(smoke_plume(SHAPE), "density")
shifted.SetOrigin(shifted.GetOrigin()[0] + 3.0, *shifted.GetOrigin()[1:])
write_vti(shifted, OUT / "plume_shifted.vti")
moved = simple.XMLImageDataReader(FileName=[str(OUT / "plume_shifted.vti")])
second = vtkIllumLightTransmittance(Input=moved)  # noqa: F821
second.Lights = LIGHT
second.ScalarOpacityUnitDistance = 0.5
plugin.ShowIlluminated(second, view)
simple.Hide(second, view)
shot(view, "rgba_first_after_second.png")
record["rgba_opacity_functions_differ"] = (
    simple.GetDisplayProperties(first, view).ScalarOpacityFunction
    != simple.GetDisplayProperties(second, view).ScalarOpacityFunction)
simple.Delete(view)

# --- 6: the other methods ------------------------------------------------------------------------------
for label in ("ConvectionDiffusionLight", "AmbientExtinction", "PhotonDensity", "ManyLights"):
    proxy = globals()[f"vtkIllum{label}"](Input=reader)
    proxy.Lights = LIGHT
    if label == "ConvectionDiffusionLight":
        proxy.Scattering = [0.02, 0.02, 0.02]
    if label == "PhotonDensity":
        proxy.Photons = 20000
    if label == "ManyLights":
        proxy.Count = 16
        proxy.AVSMResolution = 8
    view = new_view()
    simple.Show(proxy, view)
    shot(view, f"pv_{label}.png")
    record[f"swapped_{label}"] = swapped(view)
    simple.Delete(view)

# --- 7: a file written from a filter output, transmittance set to 1: ParaView's own volume ----------
import numpy as np  # noqa: E402
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402

lit.UpdatePipeline()
unlit = lit.GetClientSideObject().GetOutputDataObject(0).NewInstance()
unlit.DeepCopy(lit.GetClientSideObject().GetOutputDataObject(0))
vtk_to_numpy(unlit.GetPointData().GetArray("transmittance"))[:] = 1.0
unlit.GetFieldData().GetArray("vtkillum_render").SetValue(0, 1.0)  # albedo 1: all scatters
write_vti(unlit, OUT / "unlit.vti")
white = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
lut.RGBPoints = white
_display.NEAR_CELLS = 0.0  # the transmittance from the grid only (here 1), no exact march
for name, path in (("file_unlit.png", OUT / "unlit.vti"), ("file_plain.png", OUT / "plume.vti")):
    source = simple.XMLImageDataReader(FileName=[str(path)])
    view = new_view()
    shown = simple.Show(source, view)
    shown.SetRepresentationType("Volume")
    simple.ColorBy(shown, ("POINTS", "density"))
    shown.ScalarOpacityUnitDistance = record["unit_distance"]
    shot(view, name)
    record[f"swapped_{name}"] = swapped(view)
    simple.Delete(view)
lut.RGBPoints = record["colors"]
_display.NEAR_CELLS = 2.0

# --- 8: a vector array: the filter follows the colour map's Magnitude / component -------------------
calc = simple.Calculator(Input=reader, ResultArrayName="vec",
                         Function="density*iHat+0.2*density*jHat+coordsZ*kHat")
vec = vtkIllumLightTransmittance(Input=calc)  # noqa: F821
vec.Lights = LIGHT
vec.Scalars = ["POINTS", "vec"]
view = new_view()
vec_display = simple.Show(vec, view)
shot(view, "vec_magnitude.png")
t_magnitude = vtk_to_numpy(vec.GetClientSideObject().GetOutputDataObject(0).GetPointData()
                           .GetArray("transmittance")).copy()
simple.ColorBy(vec_display, ("POINTS", "vec", "X"))
shot(view, "vec_x.png")
t_x = vtk_to_numpy(vec.GetClientSideObject().GetOutputDataObject(0).GetPointData()
                   .GetArray("transmittance")).copy()
record["vector"] = {"color_array": list(vec_display.ColorArrayName),
                    "lut_mode": str(vec.LookupTable.VectorMode),
                    "transmittance_changed": float(np.abs(t_x - t_magnitude).max()),
                    "swapped": swapped(view), "error": vec.GetClientSideObject().GetLastError()}
simple.Delete(view)

# --- 9: errors in ParaView's words ------------------------------------------------------------------
errors = {}
probe = vtkIllumLightTransmittance(Input=reader)  # noqa: F821
probe.Lights = [0, 1, 0, 0, 1, 1, 1, 0, 2, 0, 1, 0, 1, 1, 1, 0]
probe.UpdatePipeline()
errors["light_type"] = probe.GetClientSideObject().GetLastError()
probe.Lights = [0, 0, 0, 0, 1, 1, 1, 0]
probe.UpdatePipeline()
errors["light_zero"] = probe.GetClientSideObject().GetLastError()
probe.Lights = LIGHT
probe.Albedo = 1.5
probe.UpdatePipeline()
errors["albedo"] = probe.GetClientSideObject().GetLastError()
probe.Albedo = 0.9
probe.UpdatePipeline()
errors["fixed"] = probe.GetClientSideObject().GetLastError()
photon = vtkIllumPhotonDensity(Input=reader)  # noqa: F821
photon.Radius = -1.0
photon.UpdatePipeline()
errors["photon_radius"] = photon.GetClientSideObject().GetLastError()
record["errors"] = errors

# --- 10: progress reported while the kernels run (ParaView's progress bar) ---------------------------
progress = []
busy = vtkIllumLightTransmittance(Input=reader)  # noqa: F821
busy.Lights = LIGHT[:] + [1, 0.0, -3.0, 1.5, 5.0, 5.0, 5.0, 0] + [0, -1, 0.2, -0.4, 1, 1, 1, 0]
busy.GetClientSideObject().AddObserver(
    "ProgressEvent", lambda obj, event: progress.append(round(obj.GetProgress(), 4)))
busy.UpdatePipeline()
record["progress"] = progress

(OUT / "render.json").write_text(json.dumps(record, indent=1))
print("pvbatch_render: done")
