"""Animate the built-in smoke-plume time series in ParaView (pvbatch) with the vtkIllum plugin.

Writes the steps of :func:`vtkillum.data.procedural.plume_series` as a ``.vti.series``
file, opens it in ParaView, applies *vtkIllum Light Transmittance* (or
*Convection-Diffusion Light*) with the plume's recommended transfer function and
lights, shows the illuminated volume and plays the animation forward and
back, saving one PNG per frame. Per step it prints the time, the seconds the
update and render took and the filter's cache hits/misses.

Run it from the vtkillum virtual environment; it restarts itself under
``xvfb-run -a pvbatch`` with the environment of ``paraview_plugin/pvbatch_env.py``::

    python examples/time_series_pvbatch.py --out frames_pv/ [--method convection_diffusion]

(or directly: ``eval "$(python paraview_plugin/pvbatch_env.py)"; xvfb-run -a pvbatch
examples/time_series_pvbatch.py --out frames_pv/``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
METHODS = {"transmittance": "vtkIllumLightTransmittance",
           "convection_diffusion": "vtkIllumConvectionDiffusionLight"}


def parse(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="frames_pv", help="directory for data and frames")
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--shape", type=int, nargs=3, default=(40, 40, 60))
    parser.add_argument("--method", choices=sorted(METHODS), default="transmittance")
    parser.add_argument("--size", type=int, default=320, help="frame width and height")
    parser.add_argument("--exposure", type=float, default=0.5,
                        help="factor on the radiance (the plume's lights are bright)")
    return parser.parse_args(argv)


def relaunch(argv) -> int:
    """Not inside ParaView: run this script under xvfb-run -a pvbatch with the shim environment."""
    sys.path.insert(0, str(ROOT / "paraview_plugin"))
    import pvbatch_env

    return pvbatch_env.run_pvbatch(Path(__file__).resolve(), *argv).returncode


def animate(opts) -> int:
    from paraview import simple

    out = Path(opts.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    plugin_path = ROOT / "paraview_plugin" / "vtkillum_plugin.py"
    namespace = globals()  # LoadPlugin adds the filters' constructors (ns must not be empty)
    simple.LoadPlugin(str(plugin_path), ns=namespace)
    import vtkillum_plugin as plugin  # registered by LoadPlugin
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    from vtkillum.data.procedural import default_scene, plume_series
    from vtkillum.io.convert import image_data_from_volume

    # 1. The data: one .vti per step and a .vti.series file with their times.
    series = plume_series(steps=opts.steps, shape=tuple(opts.shape))
    files = []
    for k, (t, volume) in enumerate(series):
        writer = vtkXMLImageDataWriter()
        writer.SetFileName(str(out / f"plume_{k:03d}.vti"))
        writer.SetInputData(image_data_from_volume(volume, "density"))
        writer.Write()
        files.append({"name": f"plume_{k:03d}.vti", "time": t})
    (out / "plume.vti.series").write_text(json.dumps({"file-series-version": "1.0",
                                                      "files": files}))
    scene = default_scene("plume", series[0][1])
    tf = scene.transfer_function

    # 2. The pipeline: reader -> illumination filter, shown as an illuminated volume.
    reader = simple.OpenDataFile(str(out / "plume.vti.series"))
    light = namespace[METHODS[opts.method]](Input=reader)
    light.Scalars = ["POINTS", "density"]
    # One transfer function: the colour map and opacity function of "density" (the ones
    # the Color Map Editor edits), which the filter and its display share.
    lut = simple.GetColorTransferFunction("density")
    lut.AutomaticRescaleRangeMode = "Never"
    lut.RGBPoints = [v for x, c in zip(tf.scalars, tf.colors) for v in (x, *c)]
    simple.GetOpacityTransferFunction("density").Points = [
        v for x, a in zip(tf.scalars, tf.opacity) for v in (x, a, 0.5, 0.0)]
    light.Albedo = scene.albedo
    light.Exposure = opts.exposure
    plugin.SetLights(light, scene.lights)
    view = simple.CreateRenderView()
    view.ViewSize = [opts.size, opts.size]
    view.OrientationAxesVisibility = 0
    if hasattr(view, "UseColorPaletteForBackground"):
        view.UseColorPaletteForBackground = 0
    view.Background = [0.0, 0.0, 0.0]
    display = simple.Show(light, view)  # a volume lit per sample by the render view
    display.ScalarOpacityUnitDistance = scene.resolved_unit_distance(series[0][1])
    camera = scene.resolved_camera(series[0][1])
    simple.Render(view)
    view.CameraPosition = list(camera.position)
    view.CameraFocalPoint = list(camera.focal_point)
    view.CameraViewUp = list(camera.view_up)
    view.CameraViewAngle = camera.view_angle

    # 3. The animation, forward and back: the way back is served from the cache.
    animation = simple.GetAnimationScene()
    animation.UpdateAnimationUsingDataTimeSteps()
    times = list(reader.TimestepValues)
    order = list(range(len(times))) + list(range(len(times) - 2, -1, -1))
    algorithm = light.GetClientSideObject()
    print(f"ParaView {simple.GetParaViewVersion()}: {light.GetXMLLabel()} on "
          f"{len(times)} steps of {tuple(opts.shape)}")
    print(f"{'frame':>5} {'time':>6} {'update s':>9} {'render s':>9} {'hits':>5} {'misses':>6}")
    for index, k in enumerate(order):
        start = time.perf_counter()
        animation.AnimationTime = times[k]
        light.UpdatePipeline(times[k])  # the filter (and reader) at this time
        update = time.perf_counter() - start
        start = time.perf_counter()
        simple.Render(view)
        render = time.perf_counter() - start
        simple.SaveScreenshot(str(out / f"frame_{index:03d}.png"), view,
                              ImageResolution=[opts.size, opts.size])
        stats = algorithm.GetCacheStatistics()
        print(f"{index:>5} {times[k]:>6.2f} {update:>9.3f} {render:>9.3f} {stats.hits:>5} "
              f"{stats.misses:>6}")
    stats = algorithm.GetCacheStatistics()
    print(f"cache: {stats.hits} hits, {stats.misses} misses, {stats.entries} entries, "
          f"{stats.bytes / 2**20:.1f} MB; frames in {out}")
    simple.Delete(view)  # before exit: tearing down a live view upsets GLX under Xvfb
    return 0


if __name__ == "__main__":
    try:
        import paraview  # noqa: F401
    except ImportError:
        raise SystemExit(relaunch(sys.argv[1:])) from None
    raise SystemExit(animate(parse(sys.argv[1:])))
