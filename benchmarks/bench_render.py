"""Milliseconds per frame of the foundation's rendering modes.

Prints a table (volume size, image size, device, method, ms per frame) for the
``emission``, ``single`` and ``path`` (per sample per pixel) modes on the built-in
smoke plume. Absolute numbers mean something only on a GPU; on a CPU compare
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

from vtkillum.core.device import resolve_device
from vtkillum.core.render import render
from vtkillum.data.procedural import default_scene, smoke_plume


def device_name(device: str) -> str:
    import warp as wp

    d = wp.get_device(device)
    return d.name if d.is_cuda else f"cpu ({d.name})"


@contextlib.contextmanager
def empty_skipping(enabled: bool):
    """Media made inside this block skip empty blocks (the default) or not."""
    import vtkillum.core.light_transmittance as light_transmittance
    import vtkillum.core.raycast as raycast
    from vtkillum.core import warp_common

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
    """Median milliseconds: (whole call incl. upload/download, kernel stage alone)."""
    render(volume, scene, method, size, size, device, **options)  # compile and warm up
    total, kernel = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = render(volume, scene, method, size, size, device, **options)
        total.append(time.perf_counter() - t0)
        info = result.info
        kernel.append(info["render_s"] if "render_s" in info
                      else info["ms_per_pass"] * info["passes"] / 1000.0)
    return 1000.0 * float(np.median(total)), 1000.0 * float(np.median(kernel))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="cpu, cuda (default: cuda if present)")
    ap.add_argument("--volumes", type=int, nargs="+", default=[128, 256], help="cube edge sizes")
    ap.add_argument("--images", type=int, nargs="+", default=[256, 512], help="square image sizes")
    ap.add_argument("--methods", nargs="+", default=["emission", "single", "path"])
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
        scene = default_scene("plume", volume)
        for size in args.images:
            for method in args.methods:
                if method == "path":
                    total, kernel = time_render(volume, scene, method, size, device,
                                                args.repeats, spp=args.path_spp)
                    total, kernel = total / args.path_spp, kernel / args.path_spp
                    label = "path (per spp)"
                else:
                    total, kernel = time_render(volume, scene, method, size, device, args.repeats)
                    label = method
                row = f"| {n}³ | {size}² | {name} | {label} | {total:.1f} | {kernel:.1f} |"
                if args.compare_skipping:
                    with empty_skipping(False):
                        volume._derived.pop("light_transmittance", None)  # made again
                        plain, _ = time_render(volume, scene, method, size, device,
                                               args.repeats, **({"spp": args.path_spp}
                                                                if method == "path" else {}))
                    volume._derived.pop("light_transmittance", None)
                    if method == "path":
                        plain /= args.path_spp
                    row += f" {plain:.1f} |"
                print(row, flush=True)


if __name__ == "__main__":
    main()
