"""Animate the built-in smoke-plume time series with illumination in pyvista, off screen.

:class:`vtkillum.io.time_series.TimeSeriesSource` serves the steps of
:func:`vtkillum.data.procedural.plume_series` with ``TIME_STEPS`` (the same source reads
a 4-D NIfTI, a ``.pvd`` or a file series: ``TimeSeriesSource("functional.nii")``); an
illumination filter follows it time step by time step, and each frame shows the step
with :func:`vtkillum.pyvista_accessor.add_illuminated_volume`.
The animation plays forward and back once more, so the second pass is served from
the filter's per-time-step cache. Per step it prints the time, the seconds the
illumination took and the cache hits/misses so far.

    python examples/time_series_pyvista.py --out frames/ [--gif] [--method convection_diffusion]

Writes ``frame_000.png`` ... (and ``plume.gif`` with ``--gif``) to ``--out``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")  # headless VTK

import pyvista as pv

from vtkillum.data.procedural import default_scene, plume_series
from vtkillum.filters import ConvectionDiffusionLightFilter, LightTransmittanceFilter
from vtkillum.io.time_series import TimeSeries, TimeSeriesSource
from vtkillum.mappers import apply_camera_to_vtk
from vtkillum.pyvista_accessor import add_illuminated_volume

FILTERS = {"transmittance": LightTransmittanceFilter,
           "convection_diffusion": ConvectionDiffusionLightFilter}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="frames", help="directory for the frames")
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--shape", type=int, nargs=3, default=(40, 40, 60))
    parser.add_argument("--method", choices=sorted(FILTERS), default="transmittance")
    parser.add_argument("--size", type=int, default=320, help="frame width and height")
    parser.add_argument("--gif", action="store_true", help="also write plume.gif")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: auto)")
    parser.add_argument("--exposure", type=float, default=0.5,
                        help="factor on the radiance (the plume's lights are bright)")
    opts = parser.parse_args(argv)
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)

    series = plume_series(steps=opts.steps, shape=tuple(opts.shape))
    scene = default_scene("plume", series[0][1])
    source = TimeSeriesSource(TimeSeries.from_volumes(series, name="plume"))
    light = FILTERS[opts.method]()
    light.SetInputConnection(source.GetOutputPort())
    light.SetTransferFunction(scene.transfer_function)
    light.SetLights(scene.lights)
    light.SetAlbedo(scene.albedo)
    if opts.device:
        light.SetDevice(opts.device)

    plotter = pv.Plotter(off_screen=True, window_size=(opts.size, opts.size))
    plotter.set_background("black")
    order = list(range(len(series))) + list(range(len(series) - 2, -1, -1))
    frames = []
    print(f"{'frame':>5} {'time':>6} {'illum s':>8} {'render s':>9} {'hits':>5} {'misses':>6}")
    for index, k in enumerate(order):
        t = source.GetTimeSteps()[k]
        start = time.perf_counter()
        illumination = light.execute(time=t)
        illum_seconds = time.perf_counter() - start
        stats = light.GetCacheStatistics()
        start = time.perf_counter()
        grid = pv.wrap(source.image(k))  # the step's data (on a cache hit the source idles)
        add_illuminated_volume(plotter, grid, illumination=illumination,
                               transfer_function=scene.transfer_function,
                               opacity_unit_distance=scene.resolved_unit_distance(series[k][1]),
                               lights=scene.lights, albedo=scene.albedo,
                               anisotropy=scene.anisotropy, exposure=opts.exposure,
                               name="plume", reset_camera=False, render=False)
        if index == 0:
            apply_camera_to_vtk(scene.resolved_camera(series[0][1]), plotter.camera)
        plotter.render()  # screenshot() alone would return the previous frame
        image = plotter.screenshot(str(out / f"frame_{index:03d}.png"))
        render_seconds = time.perf_counter() - start
        frames.append(image)
        print(f"{index:>5} {t:>6.2f} {illum_seconds:>8.3f} {render_seconds:>9.3f} "
              f"{stats.hits:>5} {stats.misses:>6}")
    plotter.close()
    if opts.gif:
        from PIL import Image

        first, *rest = [Image.fromarray(f) for f in frames]
        first.save(out / "plume.gif", save_all=True, append_images=rest, duration=120, loop=0)
    final = light.GetCacheStatistics()
    print(f"cache: {final.hits} hits, {final.misses} misses, {final.entries} entries, "
          f"{final.bytes / 2**20:.1f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
