"""pvbatch script driven by ``test_pvbatch.py``: every plugin filter in ParaView (5.11 to 6.x).

Run as ``xvfb-run -a pvbatch pvbatch_filters.py OUT_DIR`` with the environment of
``paraview_plugin/pvbatch_env.py``. It writes screenshots and ``summary.json`` to
OUT_DIR; the pytest side checks them (this script only records, except that it
fails loudly when ParaView raises).

1. A static smoke plume (written as .vti with vtkillum's converters under
   ParaView's VTK 9.2): every plugin filter, one screenshot per light position.
2. The same filters' list against ``vtkillum.filters``: every filter has an entry.
3. The RGBA path against ParaView's own volume rendering: with shadows switched
   off (a huge opacity unit distance in the filter only) and exposure 4 pi, the
   illuminated RGBA volume must look like the plain rendering of the same
   transfer function.
4. A 3-step plume series (.vti.series): an animation played twice; screenshots,
   per-step cache statistics, data times.
5. vtkIllum Refraction Render (an image, not a volume: left out of 1.) on a small
   stemmed glass: the refractive-index and medium-colour tables, the colour map link,
   the view's camera copied in, a bad table row, the picture shown and saved.
"""

import json
import sys
import time
from pathlib import Path

from paraview import servermanager, simple

OUT = Path(sys.argv[1])
OUT.mkdir(parents=True, exist_ok=True)
ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "paraview_plugin" / "vtkillum_plugin.py"
SIZE = [160, 160]
SHAPE = (20, 20, 30)

simple.LoadPlugin(str(PLUGIN), ns=globals())
import importlib
import pkgutil

import vtkillum_plugin as plugin
from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

import vtkillum.filters as vtkillum_filters
from vtkillum.data.procedural import plume_series, smoke_plume
from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.convert import image_data_from_volume

# GetParaViewVersion().GetVersion() is gone in 6.x; the server manager has the numbers in both.
_pm = servermanager.vtkSMProxyManager
summary = {"paraview": [_pm.GetVersionMajor(), _pm.GetVersionMinor(), _pm.GetVersionPatch()],
           "filters": {}, "series": {}}
# Plume transfer function: transparent air, wisps, body, core (data in [0, 1]).
OPACITY = [0.0, 0.0, 0.5, 0.0, 0.02, 0.0, 0.5, 0.0, 0.3, 0.35, 0.5, 0.0, 1.0, 0.95, 0.5, 0.0]
COLORS = [0.0, 1.0, 1.0, 1.0, 0.5, 1.0, 0.85, 0.7, 1.0, 1.0, 0.7, 0.5]
LIGHT_A = [0, 1.0, 0.3, -0.6, 1.0, 1.0, 1.0, 0]   # from -x: the camera sees the lit side
LIGHT_B = [0, -1.0, 0.3, -0.6, 1.0, 1.0, 1.0, 0]  # from +x: the camera sees the shadowed side


def write_vti(volume, path: Path) -> None:
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(image_data_from_volume(volume, "density"))
    if not writer.Write():
        raise RuntimeError(f"could not write {path}")


def new_view():
    view = simple.CreateRenderView()
    view.ViewSize = SIZE
    view.OrientationAxesVisibility = 0
    if hasattr(view, "UseColorPaletteForBackground"):
        view.UseColorPaletteForBackground = 0
    view.Background = [0.0, 0.0, 0.0]
    return view


def frame(view) -> None:
    """The camera in front of the plume (-y), looking along +y, z up."""
    simple.Render(view)
    view.CameraPosition = [0.0, -6.0, 1.5]
    view.CameraFocalPoint = [0.0, 0.0, 1.5]
    view.CameraViewUp = [0.0, 0.0, 1.0]
    view.CameraParallelProjection = 0
    simple.ResetCamera(view)


def configure(proxy, colors=COLORS) -> None:
    # Explicit: ParaView 5.11 may default the array to the one last coloured by elsewhere.
    proxy.Scalars = ["POINTS", "density"]
    lut = simple.GetColorTransferFunction("density")
    lut.AutomaticRescaleRangeMode = "Never"  # exactly these points, not fitted to the data
    lut.RGBPoints = colors
    opacity = simple.GetOpacityTransferFunction("density")
    opacity.Points = OPACITY
    proxy.LookupTable = lut
    proxy.ScalarOpacityFunction = opacity
    if hasattr(proxy, "Lights"):
        proxy.Lights = LIGHT_A
    if hasattr(proxy, "Photons"):
        proxy.Photons = 20000  # (CPU)
    if hasattr(proxy, "AVSMResolution"):
        proxy.Count = 32  # (CPU)
        proxy.AVSMResolution = 8


