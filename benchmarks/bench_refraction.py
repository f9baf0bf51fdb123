"""Refraction and caustics at the sizes of Magnus & Bruckner 2017, Table 1, beside the paper.

For each data set of the paper's Table 1 (procedural stand-ins of the same
dimensions; the glass is the built-in ``builtin:glass`` at 768 x 768 x 800) and
each viewport (512², 768², 1024²) it renders with the ``refraction`` method at
sample distance 1 (the paper's setting), a refractive-index transfer function
that varies (so ∇η is evaluated everywhere), a coloured medium and soft light
(softness 0.2, direction filter on), and prints

* **texels / plane** — light texels computed per plane on average (each plane's
  cross-section with the box, ``cull_light``; ``--no-cull``: the whole sheared grid);
* **first** — the first frame (ms): tables, buffers and, on CUDA, the capture of the
  plane launches as a graph;
* **frame** — the mean time per frame over ``--frames`` frames (ms) with the camera
  orbiting by a few tenths of a degree per frame (a new camera every frame; the
  plane count is kept, so the captured graph is replayed), image downloaded;
* **sweep** — the part of it spent in the plane sweep on the device (ms);

next to the paper's GTX 1080 numbers (averages over 100 frames) and the speed-up.
The target is 10x the paper on every row (the GTX 1080 is a newer card than the
other papers').

Examples
--------
GPU, the paper's sizes::

    python benchmarks/bench_refraction.py --device cuda

CPU, small (1/8 of each dimension, 64²/96²/128² viewports)::

    python benchmarks/bench_refraction.py --device cpu --small
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from vtkillum.core.camera import Camera
from vtkillum.core.device import resolve_device
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.render import RefractionRenderer
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

#: Table 1 of the paper (GTX 1080, sample distance 1, 100-frame averages): dimensions and
#: ms per frame at 512², 768², 1024².
TABLE1 = {
    "visible-human": ((587, 341, 1878), (43, 83, 130)),
    "supernova": ((432, 432, 432), (71, 95, 132)),
    "piggy-bank": ((512, 512, 134), (68, 128, 207)),
    "glass": ((768, 768, 800), (95, 166, 186)),
    "head": ((512, 512, 333), (64, 110, 174)),
    "hand": ((244, 124, 257), (14, 26, 45)),
    "fly": ((498, 498, 226), (55, 109, 183)),
    "combustion": ((480, 720, 120), (17, 32, 52)),
}
#: View direction and view-up per data set (the paper does not give its cameras): upright
#: bodies from the front, flat data sets across their thin axis (the plane count follows
#: the depth along the view: about 341 planes for the Visible Human from the front).
FRONT = ((0.2, 1.0, -0.15), (0.0, 0.0, 1.0))
ACROSS_Z = ((0.15, 0.2, 1.0), (0.0, 1.0, 0.0))
VIEWS = {"visible-human": FRONT, "supernova": FRONT, "piggy-bank": ACROSS_Z, "head": FRONT,
         "hand": FRONT, "fly": ACROSS_Z, "combustion": ACROSS_Z}
VIEWPORTS = (512, 768, 1024)
TARGET = 10.0


def stand_in(name: str, dims) -> Volume:
    """A procedural volume of ``dims`` (values in [0, 1], unit spacing) with nested structures
    of different refractive index; built slab by slab in float32."""
    if name == "glass":
        from vtkillum.data.procedural import stemmed_glass

        return stemmed_glass(dims[0])
    nx, ny, nz = dims
    x = np.linspace(-1, 1, nx, dtype=np.float32)[:, None]
    y = np.linspace(-1, 1, ny, dtype=np.float32)[None, :]
    out = np.empty(dims, dtype=np.float32)
    for k, z in enumerate(np.linspace(-1, 1, nz, dtype=np.float32)):
        r = np.sqrt(x * x + y * y + z * z)
        wiggle = np.sin(7 * x + 1) * np.sin(9 * y + 2) * np.sin(5 * z + 3)
        shell = np.exp(-((r - 0.6 - 0.05 * wiggle) / 0.1) ** 2)
        core = np.exp(-((x - 0.2) ** 2 + y ** 2 + (z + 0.1) ** 2) / 0.03)
        body = 0.3 * (r < 0.85)
        out[:, :, k] = np.clip(0.5 * shell + 0.6 * core + body, 0.0, 1.0)
    return Volume(out)


def scene_for(volume: Volume, name: str):
    """Camera from :data:`VIEWS`, the light about 33° off the view direction, a transfer
    function with refraction, medium colour and some opacity."""
    if name == "glass":
        from vtkillum.data.procedural import glass_preset

        scene, optics = glass_preset(volume, "wine")
        return scene, optics
    b = volume.bounds.reshape(3, 2)
    centre = b.mean(1)
    radius = 0.5 * np.linalg.norm(b[:, 1] - b[:, 0])
    direction, up = (np.array(a, dtype=np.float64) for a in VIEWS[name])
    direction /= np.linalg.norm(direction)
    camera = Camera(centre - 2.2 * radius * direction, centre, up, view_angle=30.0)
    side = np.cross(direction, up)
    light = DirectionalLight(direction + 0.5 * side / np.linalg.norm(side) - 0.4 * up,
                             (3.0, 3.0, 3.0))
    tf = TransferFunction([0.0, 0.25, 0.5, 0.8, 1.0], [0.0, 0.0, 0.002, 0.05, 0.3],
                          [[1, 1, 1], [1, 1, 1], [0.9, 0.8, 0.6], [1.0, 0.9, 0.8], [1, 1, 1]])
    optics = RefractiveOptics([0.0, 0.25, 0.5, 1.0], [1.0, 1.1, 1.3, 1.4],
                              [0.0, 0.25, 0.6], [[1, 1, 1], [0.95, 0.97, 1.0], [0.8, 0.9, 0.97]])
    scene = Scene(transfer_function=tf, opacity_unit_distance=float(volume.spacing.min()),
                  lights=[light], camera=camera)
    return scene, optics


def orbit(camera: Camera, degrees: float) -> Camera:
    """``camera`` turned about its view-up axis through the focal point."""
    a = np.radians(degrees)
    up = camera.view_up / np.linalg.norm(camera.view_up)
    d = camera.position - camera.focal_point
    d = d * np.cos(a) + np.cross(up, d) * np.sin(a) + up * np.dot(up, d) * (1 - np.cos(a))
    return Camera(camera.focal_point + d, camera.focal_point, camera.view_up, camera.view_angle)


def bench(name: str, dims, viewports, frames: int, device: str, options: dict):
    t0 = time.perf_counter()
    volume = stand_in(name, dims)
    build_s = time.perf_counter() - t0
    scene, optics = scene_for(volume, name)
    renderer = RefractionRenderer(device)
    rows = []
    for size in viewports:
        t0 = time.perf_counter()
        first = renderer.render(volume, scene, size, size, optics=optics, **options)
        first_ms = 1e3 * (time.perf_counter() - t0)
        base = scene.camera
        total = sweep = 0.0
        for f in range(frames):
            scene.camera = orbit(base, 0.3 * (f + 1))
            t0 = time.perf_counter()
            r = renderer.render(volume, scene, size, size, optics=optics, **options)
            total += time.perf_counter() - t0
            sweep += r.info["sweep_s"]
        scene.camera = base
        rows.append({"size": size, "first_ms": first_ms, "frame_ms": 1e3 * total / frames,
                     "sweep_ms": 1e3 * sweep / frames, "planes": first.info["planes"],
                     "light_grid": first.info["light_grid"], "graph": first.info["graph"],
                     "texels": first.info["light_texels"] / first.info["planes"]})
    return build_s, rows


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        import warp as wp

        return wp.get_device(device).name
    return f"CPU ({platform.processor() or platform.machine()}, warp single-threaded)"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="cpu, cuda (default: cuda if present)")
    ap.add_argument("--datasets", nargs="+", default=list(TABLE1), choices=list(TABLE1))
    ap.add_argument("--small", action="store_true",
                    help="1/8 of every dimension and 64²/96²/128² viewports (CPU)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames averaged per row (default 100 on CUDA, 2 on the CPU)")
    ap.add_argument("--sample-distance", type=float, default=1.0)
    ap.add_argument("--softness", type=float, default=0.2)
    ap.add_argument("--no-graph", action="store_true", help="launch plane by plane on CUDA")
    ap.add_argument("--no-cull", action="store_true",
                    help="propagate the light over the whole sheared grid, not only over each "
                         "plane's cross-section with the box")
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    frames = args.frames or (100 if device.startswith("cuda") else 2)
    scale = 8 if args.small else 1
    viewports = tuple(v // scale for v in VIEWPORTS)
    options = {"sample_distance": args.sample_distance, "softness": args.softness,
               "graph": not args.no_graph, "cull_light": not args.no_cull}
    print(f"# refraction (Magnus & Bruckner 2017), {device_name(device)}; "
          f"{frames} frames per row, sample distance {args.sample_distance}, "
          f"softness {args.softness}, direction filter 1")
    # Compile the kernels first so that no row pays for it.
    small = stand_in("hand", (12, 10, 14))
    s, o = scene_for(small, "hand")
    RefractionRenderer(device).render(small, s, 8, 8, optics=o, **options)
    print("| data | dims | viewport | planes | light grid | texels / plane | first ms | frame ms "
          "| sweep ms | paper ms (GTX 1080) | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.datasets:
        dims, paper = TABLE1[name]
        run_dims = tuple(max(8, d // scale) for d in dims)
        build_s, rows = bench(name, run_dims, viewports, frames, device, options)
        for row, paper_ms, size in zip(rows, paper, VIEWPORTS):
            speed = paper_ms / row["frame_ms"]
            label = f"{size}²" if scale == 1 else f"{row['size']}² (for {size}²)"
            print(f"| {name} | {'x'.join(map(str, run_dims))} | {label} | {row['planes']} | "
                  f"{row['light_grid'][0]}x{row['light_grid'][1]} | {row['texels'] / 1e3:.0f} k | "
                  f"{row['first_ms']:.1f} | "
                  f"{row['frame_ms']:.2f} | {row['sweep_ms']:.2f} | {paper_ms} | "
                  f"{speed:.1f}x{'' if speed >= TARGET or scale > 1 else ' (below 10x)'} |",
                  flush=True)
        print(f"<!-- {name}: volume built in {build_s:.1f} s -->")


if __name__ == "__main__":
    main()
