"""Where the time of one interactive update goes: kernels, launches, host work.

For a convection–diffusion light simulation after a transfer-function edit (the rows of
Zhang & Ma's Table 1, see ``bench_convection_diffusion.py``) and an ambient-scattering
g / light edit (``bench_ambient.py``), prints per update:

* the wall time with launch graphs (the default) and launch by launch
  (``VTKILLUM_GRAPHS=0`` semantics, :mod:`vtkillum.core.graphs`);
* on CUDA, from warp's activity timing of a launch-by-launch update: the number of
  kernel launches and memsets, the summed GPU time of the kernels, and the kernels
  taking most of it. The gap between the wall time and the GPU time is what launches
  and host work cost.

Examples
--------
python benchmarks/profile_updates.py --device cuda:0
python benchmarks/profile_updates.py --device cpu --rows Buckyball --repeats 1
"""

from __future__ import annotations

import argparse
import collections
import functools
import time

import numpy as np
import warp as wp
from bench_convection_diffusion import (
    PAPER_TABLE_1,
    TF_A,
    TF_B,
    device_name,
    make_lights,
    synthetic,
)

from vtkillum.core.convection_diffusion import ConvectionDiffusionSolver
from vtkillum.core.device import resolve_device


def timed(fn, device, repeats):
    """Median wall ms of ``fn(1) ... fn(repeats)`` (after each, the device is idle)."""
    samples = []
    for r in range(1, repeats + 1):  # fn(0) came last: every call is an edit
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        fn(r)
        wp.synchronize_device(device)
        samples.append(1000.0 * (time.perf_counter() - t0))
    return float(np.median(samples))


def kernel_profile(fn, device):
    """Launch count, memset count, summed kernel ms and the top kernels of one ``fn()``."""
    if not wp.get_device(device).is_cuda:
        return None
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMSET)
    fn()
    results = wp.timing_end()
    per = collections.defaultdict(lambda: [0, 0.0])
    memsets = 0
    for r in results:
        if r.filter == wp.TIMING_MEMSET:
            memsets += 1
            continue
        name = r.name.split("(")[0].replace("forward kernel ", "")
        per[name][0] += 1
        per[name][1] += r.elapsed
    launches = sum(v[0] for v in per.values())
    total = sum(v[1] for v in per.values())
    top = sorted(per.items(), key=lambda kv: -kv[1][1])[:6]
    return launches, memsets, total, top


def cd_rows(rows, device, repeats, model):
    print(f"\n### Convection–diffusion, light simulation after a TF edit ({model} model), "
          f"device {device_name(device)}\n")
    print("| data | light volume | lights | start | graphs ms | opacity / convection per light / "
          "composition / diffusion ms | launch by launch ms | launches | memsets | "
          "kernel ms (sum) | top kernels (count, ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, dims, light_dims, count in rows:
        vol = synthetic(dims)
        lights = make_lights(vol, count)
        for warm in (False, True):
            cds, iterations = {}, []
            for graphs in (True, False):
                cd = ConvectionDiffusionSolver(light_volume_shape=light_dims,
                                               diffusion_model=model, warm_start=warm,
                                               device=device)
                cd._graphs.enabled = graphs
                cds[graphs] = cd

                def edit(r, cd=cd, graphs=graphs, vol=vol, lights=lights, label=label,
                         iterations=iterations):
                    stats = cd.update(vol, TF_B if r % 2 == 0 else TF_A, vol.mean_spacing(),
                                      lights, volume_key=label, albedo=0.9, anisotropy=0.3)
                    if cd._radiative is not None:
                        cd._radiative[1].graphs.enabled = graphs
                    if graphs and stats.diffusion is not None:
                        iterations.append(stats.diffusion.iterations)
                    return stats

                edit(1)  # upload, allocate, compile, record
                edit(0)
                cds[graphs] = (cd, edit, timed(edit, device, repeats))
            cds[False][1](0)  # then edit(1) changes the transfer function, whatever came last
            prof = kernel_profile(functools.partial(cds[False][1], 1), device)
            cds[True][1](0)
            st = cds[True][1](1)  # one more edit, for its stages
            flags = "".join(f", {name}" for name in ("fallback", "stalled")
                            if st.diffusion is not None and getattr(st.diffusion, name))
            rd = cds[True][0]._radiative[1]
            flags += f", {cds[True][0]._graphs.captures + rd.graphs.captures} captures"
            stages = (f"{st.ms.get('opacity', 0):.2f} / "
                      f"{np.mean(st.ms.get('convection') or [0]):.2f} / "
                      f"{st.ms.get('composition', 0):.2f} / {st.ms.get('diffusion', 0):.2f}")
            its = f"{np.median(iterations):.0f}" if iterations else "?"
            cells = "| — | — | — | — |" if prof is None else (
                f"| {prof[0]} | {prof[1]} | {prof[2]:.2f} | "
                + "; ".join(f"{n} ({c}, {ms:.2f})" for n, (c, ms) in prof[3]) + " |")
            print(f"| {label} | {'x'.join(map(str, light_dims))} | {count} | "
                  f"{'warm' if warm else 'cold'} ({its} it{flags}) | {cds[True][2]:.2f} | {stages} | "
                  f"{cds[False][2]:.2f} {cells}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--rows", nargs="*", default=None, help="Table-1 rows (default: all)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--models", nargs="*", default=["physical"])
    opts = ap.parse_args(argv)
    device = resolve_device(opts.device)
    rows = [r for r in PAPER_TABLE_1 if opts.rows is None or r[0] in opts.rows]
    for model in opts.models:
        cd_rows(rows, device, opts.repeats, model)


if __name__ == "__main__":
    main()