def filter_proxies() -> dict:
    """label -> proxy constructor, for every filter the plugin declares (its readers,
    proxies of group "sources", are left out)."""
    found = {}
    for name, obj in vars(plugin).items():
        original = getattr(obj, "_pv_original_func", obj)
        if '<ProxyGroup name="filters">' in getattr(original, "_pvsm_proxy_xml", ""):
            label = original._pvsm_proxy_xml.split('label="')[1].split('"')[0]
            found[label] = (name, original)
    return found


# --- 1. static volume, every filter, two light positions ----------------------------------------
static = OUT / "plume.vti"
write_vti(smoke_plume(SHAPE), static)
reader = simple.XMLImageDataReader(FileName=[str(static)])
entries = filter_proxies()
summary["plugin_classes"] = sorted(name for name, _ in entries.values())
covered = {base.__name__ for _, cls in entries.values() for base in cls.__mro__}
library = set()
for module_info in pkgutil.iter_modules(vtkillum_filters.__path__):
    module = importlib.import_module(f"vtkillum.filters.{module_info.name}")
    for obj in vars(module).values():
        if (isinstance(obj, type) and issubclass(obj, IlluminationFilterBase)
                and obj is not IlluminationFilterBase and obj.__module__ == module.__name__):
            library.add(obj.__name__)
summary["library_filters"] = sorted(library)
summary["library_filters_covered"] = sorted(set(summary["library_filters"]) & covered)

IMAGE_FILTERS = {"vtkIllum Refraction Render"}  # a rendered picture: section 5
for label, (name, cls) in sorted(entries.items()):
    if label in IMAGE_FILTERS:
        continue
    constructor = globals()[label.replace(" ", "").replace("-", "")]
    proxy = constructor(Input=reader)
    configure(proxy)
    view = new_view()
    record = {"class": name}
    illuminated = hasattr(proxy, "Lights")
    start = time.perf_counter()
    if illuminated:
        display = plugin.ShowIlluminated(proxy, view)
    else:
        display = simple.Show(proxy, view)
        simple.ColorBy(display, ("POINTS", "sigma_t"))
    record["representation"] = str(display.Representation)
    record["arrays"] = [proxy.PointData[i].GetName() for i in range(len(proxy.PointData))]
    frame(view)
    simple.Render(view)
    record["first_update_s"] = time.perf_counter() - start
    shots = []
    for tag, light in (("a", LIGHT_A), ("b", LIGHT_B)):
        if illuminated:
            proxy.Lights = light
        path = OUT / f"{name}_{tag}.png"
        simple.SaveScreenshot(str(path), view, ImageResolution=SIZE)
        shots.append(path.name)
    record["screenshots"] = shots
    record["cache"] = proxy.GetClientSideObject().GetCacheStatistics().as_dict()
    record["cache_property"] = list(plugin.CacheStatistics(proxy).values())
    proxy.UpdatePropertyInformation()
    record["cache_attribute"] = list(proxy.CacheStatistics)  # a pvpython attribute too
    summary["filters"][label] = record
    simple.Delete(view)

# --- 2. Light Transmittance's SegmentPlanes: chained segments by default, exact rays with 0 ------
def transmittance_values(proxy):
    from vtkmodules.util.numpy_support import vtk_to_numpy as to_numpy

    proxy.UpdatePipeline()
    data = servermanager.Fetch(proxy)
    return to_numpy(data.GetPointData().GetArray("transmittance")).astype(float)


segmented = vtkIllumLightTransmittance(Input=reader)  # noqa: F821 (from LoadPlugin)
configure(segmented)
segmented.Lights = LIGHT_A
record = {"default": int(segmented.SegmentPlanes)}
segmented.SegmentPlanes = 0
exact_t = transmittance_values(segmented)
segmented.SegmentPlanes = 4
chained_t = transmittance_values(segmented)
record["mean_change"] = float(abs(chained_t - exact_t).mean())
record["max_change"] = float(abs(chained_t - exact_t).max())
segmented.SegmentPlanes = 0
record["back_to_exact"] = float(abs(transmittance_values(segmented) - exact_t).max())
# a bad value, then good ones: the view must follow again (a failed request once left
# ParaView's representation stuck on its last data)
segmented.SegmentPlanes = 16
seg_view = new_view()
plugin.ShowIlluminated(segmented, seg_view)
frame(seg_view)
simple.SaveScreenshot(str(OUT / "recover_before.png"), seg_view, ImageResolution=SIZE)
segmented.SegmentPlanes = -1
simple.Render(seg_view)
record["bad_value_error"] = segmented.GetClientSideObject().GetLastError()
segmented.SegmentPlanes = 16
segmented.Lights = LIGHT_B
simple.Render(seg_view)
simple.SaveScreenshot(str(OUT / "recover_after.png"), seg_view, ImageResolution=SIZE)
record["recover_screenshots"] = ["recover_before.png", "recover_after.png"]
summary["segment_planes"] = record
simple.Delete(seg_view)
simple.Delete(segmented)

