"""Milliseconds per frame of every rendering method.

Prints a table (volume size, image size, device, method, ms per frame: the whole call
and the device stages the method reports, :func:`_timing.kernel_seconds`; "–" where a
method reports none) for any registered method (default ``emission``, ``single`` and
``path`` per sample per pixel) on the built-in smoke plume. The frame timed is a
repeat of the same render (cached light volumes are reused). ``refraction`` gets the
plume's key light only (it takes one distant light). Absolute numbers mean something only on a GPU; on a CPU compare
ratios within one run. ``--compare-skipping`` adds the time with empty-block skipping
off (every block of the medium marked occupied), which gives the same pixels.

Examples
--------
python benchmarks/bench_render.py --device cuda
python benchmarks/bench_render.py --device cpu --volumes 64 --images 128
python benchmarks/bench_render.py --device cpu --volumes 64 --images 128 --methods single \
    transmittance --compare-skipping
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import time

import numpy as np
from _timing import device_name, fmt_ms, kernel_seconds

from vtkillum.core.device import resolve_device
from vtkillum.core.render import render
from vtkillum.data.procedural import default_scene, smoke_plume


@contextlib.contextmanager
def empty_skipping(enabled: bool):
    """Media made inside this block skip empty blocks (the default) or not."""
    from vtkillum.core import light_transmittance, raycast, warp_common

    modules = (raycast, light_transmittance)
    saved = [m.make_medium for m in modules]
    for m in modules:
        m.make_medium = functools.partial(warp_common.make_medium, skip_empty=enabled)
    try:
        yield
    finally:
        for m, f in zip(modules, saved):
            m.make_medium = f


def time_render(volume, scene, method, size, device, repeats, **options):
    """Median seconds: (whole call incl. upload/download, device stages or None)."""
    render(volume, scene, method, size, size, device, **options)  # compile and warm up
    total, kernel = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = render(volume, scene, method, size, size, device, **options)
        total.append(time.perf_counter() - t0)
        kernel.append(kernel_seconds(result.info))
    if any(k is None for k in kernel):
        return float(np.median(total)), None
    return float(np.median(total)), float(np.median(kernel))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="cpu, cuda (default: cuda if present)")
    ap.add_argument("--volumes", type=int, nargs="+", default=[128, 256], help="cube edge sizes")
    ap.add_argument("--images", type=int, nargs="+", default=[256, 512], help="square image sizes")
    ap.add_argument("--methods", nargs="+", default=["emission", "single", "path"],
                    help="any of vtkillum.core.render.METHODS except 'illumination'")
    ap.add_argument("--path-spp", type=int, default=4, help="samples per pixel timed for path")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--compare-skipping", action="store_true",
                    help="also time each row with empty-block skipping off")
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    name = device_name(device)
    extra = " ms total without skipping |" if args.compare_skipping else ""
    print("| volume | image | device | method | ms per frame (total) | ms kernel |" + extra)
    print("|---|---|---|---|---|---|" + ("---|" if extra else ""))
    for n in args.volumes:
        volume = smoke_plume(shape=(n, n, n))
        plume = default_scene("plume", volume)
        key_light = default_scene("plume", volume)
        key_light.lights = key_light.lights[:1]
        for size in args.images:
            for method in args.methods:
                scene = key_light if method == "refraction" else plume
                if method == "path":
                    total, kernel = time_render(volume, scene, method, size, device,
                                                args.repeats, spp=args.path_spp)
                    total = total / args.path_spp
                    kernel = None if kernel is None else kernel / args.path_spp
                    label = "path (per spp)"
                else:
                    total, kernel = time_render(volume, scene, method, size, device, args.repeats)
                    label = method
                row = (f"| {n}³ | {size}² | {name} | {label} | {fmt_ms(total)} | "
                       f"{fmt_ms(kernel)} |")
                if args.compare_skipping:
                    with empty_skipping(False):
                        volume._derived.pop("light_transmittance", None)  # made again
                        plain, _ = time_render(volume, scene, method, size, device,
                                               args.repeats, **({"spp": args.path_spp}
                                                                if method == "path" else {}))
                    volume._derived.pop("light_transmittance", None)
                    if method == "path":
                        plain /= args.path_spp
                    row += f" {fmt_ms(plain)} |"
                print(row, flush=True)


if __name__ == "__main__":
    main()
