"""The floor of a dependent kernel launch: ``N`` launches captured as one CUDA graph and
replayed, microseconds per launch, for kernels of 1 thread up to one float per cell of
a 128³ grid.

Every grid-wide dependent step of a method (a red–black colour, a multigrid transfer, a
light plane) costs at least this much on the device, whatever its work. Used in
``docs/benchmarks.md`` to judge which speed targets a device can meet.

Examples
--------
::

    python benchmarks/launch_floor.py --device cuda:0
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device


@wp.kernel
def bump(a: wp.array(dtype=wp.float32)):
    i = wp.tid()
    if i == 0:
        a[0] = a[0] + 1.0


@wp.kernel
def touch(a: wp.array(dtype=wp.float32), n: int):
    i = wp.tid()
    if i < n:
        a[i] = a[i] * 0.5 + 1.0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda:0", help="a CUDA device (graphs need one)")
    ap.add_argument("--launches", type=int, nargs="+", default=[100, 400])
    ap.add_argument("--repeats", type=int, default=9)
    args = ap.parse_args(argv)
    try:
        device = wp.get_device(resolve_device(args.device))
    except ValueError as exc:
        ap.error(str(exc))
    if not device.is_cuda:
        ap.error(f"--device must be a CUDA device, got {args.device!r}")
    sms = device.sm_count
    cases = [("1 thread", 1, bump), (f"{sms} x 1024 threads, a float each", sms * 1024, touch),
             ("128^3 / 8 threads, a float each", 128 ** 3 // 8, touch),
             ("128^3 threads, a float each", 128 ** 3, touch)]
    a = wp.zeros(128 ** 3, dtype=wp.float32, device=device)
    print(f"\n### Dependent launches replayed from a CUDA graph, device {device.name}\n")
    print("| kernel | launches | µs per launch |")
    print("|---|---|---|")
    for label, dim, kernel in cases:
        inputs = [a] if kernel is bump else [a, dim]
        for n in args.launches:
            wp.launch(kernel, dim=dim, inputs=inputs, device=device)
            wp.synchronize_device(device)
            wp.capture_begin(device)
            for _ in range(n):
                wp.launch(kernel, dim=dim, inputs=inputs, device=device)
            graph = wp.capture_end(device)
            wp.capture_launch(graph)
            times = []
            for _ in range(args.repeats):
                wp.synchronize_device(device)
                t0 = time.perf_counter()
                wp.capture_launch(graph)
                wp.synchronize_device(device)
                times.append(time.perf_counter() - t0)
            print(f"| {label} | {n} | {1e6 * np.median(times) / n:.2f} |", flush=True)


if __name__ == "__main__":
    main()
