"""Where an ambient-scattering transfer-function edit spends its time, per stage.

Runs ``bench_scaling``'s CT-like volume at the given edges, renders once, then edits the
opacity (scaled by 0.8) and prints the cache's stage timings (σt grid and SAT, σ̃t,
radiance cache) beside the whole call. GPU only in practice (1024³).

    python benchmarks/ambient_breakdown.py --sizes 512 1024
"""

from __future__ import annotations

import argparse
import time

import warp as wp
from _timing import device_name
from bench_scaling import device_volume, make_scene

from vtkillum.core.ambient.render import release_default_caches
from vtkillum.core.device import resolve_device
from vtkillum.core.render import render


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--sizes", type=int, nargs="+", default=[256])
    ap.add_argument("--image", type=int, default=1024)
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    print(f"## ambient TF edit by stage — {device_name(device)}, {args.image}² image\n")
    print("| volume | whole call ms | stage timings ms |")
    print("|---|---|---|")
    for n in args.sizes:
        volume, _ = device_volume(n, device)
        render(volume, make_scene(volume), "ambient-scattering", args.image, args.image, device)
        for scale in (0.8, 1.0):
            scene = make_scene(volume, azimuth=10.0, opacity_scale=scale)
            t0 = time.perf_counter()
            result = render(volume, scene, "ambient-scattering", args.image, args.image, device)
            wp.synchronize_device(device)
            total = 1e3 * (time.perf_counter() - t0)
            timings = {k: v for k, v in result.info.items()
                       if k.endswith("_ms") or k.endswith("_s") or k == "timings"}
            print(f"| {n}³ | {total:.1f} | {timings} |", flush=True)
        del volume
        release_default_caches()
        wp.synchronize_device(device)


if __name__ == "__main__":
    main()
