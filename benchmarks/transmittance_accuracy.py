"""What each speed-up of the ``transmittance`` method costs in accuracy, against ``single``.

On ``bench_scaling``'s CT-like volume (made on the device) it renders ``single`` (exact
shadow rays at every sample: the reference of the method) and then ``transmittance``
with its speed-ups switched on one by one:

* ``exact``: one shadow ray per light-grid point, the near field marched at every
  sample, arrays (software trilinear) everywhere;
* ``+ chained``: the light grid from chained segments (``segment_planes`` 16);
* ``+ near skip``: the near-field march skipped where it is provably thin
  (``near_tolerance`` 0.02);
* ``+ textures``: hardware-filtered textures on CUDA (the default: all of the above).

For each: the error against ``single`` (mean |Δ| over the mean radiance, and the 99th
percentile of |Δ| over the maximum), the light-grid time (a TF edit's extra) and a camera
move (the whole render call with the grid cached). Jitter off, so the two renders of
each pixel take the same samples.

    python benchmarks/transmittance_accuracy.py --size 512 --image 1024
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp
from _timing import device_name
from bench_scaling import device_volume, make_scene

from vtkillum.core.device import resolve_device
from vtkillum.core.render import render

SETTINGS = [
    ("exact", {"segment_planes": 0, "near_tolerance": 0.0, "textures": False}),
    ("+ chained", {"near_tolerance": 0.0, "textures": False}),
    ("+ near skip", {"textures": False}),
    ("+ textures (default)", {}),
]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--image", type=int, default=1024)
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    small, _ = device_volume(16, device)  # compile every variant first: not a light grid
    for _name, options in SETTINGS:
        render(small, make_scene(small), "transmittance", 16, 16, device, **options)
    volume, _ = device_volume(args.size, device)
    scene = make_scene(volume, azimuth=10.0)
    w = args.image
    for _ in range(2):  # compile, then the reference
        ref = render(volume, scene, "single", w, w, device, jitter=False).radiance
    mean_ref, max_ref = float(ref.mean()), float(ref.max())
    print(f"## transmittance speed-ups against `single` — {device_name(device)}, "
          f"{args.size}³ CT-like, {w}² image\n")
    print("| settings | mean error | 99th pct error | light grid ms | camera move ms |")
    print("|---|---|---|---|---|")
    grids = set()
    for name, options in SETTINGS:
        planes = options.get("segment_planes", 16)
        first = render(volume, make_scene(volume), "transmittance", w, w, device,
                       jitter=False, **options)  # builds the grid
        t0 = time.perf_counter()
        result = render(volume, scene, "transmittance", w, w, device, jitter=False, **options)
        wp.synchronize_device(device)
        move = 1e3 * (time.perf_counter() - t0)
        diff = np.abs(result.radiance - ref)
        grid_ms = "(same grid)" if planes in grids else f"{1e3 * first.info['light_volume_s']:.1f}"
        grids.add(planes)
        print(f"| {name} | {diff.mean() / mean_ref:.2e} | "
              f"{np.percentile(diff, 99) / max_ref:.2e} | {grid_ms} | {move:.1f} |", flush=True)


if __name__ == "__main__":
    main()
