"""Many lights with transmittance caching at the sizes of Weber et al.'s Table 2.

The paper times multiple scattering from 100–2000 virtual lights on a subsampled MANIX
(256³) at 800², with AVSMs of 40² texels x 6 faces x 8 nodes, on a GTX Titan. Here the
stand-in is the procedural CT phantom (:func:`vtkillum.data.procedural.ct_phantom`, skin,
tissue, lesion and bone) with its default scene (two directional lights), and for each VL
count the script measures (ms, device synchronised, kernels compiled beforehand, median of
``--repeat`` runs):

* **RM**: the multiple-scattering image with ray-marched VL transmittance;
* **AVSM creation**: building every VL's shadow map;
* **point** / **trilinear**: the multiple-scattering image with point-sampled and
  trilinear AVSM lookups (the paper's "bilinear" column is its trilinear filtering);
* **walk**: tracing the light paths (counting and writing, optical depths, densities and
  contributions);
* **update**: the first response to a transfer-function edit (eq. 6 contribution update
  along the stored paths, positions and AVSMs kept), and **update + image** with it;
* **regeneration**: progressive regeneration of every path after that edit, all frames
  (``update_fraction`` 0.1, no rendering in between), and the number of frames;
* **single**: the exact single-scattering term alone (paper: 30 ms).

and prints the paper's numbers beside them. The targets of issue 10 on an H100/H200 for
1000 VLs with trilinear AVSMs: creation <= 30 ms, render <= 30 ms, update <= 10 ms,
regeneration <= 0.3 s.

Examples
--------
GPU, the paper's sizes (default)::

    python benchmarks/bench_many_lights.py

CPU, small::

    python benchmarks/bench_many_lights.py --small
"""

from __future__ import annotations

import argparse
import copy
import platform
import time

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.many_lights.cache import ManyLightsState
from vtkillum.core.many_lights.gather import gather_device, gather_params
from vtkillum.core.many_lights.render import parse_options
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.warp_common import make_camera
from vtkillum.data.procedural import ct_phantom, default_scene

#: Table 2 of the paper (GTX Titan, 800², AVSM 40² x 6 x 8): VLs -> (RM, creation, point,
#: bilinear) in ms.
PAPER = {100: (720, 100, 90, 160), 500: (3600, 500, 460, 860), 1000: (7220, 990, 870, 1510),
         2000: (14600, 2300, 1850, 3080)}
#: The paper's single-scattering time (Fig. 1a, 800²).
PAPER_SINGLE = 30.0


def edited_scene(scene):
    """The CT scene with soft tissue made visible and recoloured (the paper's Fig. 6 edit)."""
    tf = scene.transfer_function
    opacity = np.array(tf.opacity, float)
    colors = np.array(tf.colors, float)
    tissue = np.isclose(tf.scalars, 0.5)
    opacity[tissue] = 0.06
    colors[tissue] = (0.9, 0.3, 0.25)
    edited = copy.copy(scene)
    edited.transfer_function = TransferFunction(tf.scalars, opacity, colors)
    return edited


def timed(fn, device: str, repeat: int) -> float:
    """Median wall time of ``fn()`` in ms (device synchronised)."""
    times = []
    for _ in range(repeat):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times))


