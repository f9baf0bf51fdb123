"""A time series rendered with and without reading ahead: does it play at the rate of the
slower of reading and rendering?

The script writes ``--steps`` volumes of the procedural plume (``--size`` points along its
longest axis) as one file each (``--format``: ``.nii.gz`` is the slow case, gzip
decompression on the host; ``.vti`` is zlib-compressed VTK XML). It then renders them in
order the way ``vtkillum render`` does: steps from
:class:`~vtkillum.io.time_series.StepPrefetcher` with the CLI's preparation
(:func:`vtkillum.cli.render_preparation`), and :func:`vtkillum.core.render.render` for
each. It does this once with ``--prefetch 0`` and once with each ``--ahead`` value.

For each run it prints these figures:

* the seconds spent reading and rendering, summed over the steps; each read is timed on
  the thread that does it;
* the whole loop's seconds;
* the ideal: the first read plus, for each later step, the larger of its read and the
  render before it. The ratio *ideal / whole* is 1 when reading hides entirely behind
  rendering (or the reverse).

The kernels are compiled and the files are read once before any timing, so the page cache
holds them: this measures decoding and conversion, not the disk. Slow storage makes
reading longer and the gain larger.

Examples
--------
CPU, small::

    python benchmarks/bench_series_prefetch.py --size 96 --steps 4 --image 128

GPU, a clinical-size series::

    python benchmarks/bench_series_prefetch.py --size 384 --steps 8 --image 1024 \\
        --method transmittance --device cuda:0
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

from vtkillum.cli import render_preparation
from vtkillum.core.device import resolve_device
from vtkillum.core.render import render
from vtkillum.data.procedural import default_scene, plume_series
from vtkillum.io.time_series import StepPrefetcher, open_time_series
from vtkillum.io.writers import write_volume


def write_series(directory: Path, steps: int, size: int, fmt: str) -> list[Path]:
    """``steps`` plume volumes, ``size`` points along the longest axis, one file each."""
    shape = (size * 2 // 3, size * 2 // 3, size)
    files = []
    for k, (_, volume) in enumerate(plume_series(steps, shape=shape)):
        path = directory / f"step_{k:03d}{fmt}"
        write_volume(volume, path)
        files.append(path)
    return files


def run(series, scene, method, size, device, ahead) -> dict:
    """Render every step of ``series`` in order, ``ahead`` steps read ahead; timings."""
    reads, renders = {}, []
    lock = threading.Lock()

    def read(step):
        start = time.perf_counter()
        volume = series.read(step)
        with lock:
            reads[step] = time.perf_counter() - start
        return volume

    order = list(range(len(series)))
    start = time.perf_counter()
    with StepPrefetcher(read, ahead, prepare=render_preparation(method)) as prefetcher:
        for n, k in enumerate(order):
            volume = prefetcher.take(k, then=order[n + 1:n + 1 + ahead])
            begin = time.perf_counter()
            render(volume, scene, method, size, size, device)
            renders.append(time.perf_counter() - begin)
            volume = None
    whole = time.perf_counter() - start
    read_s = [reads[k] for k in order]
    ideal = read_s[0] + sum(max(r, c) for r, c in zip(read_s[1:], renders[:-1])) + renders[-1]
    return {"ahead": ahead, "read": sum(read_s), "render": sum(renders), "whole": whole,
            "ideal": ideal}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=96, help="points along the longest axis")
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--image", type=int, default=128, help="image side, pixels")
    parser.add_argument("--method", default="emission")
    parser.add_argument("--format", default=".nii.gz", choices=[".nii.gz", ".nii", ".vti"])
    parser.add_argument("--ahead", type=int, nargs="+", default=[1])
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    device = resolve_device(args.device)
    with tempfile.TemporaryDirectory() as tmp:
        write_series(Path(tmp), args.steps, args.size, args.format)
        series = open_time_series(str(Path(tmp) / f"step_*{args.format}"))
        first = series.read(0)
        scene = default_scene("plume", first)
        render(first, scene, args.method, args.image, args.image, device)  # compile, warm
        for k in range(len(series)):
            series.read(k)  # files in the page cache
        rows = [run(series, scene, args.method, args.image, device, 0)]
        rows += [run(series, scene, args.method, args.image, device, a) for a in args.ahead]
    print(f"{args.steps} steps of {first.dims} ({args.format}), {args.method} "
          f"{args.image}x{args.image} on {device}")
    print("| prefetch | reading s | rendering s | whole s | ideal s | ideal / whole |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['ahead']} | {row['read']:.2f} | {row['render']:.2f} | "
              f"{row['whole']:.2f} | {row['ideal']:.2f} | {row['ideal'] / row['whole']:.2f} |")


if __name__ == "__main__":
    main()
