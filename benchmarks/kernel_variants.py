"""Kernel time of a camera move under the ray caster's options: where the time goes.

On ``bench_scaling``'s CT-like volume (made on the device) it renders camera moves with
``emission``, ``transmittance`` and ``convection-diffusion`` and prints the median kernel
time (``info["render_s"]``) with each option changed from its default: no near-field
march (``near_cells`` 0), never skipping it (``near_tolerance`` 0), skipping nearly
always (``near_tolerance`` 0.5), no jitter, one light-grid cell of near field, a 1.5×
longer step.

    python benchmarks/kernel_variants.py --size 512 --image 1024
"""

from __future__ import annotations

import argparse

import numpy as np
from _timing import device_name
from bench_scaling import device_volume, make_scene

from vtkillum.core.device import resolve_device
from vtkillum.core.render import render

VARIANTS = {"default": {}, "near_cells 0": {"near_cells": 0},
            "near_tolerance 0": {"near_tolerance": 0.0},
            "near_tolerance 0.5": {"near_tolerance": 0.5}, "jitter off": {"jitter": False},
            "near_cells 1": {"near_cells": 1.0}, "step x1.5": {"step_size": 0.75}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--image", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=4)
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    volume, _ = device_volume(args.size, device)
    scenes = [make_scene(volume, azimuth=a) for a in (5.0, 10.0)]
    print(f"## kernel ms of a camera move — {device_name(device)}, {args.size}³ CT-like, "
          f"{args.image}² image\n")
    print("| method | variant | kernel ms | samples per pixel |")
    print("|---|---|---|---|")
    w = args.image
    for method in ("emission", "transmittance", "convection-diffusion"):
        for name, options in VARIANTS.items():
            if method == "emission" and name not in ("default", "jitter off"):
                continue
            step = options.get("step_size")
            if step is not None:  # in voxels of this volume: spacing 1
                options = dict(options, step_size=step * float(np.min(volume.spacing)))
            render(volume, make_scene(volume), method, w, w, device, **options)  # compile, grids
            times = []
            for r in range(args.repeats):
                result = render(volume, scenes[r % 2], method, w, w, device, **options)
                times.append(result.info["render_s"])
            print(f"| {method} | {name} | {1e3 * np.median(times):.2f} | "
                  f"{result.info['mean_samples_per_pixel']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
