"""pvbatch script driven by ``test_pvbatch.py``: every plugin filter in ParaView 5.11.

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
"""

import json
import sys
import time
from pathlib import Path

from paraview import simple

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

summary = {"paraview": simple.GetParaViewVersion().GetVersion(), "filters": {}, "series": {}}
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
    """label -> proxy constructor, for every filter the plugin declares."""
    found = {}
    for name, obj in vars(plugin).items():
        original = getattr(obj, "_pv_original_func", obj)
        if hasattr(original, "_pvsm_proxy_xml"):
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

for label, (name, cls) in sorted(entries.items()):
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

(OUT / "summary.json").write_text(json.dumps(summary, indent=1))
print("pvbatch_filters: done")
