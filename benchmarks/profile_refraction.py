"""Per-kernel profile of the refraction plane sweep (``bench_refraction.py``'s scenes).

For each data set it renders one frame plane by plane (no graph) with warp's
per-launch CUDA timing and prints the mean time per plane of every kernel, then
times the graph-replayed frame. ``--micro`` adds a micro-kernel that does
only the volume sampling of the light texels (one fetch of the optics field), to see
what the sampling costs. ``--save`` writes the images (to compare two versions of the code).

Examples
--------
::

    python benchmarks/profile_refraction.py --device cuda:0 --datasets hand visible-human --micro
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time

import numpy as np
import warp as wp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_refraction import TABLE1, scene_for, stand_in

from vtkillum.cli import UserError, _parse_options
from vtkillum.core.device import resolve_device
from vtkillum.core.refraction import sweep
from vtkillum.core.refraction.planes import SweepParams, texel_position
from vtkillum.core.refraction.preintegration import RefractiveMedium
from vtkillum.core.refraction.ray_equation import camera_sample_and_gradient
from vtkillum.core.refraction.render import RefractionRenderer
from vtkillum.core.refraction.view_rays import ACTIVE


@wp.kernel
def sample_only(m: RefractiveMedium, params: wp.array(dtype=SweepParams), j: int,
               out: wp.array(dtype=wp.vec3)):
    """The value and ``∇η`` (the seven data fetches) at every light texel of plane ``j``."""
    t = wp.tid()
    p = params[0]
    if t >= p.nx * p.ny:
        return
    b = t / p.nx
    a = t - b * p.nx
    s, g, _inside = camera_sample_and_gradient(m, p.frame,
                                               texel_position(p, float(a), float(b), j))
    out[t] = g * s


def cached_stand_in(name: str, dims):
    """:func:`stand_in`, kept as ``.npy`` under ``$REFRACTION_VOLUME_CACHE`` when it is set
    (two profiles of the same data set then build it once)."""
    cache = os.environ.get("REFRACTION_VOLUME_CACHE")
    if not cache or name == "glass":
        return stand_in(name, dims)
    from vtkillum.core.volume import Volume

    path = os.path.join(cache, f"{name}.npy")
    if os.path.exists(path):
        return Volume(np.load(path))
    volume = stand_in(name, dims)
    os.makedirs(cache, exist_ok=True)
    np.save(path, volume.scalars)
    return volume


def per_kernel(results) -> dict:
    """Total ms and launch count per kernel name."""
    acc = collections.defaultdict(lambda: [0.0, 0])
    for r in results:
        name = r.name.split("_cuda_kernel")[0]
        for prefix in ("forward kernel ", "kernel "):
            name = name.removeprefix(prefix)
        acc[name][0] += r.elapsed
        acc[name][1] += 1
    return acc


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--datasets", nargs="+", default=["hand", "visible-human"], choices=list(TABLE1))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--micro", action="store_true", help="also the sampling micro-kernels")
    ap.add_argument("--variants", default=None,
                    help="comma-separated LIGHT_MAX_REGISTERS:VIEW_MAX_REGISTERS:BLOCK_DIM[:fast] "
                         "settings of the sweep kernels to compare (0: no register cap)")
    ap.add_argument("--save", default=None, help="write the images to this .npz")
    ap.add_argument("--ncu", action="store_true", help="one plane-by-plane frame only (for ncu)")
    ap.add_argument("--option", nargs="+", default=[], metavar="KEY=VALUE",
                    help="render options to change, VALUE in JSON, as vtkillum render's "
                         "--option (e.g. light_buffer_scale=2 direction_blur=0)")
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    options = {"sample_distance": 1.0, "softness": 0.2}
    try:  # the command line's KEY=VALUE (JSON values) parsing
        options.update(_parse_options(args.option))
    except UserError as exc:
        ap.error(str(exc))
    images = {}
    for name in args.datasets:
        dims = TABLE1[name][0]
        volume = cached_stand_in(name, dims)
        scene, optics = scene_for(volume, name)
        for variant in (args.variants or "default").split(","):
            if variant != "default":
                parts = variant.split(":")
                sweep.LIGHT_MAX_REGISTERS, sweep.VIEW_MAX_REGISTERS = int(parts[0]), int(parts[1])
                sweep.BLOCK_DIM = int(parts[2])
                sweep.FAST_MATH = len(parts) > 3
            profile(args, name, dims, volume, scene, optics, options, device, variant, images)
    if args.save:
        np.savez(args.save, **images)


def profile(args, name, dims, volume, scene, optics, options, device, variant, images):
    """Plane-by-plane frame with per-kernel times, then graph replays."""
    renderer = RefractionRenderer(device)
    size = args.size
    if args.ncu:
        renderer.render(volume, scene, size, size, optics=optics, graph=False, **options)
        return
    r = renderer.render(volume, scene, size, size, optics=optics, graph=False, **options)
    planes = r.info["planes"]
    nx, ny = r.info["light_grid"]
    wp.synchronize_device(device)
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMCPY)
    r = renderer.render(volume, scene, size, size, optics=optics, graph=False, **options)
    acc = per_kernel(wp.timing_end())
    images[f"{name}_{variant}"] = r.radiance
    print(f"## [{variant}] {name} {'x'.join(map(str, dims))} at {size}²: {planes} planes, "
          f"light grid {nx}x{ny} = {nx * ny} texels, {size * size} pixels; active view rays at the end: "
          f"{int((renderer.buffers.view['state'].numpy()[: size * size] == ACTIVE).sum())}")
    print("| kernel | launches | total ms | us per launch |")
    print("|---|---|---|---|")
    for k, (ms, n) in sorted(acc.items(), key=lambda kv: -kv[1][0]):
        print(f"| {k} | {n} | {ms:.2f} | {1e3 * ms / n:.1f} |")
    # Graph replay, as in the benchmark.
    renderer.render(volume, scene, size, size, optics=optics, **options)
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    sweep_s = 0.0
    for _ in range(args.frames):
        r = renderer.render(volume, scene, size, size, optics=optics, **options)
        sweep_s += r.info["sweep_s"]
    frame = (time.perf_counter() - t0) / args.frames
    print(f"graph replay: frame {1e3 * frame:.2f} ms, sweep {1e3 * sweep_s / args.frames:.2f} ms, "
          f"{1e6 * sweep_s / args.frames / planes:.1f} us per plane")
    if args.micro:
        micro(renderer, volume, planes, nx * ny, device)
    sys.stdout.flush()


def micro(renderer, volume, planes, texels, device):
    """Micro-kernel over every light plane: the volume sampling alone."""
    medium = renderer._medium
    params = renderer._params
    out = wp.zeros(texels, dtype=wp.vec3, device=device)
    for j in range(3):  # warm-up
        wp.launch(sample_only, dim=texels, inputs=[medium, params, j, out], device=device)
    wp.synchronize_device(device)
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
    for j in range(planes):
        wp.launch(sample_only, dim=texels, inputs=[medium, params, j, out], device=device)
    for k, (ms, n) in per_kernel(wp.timing_end()).items():
        print(f"micro {k}: {1e3 * ms / n:.1f} us per plane ({texels} texels, "
              f"{1e12 * ms / n / 1e3 / texels:.2f} ns per texel)")


if __name__ == "__main__":
    main()