# --- 3. the RGBA path agrees with ParaView's own volume rendering -----------------------------------
for rgba_type in ("uint8", "float32"):
    unlit = vtkIllumLightTransmittance(Input=reader)  # noqa: F821 (from LoadPlugin)
    configure(unlit, colors=[0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    unlit.Albedo = 1.0
    unlit.Exposure = 12.566370614359172  # 4 pi: an unshadowed white voxel shows white
    unlit.RGBAType = rgba_type
    unlit.ScalarOpacityUnitDistance = 1.0e6  # no shadows in the filter ...
    view = new_view()
    display = plugin.ShowIlluminated(unlit, view)
    spacing = 2.0 / (SHAPE[0] - 1)
    # ... but the data's own opacity unit distance in the display (its own opacity function).
    simple.GetOpacityTransferFunction(plugin.RGBA_ARRAY, display, separate=True).Points = \
        plugin.rgba_opacity_points(spacing, 1.0 if rgba_type == "float32" else 255.0)
    frame(view)
    simple.SaveScreenshot(str(OUT / f"rgba_{rgba_type}.png"), view, ImageResolution=SIZE)
    simple.Delete(view)
    simple.Delete(unlit)
view = new_view()
plain = simple.Show(reader, view)
plain.SetRepresentationType("Volume")
simple.ColorBy(plain, ("POINTS", "density"))
simple.GetColorTransferFunction("density").RGBPoints = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
simple.GetOpacityTransferFunction("density").Points = OPACITY
plain.ScalarOpacityUnitDistance = 2.0 / (SHAPE[0] - 1)
frame(view)
simple.SaveScreenshot(str(OUT / "plain_volume.png"), view, ImageResolution=SIZE)
simple.Delete(view)

# --- 4. a time series in an animation ----------------------------------------------------------------
series = plume_series(steps=3, shape=SHAPE, dt=0.5)
files = []
for k, (t, volume) in enumerate(series):
    path = OUT / f"plume_{k}.vti"
    write_vti(volume, path)
    files.append({"name": path.name, "time": t})
(OUT / "plume.vti.series").write_text(json.dumps({"file-series-version": "1.0", "files": files}))
series_reader = simple.OpenDataFile(str(OUT / "plume.vti.series"))
light = vtkIllumLightTransmittance(Input=series_reader)  # noqa: F821
configure(light)
view = new_view()
plugin.ShowIlluminated(light, view)
frame(view)
scene = simple.GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
times = list(series_reader.TimestepValues)
summary["series"]["times"] = times
passes = []
for replay in range(2):
    steps = []
    for k, t in enumerate(times):
        start = time.perf_counter()
        scene.AnimationTime = t
        simple.Render(view)
        elapsed = time.perf_counter() - start
        path = OUT / f"series_pass{replay}_step{k}.png"
        simple.SaveScreenshot(str(path), view, ImageResolution=SIZE)
        stats = light.GetClientSideObject().GetCacheStatistics()
        data_time = light.GetDataInformation().DataInformation.GetTime()
        steps.append({"time": t, "data_time": data_time, "seconds": elapsed,
                      "hits": stats.hits, "misses": stats.misses, "screenshot": path.name})
    passes.append(steps)
summary["series"]["passes"] = passes

# --- 5. the refraction render: a picture from the refractive-index and medium-colour tables ----
from vtkmodules.util.numpy_support import vtk_to_numpy

from vtkillum.data.procedural import glass_preset, stemmed_glass

glass = stemmed_glass(32)
write_vti(glass, OUT / "glass.vti")
glass_scene, beer = glass_preset(glass, "beer")
glass_reader = simple.XMLImageDataReader(FileName=[str(OUT / "glass.vti")])
refraction = vtkIllumRefractionRender(Input=glass_reader)  # noqa: F821 (from LoadPlugin)
refraction.Scalars = ["POINTS", "density"]
tf = glass_scene.transfer_function
lut = simple.GetColorTransferFunction("density")
lut.AutomaticRescaleRangeMode = "Never"
lut.RGBPoints = [v for x, c in zip(tf.scalars, tf.colors) for v in (float(x), *map(float, c))]
simple.GetOpacityTransferFunction("density").Points = [
    v for x, a in zip(tf.scalars, tf.opacity) for v in (float(x), float(a), 0.5, 0.0)]
refraction.ScalarOpacityUnitDistance = glass_scene.opacity_unit_distance
refraction.RefractiveIndex = [v for x, e in zip(beer.eta_scalars, beer.eta) for v in (x, e)]
refraction.MediumColor = [v for x, c in zip(beer.medium_scalars, beer.medium_color)
                          for v in (x, *c)]
light = glass_scene.lights[0]
refraction.LightDirection = list(light.direction)
refraction.LightIrradiance = list(light.irradiance)
refraction.ImageSize = [64, 72]
refraction.Exposure = 6.0
# The camera of a render view that shows the glass, copied in by the plugin's helper.
glass_view = new_view()
simple.Show(glass_reader, glass_view)
glass_view.CameraPosition = list(glass_scene.camera.position)
glass_view.CameraFocalPoint = list(glass_scene.camera.focal_point)
glass_view.CameraViewUp = list(glass_scene.camera.view_up)
glass_view.CameraViewAngle = glass_scene.camera.view_angle
plugin.CopyViewCamera(refraction, glass_view)


def refraction_picture():
    refraction.UpdatePipeline()
    data = refraction.GetClientSideObject().GetOutputDataObject(0)
    pd = data.GetPointData()
    if data.GetNumberOfPoints() == 0:
        return None
    return {"dims": list(data.GetDimensions()),
            "arrays": [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())],
            "active": pd.GetScalars().GetName(),
            "rgb": vtk_to_numpy(pd.GetArray("refraction_rgb")).astype(int).tolist(),
            "radiance_sum": float(vtk_to_numpy(pd.GetArray("radiance")).sum())}


record = {"camera": {"position": list(refraction.CameraPosition),
                     "focal_point": list(refraction.CameraFocalPoint),
                     "view_angle": float(refraction.CameraViewAngle)},
          "expected_camera": glass_scene.camera.to_dict(),
          "representation_hint": None, "lookup_table": None}
record["beer"] = refraction_picture()
record["lookup_table_is_the_density_colour_map"] = \
    refraction.LookupTable.GetGlobalID() == lut.GetGlobalID()
picture_view = new_view()
display = plugin.ShowRendered(refraction, picture_view)
record["representation"] = str(display.Representation)
record["map_scalars"] = int(display.MapScalars)
record["color_array"] = list(display.ColorArrayName)
simple.SaveScreenshot(str(OUT / "refraction_beer.png"), picture_view, ImageResolution=[128, 144])
# As the GUI's Apply shows it: in the 3D view, then the colour maps' scalar bars updated.
from paraview.modules.vtkRemotingViews import vtkSMTransferFunctionManager

gui_display = simple.Show(refraction, glass_view)
manager = vtkSMTransferFunctionManager()
manager.UpdateScalarBars(glass_view.SMProxy, manager.SHOW_USED_SCALAR_BARS)
record["gui_like"] = {
    "representation": str(gui_display.Representation), "map_scalars": int(gui_display.MapScalars),
    "scalar_bar": int(simple.GetScalarBar(simple.GetColorTransferFunction("refraction_rgb"),
                                          glass_view).Visibility),
    "density_bar": int(simple.GetScalarBar(lut, glass_view).Visibility)}
simple.Hide(refraction, glass_view)
refraction.RefractiveIndex = [0.0, 1.0]  # eta = 1 everywhere: straight rays
record["eta_one"] = refraction_picture()
simple.SaveScreenshot(str(OUT / "refraction_eta_one.png"), picture_view,
                      ImageResolution=[128, 144])
misses = refraction.GetClientSideObject().GetCacheStatistics().misses
lut.RGBPoints = [v for x, c in zip(tf.scalars, tf.colors)  # the checkered walls turn blue
                 for v in (float(x), *(map(float, c) if x > -0.5 else (0.2, 0.4, 1.0)))]
record["after_colour_edit"] = refraction_picture()
record["recomputed_after_colour_edit"] = \
    refraction.GetClientSideObject().GetCacheStatistics().misses - misses
refraction.RefractiveIndex = [0.0, 1.0, 1.0, -1.5]  # a wrong row: an error, no picture
record["bad_eta"] = refraction_picture()
record["bad_eta_error"] = refraction.GetClientSideObject().GetLastError()
refraction.RefractiveIndex = [0.0, 1.0]
record["fixed"] = refraction_picture() is not None
summary["refraction"] = record
simple.Delete(picture_view)
simple.Delete(glass_view)

(OUT / "summary.json").write_text(json.dumps(summary, indent=1))
print("pvbatch_filters: done")