def run(args) -> list[dict]:
    device = resolve_device(args.device)
    volume = ct_phantom(args.size)
    scene = default_scene("ct", volume)
    edited = edited_scene(scene)
    cam = make_camera(scene.resolved_camera(volume), volume, args.image, args.image)
    shape = (args.image, args.image)
    images = [wp.zeros(shape, dtype=wp.vec3, device=device) for _ in range(2)]
    alpha = wp.zeros(shape, dtype=wp.float32, device=device)
    samples = wp.zeros(shape, dtype=wp.int32, device=device)

    def options(count, transmittance):
        return parse_options({"count": count, "transmittance": transmittance,
                              "avsm_resolution": args.avsm_resolution,
                              "avsm_nodes": args.avsm_nodes, "view_samples": args.view_samples,
                              "update_fraction": 0.1, "seed": 1}, volume, scene)

    def image(state, mode, lookup="trilinear", single=False, multiple=True):
        state.opts["avsm_lookup"] = lookup
        o = state.opts
        params = gather_params(o["step_size"], True, 7, o["early_termination"],
                               o["view_samples"], mode, o["vl_step"], state.scale, single,
                               multiple)
        vls = state.virtual_lights()
        maps = state.maps()
        return lambda: gather_device(state.medium, cam, state.lights, vls, maps, params,
                                     images[0], images[1], alpha, samples, device)

    # Compile every kernel on a small set first.
    warm = ManyLightsState(volume, scene, options(8, "avsm"), device)
    for mode in ("ray-marching", "avsm"):
        image(warm, mode, single=True)()
    warm.update(edited)
    warm.step()

    rows = []
    single_ms = timed(image(warm, "avsm", single=True, multiple=False), device, args.repeat)
    for count in args.vls:
        row = {"vls": count}
        t0 = time.perf_counter()
        state = ManyLightsState(volume, scene, options(count, "ray-marching"), device)
        wp.synchronize_device(device)
        row["walk"] = 1e3 * (time.perf_counter() - t0)
        row["n_vls"], row["paths"] = state.vls.n_vls, state.vls.n_paths
        row["rm"] = timed(image(state, "ray-marching"), device, args.rm_repeat) \
            if not args.skip_rm else float("nan")
        state = ManyLightsState(volume, scene, options(count, "avsm"), device)
        vls, pool, env = state.vls, state.pool, state.environment()
        every = np.arange(vls.n_vls)
        def build(pool=pool, env=env, vls=vls, every=every):
            pool.build(env.medium, vls.dev["position"], every, vls.slot[every], env.avsm_step,
                       env.epoch, env.avsm_stop)

        row["creation"] = timed(build, device, args.repeat)
        row["point"] = timed(image(state, "avsm", "point"), device, args.repeat)
        row["trilinear"] = timed(image(state, "avsm", "trilinear"), device, args.repeat)
        row["avsm_mib"] = pool.nbytes / 2**20
        row["single"] = single_ms
        t0 = time.perf_counter()
        state.update(edited)
        wp.synchronize_device(device)
        row["update"] = 1e3 * (time.perf_counter() - t0)
        row["update_image"] = row["update"] + timed(image(state, "avsm"), device, 1)
        t0 = time.perf_counter()
        frames = 0
        while state.stale:
            state.step()
            frames += 1
        wp.synchronize_device(device)
        row["regeneration"] = 1e3 * (time.perf_counter() - t0)
        row["frames"] = frames
        rows.append(row)
        print_row(row)
    return rows


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        return wp.get_device(device).name
    return f"CPU ({platform.processor() or platform.machine()}, warp single-threaded)"


HEADER = ("| VLs (paths) | RM | AVSM creation | point | trilinear | walk | update | update + image "
          "| regeneration (frames) | single | AVSM MiB | paper RM / creation / point / bilinear |")


def print_row(row: dict) -> None:
    paper = PAPER.get(row["vls"])
    paper_s = " / ".join(f"{v:g}" for v in paper) if paper else "–"
    print(f"| {row['n_vls']} ({row['paths']}) | {row['rm']:.1f} | {row['creation']:.1f} | "
          f"{row['point']:.1f} | {row['trilinear']:.1f} | {row['walk']:.1f} | "
          f"{row['update']:.1f} | {row['update_image']:.1f} | {row['regeneration']:.1f} "
          f"({row['frames']}) | {row['single']:.1f} | {row['avsm_mib']:.0f} | {paper_s} |",
          flush=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--small", action="store_true",
                        help="CPU sizes: 48³ volume, 96² image, 16/32/64 VLs, one repeat")
    parser.add_argument("--size", type=int, default=None, help="volume points per axis (256)")
    parser.add_argument("--image", type=int, default=None, help="image width = height (800)")
    parser.add_argument("--vls", type=int, nargs="+", default=None,
                        help="VL counts (100 500 1000 2000)")
    parser.add_argument("--avsm-resolution", type=int, default=40,
                        help="texels per face edge (paper's Table 2: 40; our default: 48)")
    parser.add_argument("--avsm-nodes", type=int, default=8)
    parser.add_argument("--view-samples", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=None, help="timed runs (median; 5)")
    parser.add_argument("--rm-repeat", type=int, default=1, help="timed runs of RM")
    parser.add_argument("--skip-rm", action="store_true", help="leave out the RM column")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    small = args.small
    args.size = args.size or (48 if small else 256)
    args.image = args.image or (96 if small else 800)
    args.vls = args.vls or ([16, 32, 64] if small else [100, 500, 1000, 2000])
    args.repeat = args.repeat or (1 if small else 5)
    device = resolve_device(args.device or ("cpu" if small else None))
    args.device = device
    print(f"many lights, {device_name(device)}: CT phantom {args.size}³, {args.image}², AVSM "
          f"{args.avsm_resolution}² x 6 x {args.avsm_nodes}, {args.view_samples} view samples, "
          "times in ms")
    print(HEADER)
    print("|" + "---|" * (HEADER.count("|") - 1))
    run(args)


if __name__ == "__main__":
    main()
