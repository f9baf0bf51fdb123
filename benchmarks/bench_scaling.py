"""Every method from 128³ to 1024³: what a user waits for, the device time and memory.

For each method and volume edge ``n`` it renders a procedural CT-like volume (made on
the device by :func:`ct_like_kernel`, so a 1024³ volume takes seconds, handed to
:class:`~vtkillum.core.volume.Volume` with its device copy pre-seeded so it is uploaded
once) at a ``--image``² image and times, with the same Volume object,

* **first image** — the first render of the volume (uploads, light volume, caches;
  kernels are compiled beforehand on a 16³ volume so compilation is not counted);
* **camera move** — the camera orbits 5° (cached light volumes are reused);
* **TF edit** — the opacity transfer function changes (scaled by 0.8 then back);
* **light move** — the light direction turns by 10°.

Columns: the whole call (:func:`vtkillum.core.render.render` with the image on the host,
median of ``--repeats``; the compute mapper tone-maps a kept image on the device instead,
``bench_window.py``),
the device time the method reports (:func:`_timing.kernel_seconds`, "–" where none),
the peak device memory of the row (warp's memory pool on CUDA, reset per row; the CPU
allocator's count on the CPU) beside :func:`vtkillum.core.memory.estimate_bytes`, and
for the first image the ratio of a bandwidth floor to the whole call: ``bytes /
bandwidth`` with bytes the method's estimated device state written once and read once
(``2 × estimate``), H200 4.8 TB/s (``--bandwidth``) — a floor for memory-bound stages,
not a model of the method. Each method's table ends with the exponent of time against
voxel count (least squares on log-log over the measured sizes; 1 is linear). A size
that does not fit on the device (:func:`vtkillum.core.memory.check_fits`) gets a row
saying why, and a last table gives the largest cube per method for the device's free
memory.

``--small`` runs edges 16/24/32 at a 64² image (CI, on a CPU, a few tens of seconds).

Examples
--------
H200, 128–512 (1024 opt-in)::

    python benchmarks/bench_scaling.py --device cuda --json scaling.json
    python benchmarks/bench_scaling.py --device cuda --sizes 1024 --methods emission \\
        transmittance convection-diffusion ambient-scattering

CPU, small::

    python benchmarks/bench_scaling.py --small --methods emission transmittance
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import warp as wp
from _timing import MemoryProbe, device_name, fmt_ms, kernel_seconds

from vtkillum.core.camera import Camera
from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.memory import DeviceMemoryError, check_fits, largest_cubes
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

METHODS = ["emission", "single", "transmittance", "convection-diffusion", "ambient-scattering",
           "photon", "photon-density", "many-lights", "refraction", "path"]
#: Rows that are not render methods: the photon-density *volume* (what PhotonDensityFilter
#: hands to a mapper, rendered by the illumination ray caster), sized like ``photon``.
VOLUME_ROWS = {"photon-density": "photon"}
STEPS = ["first image", "camera move", "TF edit", "light move"]
H200_BANDWIDTH = 4.8e12

init_warp()


# --- the volume, made on the device ----------------------------------------------------------
@wp.func
def hash3(i: int, j: int, k: int, seed: int):
    h = wp.uint32(i * 73856093) ^ wp.uint32(j * 19349663) ^ wp.uint32(k * 83492791 + seed)
    h = (h ^ (h >> wp.uint32(16))) * wp.uint32(0x7FEB352D)
    h = (h ^ (h >> wp.uint32(15))) * wp.uint32(0x846CA68B)
    h = h ^ (h >> wp.uint32(16))
    return float(h) / 4294967295.0


@wp.func
def value_noise(p: wp.vec3, seed: int):
    f = wp.vec3(wp.floor(p[0]), wp.floor(p[1]), wp.floor(p[2]))
    t = p - f
    i, j, k = int(f[0]), int(f[1]), int(f[2])
    s = wp.vec3(t[0] * t[0] * (3.0 - 2.0 * t[0]), t[1] * t[1] * (3.0 - 2.0 * t[1]),
                t[2] * t[2] * (3.0 - 2.0 * t[2]))
    x00 = wp.lerp(hash3(i, j, k, seed), hash3(i + 1, j, k, seed), s[0])
    x10 = wp.lerp(hash3(i, j + 1, k, seed), hash3(i + 1, j + 1, k, seed), s[0])
    x01 = wp.lerp(hash3(i, j, k + 1, seed), hash3(i + 1, j, k + 1, seed), s[0])
    x11 = wp.lerp(hash3(i, j + 1, k + 1, seed), hash3(i + 1, j + 1, k + 1, seed), s[0])
    return wp.lerp(wp.lerp(x00, x10, s[1]), wp.lerp(x01, x11, s[1]), s[2])


@wp.kernel
def ct_like_kernel(out: wp.array3d(dtype=wp.float32), seed: int):
    """A CT-like phantom: body, bone shell, organs, a plume of fine noise.

    ``wp.tid()`` = point ``(i, j, k)`` (x, y, z); coordinates in ``[-1, 1]`` per axis;
    writes a value in ``[0, 1]`` (air 0, soft tissue ~0.3, organs ~0.5, bone ~0.9).
    """
    i, j, k = wp.tid()
    n = wp.vec3(float(out.shape[0] - 1), float(out.shape[1] - 1), float(out.shape[2] - 1))
    p = wp.vec3(2.0 * float(i) / n[0] - 1.0, 2.0 * float(j) / n[1] - 1.0,
                2.0 * float(k) / n[2] - 1.0)
    noise = 0.5 * value_noise(p * 6.0, seed) + 0.25 * value_noise(p * 13.0, seed + 1) \
        + 0.125 * value_noise(p * 29.0, seed + 2)
    body = wp.length(wp.vec3(p[0] / 0.85, p[1] / 0.7, p[2] / 0.95))
    v = 0.0
    if body < 1.0:
        v = 0.28 + 0.08 * noise
        if body > 0.86 and body < 0.93:
            v = 0.9  # bone shell
        organ = wp.length(wp.vec3((p[0] - 0.3) / 0.3, p[1] / 0.25, (p[2] + 0.2) / 0.35))
        if organ < 1.0:
            v = 0.5 + 0.1 * noise
        spine = wp.length(wp.vec3((p[0] + 0.05) / 0.09, (p[1] + 0.45) / 0.09, 0.0))
        if spine < 1.0:
            v = 0.92
    else:
        plume = wp.exp(-8.0 * (p[0] * p[0] + p[1] * p[1])) * wp.max(0.0, p[2] + 1.0)
        v = 0.12 * plume * noise
    out[i, j, k] = v


def device_volume(n: int, device: str, seed: int = 7) -> tuple[Volume, float]:
    """A CT-like ``n³`` Volume made on ``device``; its device copy and caches pre-seeded.

    The scalars are computed by :func:`ct_like_kernel` on the device, downloaded once for
    the host-side Volume (read-only, owned: the Volume keeps it without a copy) and the
    device array is stored as the Volume's ``scalars@device`` (what
    :func:`vtkillum.core.warp_common.device_scalars` reads), so no render uploads it
    again. ``content_key`` is the generator's parameters (the data are a function of
    them), ``value_range`` a host pass over the array. Returns the Volume and the seconds.
    """
    t0 = time.perf_counter()
    scalars = wp.empty((n, n, n), dtype=wp.float32, device=device)
    wp.launch(ct_like_kernel, dim=(n, n, n), inputs=[scalars, int(seed)], device=device)
    host = np.empty((n, n, n), np.float32)
    wp.copy(wp.array(host, dtype=wp.float32, device="cpu", copy=False), scalars)
    wp.synchronize_device(device)
    host.flags.writeable = False
    volume = Volume(host)
    volume.__dict__["content_key"] = f"bench_scaling.ct_like:{n}:{seed}"
    volume.__dict__["value_range"] = (float(host.min()), float(host.max()))
    volume.derived(f"scalars@{device}", None, lambda: scalars)
    return volume, time.perf_counter() - t0


def make_scene(volume: Volume, azimuth: float = 0.0, light_turn: float = 0.0,
               opacity_scale: float = 1.0) -> Scene:
    """The CT-like scene: bone, organs and tissue; one directional key light (every
    method, refraction included, takes it); the camera orbits by ``azimuth`` degrees."""
    tf = TransferFunction([0.0, 0.1, 0.25, 0.32, 0.45, 0.55, 0.8, 1.0],
                          np.array([0.0, 0.0, 0.02, 0.03, 0.0, 0.4, 0.0, 0.9]) * opacity_scale,
                          [[1, 1, 1], [0.9, 0.9, 0.95], [0.95, 0.75, 0.6], [0.95, 0.75, 0.6],
                           [0.85, 0.45, 0.4], [0.85, 0.45, 0.4], [0.95, 0.93, 0.88],
                           [0.95, 0.93, 0.88]])
    a = np.radians(azimuth)
    d = np.array([np.cos(a) * 0.4 - np.sin(a) * 1.0, np.sin(a) * 0.4 + np.cos(a) * 1.0, 0.25])
    cam = Camera.looking_at_bounds(volume.bounds, direction=d, view_up=(0.0, 0.0, 1.0),
                                   view_angle=30.0)
    b = np.radians(light_turn)
    light = DirectionalLight((np.cos(b) * 0.6 - np.sin(b) * 0.3, np.sin(b) * 0.6 + np.cos(b) * 0.3,
                              -0.7), (10.0, 9.6, 9.0))
    n = volume.dims[0]
    return Scene(transfer_function=tf, opacity_unit_distance=max(1.0, n / 64.0), albedo=0.9,
                 anisotropy=0.2, lights=[light], camera=cam, background=(0.05, 0.05, 0.06))


#: Methods drawn by the illumination ray caster (:mod:`vtkillum.core.raycast`), which take
#: its ``textures`` option.
RAYCAST_ROWS = ("emission", "transmittance", "convection-diffusion", "photon-density")


def options_for(method: str, spp: int, textures: bool = True) -> dict:
    if method == "path":
        return {"spp": spp}
    return {} if textures or method not in RAYCAST_ROWS else {"textures": False}


def render_photon_density(volume, scene, width, height, device, **options):
    """The photon-density illumination volume, as ``PhotonDensityFilter`` makes it (its
    defaults: automatic photon count and radius, exact direct light, Historygrams, one
    pass, a grid of the data's size), kept on the device and ray cast by
    :func:`~vtkillum.core.raycast.render_illuminated`; recomputed (incrementally, by the
    Historygrams) when the transfer function or the lights change, as the filter does."""
    from vtkillum.core.photon.illumination import photon_illumination
    from vtkillum.core.photon.mapper import PhotonMapper
    from vtkillum.core.raycast import render_illuminated

    mapper = volume.derived("bench.photon_mapper", device, lambda: PhotonMapper(
        device, 0, 0.0, 0, 1, 0, True, False, "exact"))
    tf = scene.resolved_transfer_function(volume)
    u = scene.resolved_unit_distance(volume)
    key = (tf.opacity.tobytes(), tf.colors.tobytes(), u,
           repr([light.to_dict() for light in scene.lights]))
    t0 = time.perf_counter()
    illumination = volume.derived("bench.photon_density", key, lambda: photon_illumination(
        mapper, volume, tf, u, scene.albedo, scene.anisotropy, scene.lights, volume.dims,
        on_device=True))
    t1 = time.perf_counter()
    result = render_illuminated(volume, scene, width, height, device,
                                illumination=illumination, **options)
    result.info.update(method="photon-density", light_volume_s=t1 - t0)
    return result


def render_row(volume, scene, method, width, height, device, **options):
    """:func:`vtkillum.core.render.render`, or the renderer of a :data:`VOLUME_ROWS` row."""
    if method == "photon-density":
        return render_photon_density(volume, scene, width, height, device, **options)
    return render(volume, scene, method, width, height, device, **options)


# --- measuring --------------------------------------------------------------------------------
def time_step(volume, scenes, method, image, device, repeats, probe, options):
    """Whole call and device time (medians over ``repeats`` renders alternating between
    ``scenes``, each a change from the previous), peak bytes of the row."""
    probe.reset()
    total, kernel = [], []
    for r in range(repeats):
        scene = scenes[r % len(scenes)]
        t0 = time.perf_counter()
        result = render_row(volume, scene, method, image, image, device, **options)
        _ = result.radiance, result.alpha  # the image on the host (a kept one downloads now)
        total.append(time.perf_counter() - t0)
        kernel.append(kernel_seconds(result.info))
    k = None if any(x is None for x in kernel) else float(np.median(kernel))
    return float(np.median(total)), k, probe.peak()


def exponent(sizes, times) -> float | None:
    """Slope of log(time) against log(voxels) (least squares), or None below two sizes."""
    pts = [(float(n) ** 3, t) for n, t in zip(sizes, times) if t and t > 0]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def bench_method(method, sizes, args, device, name, probe, out) -> None:
    label = f"{method} (per spp)" if method == "path" else method
    if args.no_textures and method in RAYCAST_ROWS:
        label += " (arrays, no textures)"
    print(f"\n### {label} — {name}, {args.image}² image\n")
    print("| volume | step | whole call ms | device ms | peak MiB | estimate MiB | "
          "floor/call |")
    print("|---|---|---|---|---|---|---|")
    firsts = {}
    spp = args.spp
    per = spp if method == "path" else 1
    for n in sizes:
        dims = (n, n, n)
        try:
            free = probe.free()
            need = check_fits(VOLUME_ROWS.get(method, method), dims, 1, None, {}, (args.image, args.image), device,
                              free_bytes=free if free is not None else None)
        except DeviceMemoryError as err:
            print(f"| {n}³ | skipped | {err} | | | | |", flush=True)
            out.append({"method": method, "n": n, "skipped": str(err)})
            continue
        volume, made_s = device_volume(n, device)
        base = make_scene(volume)
        steps = {
            "first image": [base],
            "camera move": [make_scene(volume, azimuth=5.0), make_scene(volume, azimuth=10.0)],
            "TF edit": [make_scene(volume, azimuth=10.0, opacity_scale=0.8),
                        make_scene(volume, azimuth=10.0)],
            "light move": [make_scene(volume, azimuth=10.0, light_turn=10.0),
                           make_scene(volume, azimuth=10.0)],
        }
        opts = options_for(method, spp, not args.no_textures)
        try:
            for step in STEPS:
                repeats = 1 if step == "first image" else args.repeats
                total, kernel, peak = time_step(volume, steps[step], method, args.image, device,
                                                repeats, probe, opts)
                total, kernel = total / per, (None if kernel is None else kernel / per)
                floor = ""
                if step == "first image":
                    firsts[n] = total
                    floor = f"{2 * need / args.bandwidth / total:.2g}"
                print(f"| {n}³ | {step} | {fmt_ms(total)} | {fmt_ms(kernel)} | "
                      f"{'–' if peak is None else f'{peak / 2**20:.1f}'} | "
                      f"{need / 2**20:.1f} | {floor} |", flush=True)
                out.append({"method": method, "n": n, "step": step, "whole_s": total,
                            "device_s": kernel, "peak_bytes": peak, "estimate_bytes": need,
                            "volume_made_s": made_s})
        except (MemoryError, RuntimeError) as err:
            print(f"| {n}³ | failed | {type(err).__name__}: {str(err)[:200]} | | | | |",
                  flush=True)
            out.append({"method": method, "n": n, "failed": str(err)})
        del volume, steps, base
        _release(device)
    e = exponent(list(firsts), list(firsts.values()))
    if e is not None:
        print(f"\nfirst image: time ∝ voxels^{e:.2f} over {min(firsts)}³–{max(firsts)}³")
        out.append({"method": method, "exponent_first_image": e})


def _release(device: str) -> None:
    """Drop what the methods keep between calls (caches keyed by device)."""
    import gc

    from vtkillum.core.ambient.render import release_default_caches

    release_default_caches()
    gc.collect()
    wp.synchronize_device(device)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="cpu, cuda (default: cuda if present)")
    ap.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    ap.add_argument("--sizes", type=int, nargs="+", default=None,
                    help="cube edges (default 128 256 512; 1024 on request)")
    ap.add_argument("--image", type=int, default=None, help="square image (default 1024)")
    ap.add_argument("--repeats", type=int, default=3, help="renders per step after the first")
    ap.add_argument("--spp", type=int, default=4, help="samples per pixel timed for path")
    ap.add_argument("--bandwidth", type=float, default=H200_BANDWIDTH,
                    help="device memory bandwidth for the floor column, bytes/s")
    ap.add_argument("--small", action="store_true",
                    help="edges 16 24 32, 64² image, 2 repeats (a CPU in CI)")
    ap.add_argument("--no-textures", action="store_true",
                    help="the ray caster reads arrays, not CUDA textures (for comparison)")
    ap.add_argument("--json", default=None, help="also write the rows to this file")
    args = ap.parse_args(argv)
    if args.small:
        args.sizes = args.sizes or [16, 24, 32]
        args.image = args.image or 64
        args.repeats = min(args.repeats, 2)
        args.spp = min(args.spp, 1)
    args.sizes = args.sizes or [128, 256, 512]
    args.image = args.image or 1024
    device = resolve_device(args.device)
    name = device_name(device)
    rows: list = []
    # compile every method's kernels on a tiny volume first: compilation is not a render
    with MemoryProbe(device) as probe:
        small, _ = device_volume(16, device)
        for method in args.methods:
            render_row(small, make_scene(small), method, 16, 16, device,
                       **options_for(method, 1))
        del small
        _release(device)
        print(f"## bench_scaling — {name}" + ("" if probe.resettable or not probe.cuda else
                                              " (pool high-water not resettable: peaks "
                                              "count from the start)"))
        for method in args.methods:
            bench_method(method, args.sizes, args, device, name, probe, rows)
        free = probe.free()
        if free is None:
            from vtkillum.core.memory import free_device_bytes

            free = free_device_bytes(device)
        print(f"\n### largest volume on this device — {name}, "
              f"{free / 2**30:.1f} GiB free, {args.image}² image, one light\n")
        print("| method | largest cube (estimate) |")
        print("|---|---|")
        cubes = largest_cubes(free, [m for m in args.methods if m not in VOLUME_ROWS], 1, (args.image, args.image), device)
        for method, edge in cubes.items():
            print(f"| {method} | {edge}³ |")
        rows.append({"largest_cube": cubes, "free_bytes": free})
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"device": name, "image": args.image, "rows": rows}, f, indent=1)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
