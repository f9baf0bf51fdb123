"""Ambient scattering against the unbiased path tracer on a suite of small scenes.

Prints, per scene and per (gather, radius), the relative RMSE
``sqrt(mean((img - ref)²) / mean(ref²))`` over pixels and channels and the energy ratio
``sum(img) / sum(ref)``, then the means over the suite (RMSE and ``|ln energy|``). These
are the tables of ``docs/ambient_scattering.md``.

Scenes (``--resolution`` points per axis, default 32; the camera frames the box):

====================  ===========================================================
``cloud_S_A_G_L``     a lumpy cloud with extinction ``S`` (1/world; the box is
                      [-1, 1]³), albedo ``A``, HG ``g = G``, light ``L``: ``dir``
                      (side), ``back`` (behind the cloud), ``front`` (behind the
                      camera) or ``point``
``blobs_S_A_G``       two Gaussian blobs, coloured transfer function, one
                      directional and one point light
``ball_S_A_G``        a dense ball with a sharp (one-voxel) edge, side light
``ct_A_G``            ``ct_phantom`` with its default scene (two lights), albedo
                      and g replaced
``plume_A_G``         ``smoke_plume`` with its default scene, albedo and g replaced
====================  ===========================================================

References: ``path`` with ``--spp`` samples (default 1024) and no bounce cap to speak of
(1000), seed 7, cached as ``.npz`` in ``--cache`` (default ``/tmp/vtkillum-ambient-refs``).
``--before`` also renders the method as it was before issue 8 (the paper's gather and one
sample of ``σ̃t`` per tube step). Tables for albedo 0.5 and 0.99 are generated on demand
(about 30 s each on one CPU core, then cached).

Examples
--------
python benchmarks/ambient_accuracy.py                         # 32³, 48², r = 1 2 3 4 6 8
python benchmarks/ambient_accuracy.py --resolution 64 --radii 2 3 4 6 8
python benchmarks/ambient_accuracy.py --scenes cloud_10_0.95_0.4_dir --radii 2 4 8 14 --before
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from vtkillum.core.ambient.cache import STEP_SAMPLES, TUBE_SAMPLING, AmbientScatteringCache
from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.data.procedural import ct_phantom, default_scene, smoke_plume

SUITE = [
    "cloud_30_0.9_0.4_dir",     # thick cloud (optical radius ~22), side light
    "cloud_30_0.99_0.8_back",   # thick, albedo 0.99, strongly forward, lit from behind
    "cloud_30_0.5_-0.3_point",  # thick, albedo 0.5, backward, point light
    "cloud_3_0.9_0.0_dir",      # thin (optical radius ~2)
    "cloud_10_0.9_0.4_front",   # medium, lit from behind the camera
    "blobs_15_0.9_0.4",         # two soft blobs, directional + point light
    "ball_40_0.9_0.0",          # dense ball, sharp edge
    "ct_0.9_0.0",               # layered CT phantom
    "plume_0.9_0.4",            # smoke plume
    "cloud_3_0.99_0.8_back",    # thin, albedo 0.99, strongly forward, lit from behind
    "ct_0.5_-0.3",              # layered CT, albedo 0.5, backward
]
U = 0.1  # opacity unit distance of the synthetic scenes


def grid(n):
    x = np.linspace(-1, 1, n)
    return np.meshgrid(x, x, x, indexing="ij")


def box(n):
    return {"spacing": (2 / (n - 1),) * 3, "origin": (-1, -1, -1)}


def cloud(n, seed=3):
    rng = np.random.default_rng(seed)
    X, Y, Z = grid(n)
    f = np.zeros_like(X)
    for _ in range(12):
        k = rng.normal(0, 3.0, 3)
        f += np.cos(k[0] * X + k[1] * Y + k[2] * Z + rng.uniform(0, 2 * np.pi))
    f /= np.sqrt(12.0)
    R = np.sqrt(X**2 + (1.2 * Y) ** 2 + Z**2)
    return Volume(np.clip((0.75 - R + 0.12 * f) / 0.15, 0, 1).astype(np.float32), **box(n))


def blobs(n):
    X, Y, Z = grid(n)
    big = np.exp(-((X + 0.15) ** 2 + Y**2 + (Z - 0.1) ** 2) / 0.3)
    small = 0.8 * np.exp(-((X - 0.55) ** 2 + (Y - 0.5) ** 2 + (Z + 0.3) ** 2) / 0.06)
    return Volume((big + small).astype(np.float32), **box(n))


def ball(n):
    X, Y, Z = grid(n)
    R = np.sqrt(X**2 + Y**2 + Z**2)
    return Volume(np.clip((0.8 - R) / 0.1, 0, 1).astype(np.float32), **box(n))


def ramp(sigma):
    """Opacity ramp whose value 1 has extinction ``sigma`` (1/world units)."""
    return TransferFunction([0, 1], [0, 1 - np.exp(-sigma * U)])


def make(name: str, n: int = 32):
    """The volume and scene of a suite entry (see the module docstring)."""
    kind, *p = name.split("_")
    side = DirectionalLight((1, -0.3, -0.5), (1, 1, 1))
    if kind == "cloud":
        sigma, albedo, g, light = float(p[0]), float(p[1]), float(p[2]), p[3]
        vol = cloud(n)
        lights = {"dir": [side], "back": [DirectionalLight((0.3, -0.2, 1.0), (1, 1, 1))],
                  "front": [DirectionalLight((0.3, -0.3, -1.0), (1, 1, 1))],
                  "point": [PointLight((1.4, 1.2, 0.9), (4, 4, 4))]}[light]
        cam = Camera.looking_at_bounds(vol.bounds, direction=(0, 0, -1), view_up=(0, 1, 0))
        return vol, Scene(transfer_function=ramp(sigma), opacity_unit_distance=U, albedo=albedo,
                          anisotropy=g, lights=lights, camera=cam)
    if kind == "blobs":
        sigma, albedo, g = (float(v) for v in p)
        vol = blobs(n)
        tf = TransferFunction([0, 0.15, 1.0], [0, 0, 1 - np.exp(-sigma * U)],
                              [[0.4, 0.6, 1.0], [0.4, 0.6, 1.0], [1.0, 0.8, 0.5]])
        cam = Camera.looking_at_bounds(vol.bounds, direction=(-0.4, -0.3, -1.0),
                                       view_up=(0, 1, 0))
        return vol, Scene(transfer_function=tf, opacity_unit_distance=U, albedo=albedo,
                          anisotropy=g, lights=[DirectionalLight((1.0, -0.3, 0.2), (1, 1, 1)),
                                                PointLight((0.2, 1.6, 0.5), (3, 3, 3))],
                          camera=cam)
    if kind == "ball":
        sigma, albedo, g = (float(v) for v in p)
        vol = ball(n)
        cam = Camera.looking_at_bounds(vol.bounds, direction=(0, 0, -1), view_up=(0, 1, 0))
        return vol, Scene(transfer_function=ramp(sigma), opacity_unit_distance=U, albedo=albedo,
                          anisotropy=g, lights=[side], camera=cam)
    if kind in ("ct", "plume"):
        albedo, g = (float(v) for v in p)
        vol = ct_phantom(n) if kind == "ct" else smoke_plume((n, n, 3 * n // 2))
        scene = default_scene(kind, vol)
        scene.albedo, scene.anisotropy = albedo, g
        return vol, scene
    raise ValueError(f"unknown scene {name!r}")


def reference(name: str, n: int, size: int, spp: int, cache: Path) -> np.ndarray:
    """The path-traced image of a scene (cached)."""
    path = cache / f"{name}_n{n}_{size}px_{spp}spp.npz"
    if path.exists():
        with np.load(path) as data:
            return data["radiance"]
    vol, scene = make(name, n)
    t = time.perf_counter()
    res = render(vol, scene, "path", size, size, device="cpu", spp=spp, max_bounces=1000, seed=7)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, radiance=res.radiance)
    print(f"(reference {name} at {n}³: {time.perf_counter() - t:.0f} s)", flush=True)
    return res.radiance


def ambient(name: str, n: int, size: int, radius: float, gather: str, device: str,
            before: bool = False, tube_sampling: str = "field",
            step_samples: int = STEP_SAMPLES) -> np.ndarray:
    vol, scene = make(name, n)
    if before:  # one sample of σ̃t per tube step, at the step's middle (the paper's)
        tube_sampling = "paper"
    cache = AmbientScatteringCache(device, tube_sampling=tube_sampling,
                                   step_samples=step_samples)
    return render(vol, scene, "ambient-scattering", size, size, device=device,
                  radius=radius, gather=gather, cache=cache).radiance


def errors(img, ref):
    return (float(np.sqrt(np.mean((img - ref) ** 2) / np.mean(ref**2))),
            float(img.sum() / ref.sum()))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=SUITE)
    ap.add_argument("--resolution", type=int, default=32, help="grid points per axis")
    ap.add_argument("--size", type=int, default=48, help="square image size")
    ap.add_argument("--spp", type=int, default=1024, help="path samples per pixel")
    ap.add_argument("--radii", type=float, nargs="+", default=[1, 2, 3, 4, 6, 8],
                    help="ambient radii in voxels")
    ap.add_argument("--gathers", nargs="+", default=["centred", "paper"],
                    choices=["centred", "paper"])
    ap.add_argument("--before", action="store_true",
                    help="also the method before issue 8 (paper gather, 1 sample per tube step)")
    ap.add_argument("--single", action="store_true", help="also the single-scattering method")
    ap.add_argument("--tube-sampling", default="field", choices=list(TUBE_SAMPLING),
                    help="how the tube march measures a step's extinction (cache option)")
    ap.add_argument("--step-samples", type=int, default=STEP_SAMPLES,
                    help="samples of the step field per tube step (cache option)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/vtkillum-ambient-refs"))
    args = ap.parse_args(argv)

    columns = [(g, r, False) for g in args.gathers for r in args.radii]
    if args.before:
        columns += [("paper", r, True) for r in args.radii]
    labels = [("before" if b else g) + f" r={r:g}" for g, r, b in columns]
    if args.single:
        labels.append("single")
    print(f"relative RMSE / energy ratio vs path ({args.spp} spp), {args.resolution}³, "
          f"{args.size}² pixels, radius in voxels")
    print("| scene | " + " | ".join(labels) + " |")
    print("|---" * (len(labels) + 1) + "|")
    table = {lab: [] for lab in labels}
    for name in args.scenes:
        ref = reference(name, args.resolution, args.size, args.spp, args.cache)
        cells = []
        for lab, (g, r, b) in zip(labels, columns):
            e = errors(ambient(name, args.resolution, args.size, r, g, args.device, b,
                               args.tube_sampling, args.step_samples), ref)
            table[lab].append(e)
            cells.append(f"{e[0]:.3f} / {e[1]:.2f}")
        if args.single:
            vol, scene = make(name, args.resolution)
            e = errors(render(vol, scene, "single", args.size, args.size,
                              device=args.device).radiance, ref)
            table["single"].append(e)
            cells.append(f"{e[0]:.3f} / {e[1]:.2f}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    means = [f"**{np.mean([e[0] for e in table[lab]]):.3f} / "
             f"{np.mean([abs(np.log(e[1])) for e in table[lab]]):.2f}**" for lab in labels]
    print("| mean RMSE / mean abs(ln energy) | " + " | ".join(means) + " |")


if __name__ == "__main__":
    main()
