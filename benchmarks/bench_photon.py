"""Photon mapping with Historygrams: the paper's Table 1 on procedural stand-ins.

Jönsson, Kronander, Ropinski & Ynnerman 2012, Table 1 (GTX 570): photon tracing and
gathering with and without Historygrams after a transfer-function edit. Cases (the
paper's data sets replaced by procedural volumes of the same size):

* ``cornell`` — Cornell box with a sphere (256³), 4.2 M photons, ``S_n = 1``, ``V_n = 7``;
  edit: the sphere's colour (Fig. 4(b), Fig. 7).
* ``engine`` — CT phantom standing in for the engine (256³), 2.1 M photons, ``S_n = 2``
  (Fig. 5: "2 light bounces"), ``V_n = 10``; edit: the lesion's colour and opacity.
* ``cenovix`` — CT phantom at 361×331×361, 1.6 M photons, ``S_n = 1``, ``V_n = 7``;
  edit: the lesion's colour (the paper changes the vessels' colour, Fig. 8).

As in the paper, photons carry all the light (``direct="photons"``) and images are
512² (the paper does not give its viewport). Per case the script prints:

* without Historygrams: a full photon trace (tracing + hash) and a full gather
  (every segment), in ms;
* with Historygrams: the initialisation overhead (gather with ``V_n`` stored segments
  and their Historygrams vs. one segment per pixel), the update after the edit (photon
  query + retrace + hash; segment query + recompute + composite; the best of the repeats,
  each from a fresh first image) with the fraction of photons and segments recomputed,
  and the total speed-up;

beside the paper's numbers, then the issue's targets: a 4 M photon trace (<= 15 ms), a
512² gather (<= 30 ms), a Historygram update of a local edit (<= 10 % of a full
recompute), and the photon-density illumination volume on a 256³ grid from 2 M photons
(<= 20 ms; the scattered fluence gather on the device; then with the copy of the volume to
the host, and with the transmittance of the exact direct light).

GPU (the published numbers)::

    python benchmarks/bench_photon.py

CPU (small sizes: 48³ volumes, 64² images, 1/50 of the photons)::

    python benchmarks/bench_photon.py --small
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.photon.density import fluence_grid
from vtkillum.core.photon.illumination import photon_illumination
from vtkillum.core.photon.mapper import PhotonMapper
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.data.cornell_sphere import cornell_sphere, cornell_sphere_scene
from vtkillum.data.procedural import CT_LESION, ct_phantom, default_scene

#: The paper's Table 1 rows we stand in for: (trace s, gather s, V_n, init overhead,
#: trace update s / % photons, gather update s / % segments, speed-up).
PAPER = {
    "cornell": (0.32, 9.11, 7, "26%", "0.04 s / 3%", "0.57 s / 18%", "15.2x"),
    "engine": (0.37, 5.41, 10, "5%", "0.10 s / 5%", "0.64 s / 19%", "7.7x"),
    "cenovix": (0.11, 1.25, 7, "8%", "0.03 s / 24%", "0.16 s / 4%", "6.8x"),
}


def lesion_edit(tf: TransferFunction, color=(0.2, 0.5, 1.0), opacity=None) -> TransferFunction:
    """``tf`` with the lesion's control point recoloured (and its opacity changed)."""
    colors = tf.colors.copy()
    alpha = tf.opacity.copy()
    i = int(np.argmin(np.abs(tf.scalars - CT_LESION)))
    colors[i] = color
    if opacity is not None:
        alpha[i] = opacity
    return TransferFunction(tf.scalars, alpha, colors)


def cases(small: bool):
    n = 48 if small else 256
    scale = 50 if small else 1

    def cornell():
        volume = cornell_sphere(n)
        scene = cornell_sphere_scene(volume)
        edited = cornell_sphere_scene(volume, color=(0.2, 0.35, 0.9)).transfer_function
        return volume, scene, edited

    def engine():
        volume = ct_phantom(n)
        scene = default_scene("ct", volume)
        return volume, scene, lesion_edit(scene.transfer_function, opacity=0.3)

    def cenovix():
        full = ct_phantom(int(round(361 * n / 256)))
        y0 = (full.dims[1] - int(round(331 * n / 256))) // 2
        ny = int(round(331 * n / 256))
        volume = Volume(full.scalars[:, y0:y0 + ny, :], full.spacing, full.origin)
        scene = default_scene("ct", volume)
        return volume, scene, lesion_edit(scene.transfer_function)

    return {
        "cornell": (cornell, 4_200_000 // scale, 1, 7),
        "engine": (engine, 2_100_000 // scale, 2, 10),
        "cenovix": (cenovix, 1_600_000 // scale, 1, 7),
    }


def ms(t0: float, device: str) -> float:
    wp.synchronize_device(device)
    return 1e3 * (time.perf_counter() - t0)


def run_case(name, make, photons, order, segments, size, device, repeats):
    volume, scene, edited = make()
    camera = scene.resolved_camera(volume)
    u = scene.resolved_unit_distance(volume)
    step = scene.resolved_step_size(volume)
    args = (u, scene.albedo, scene.anisotropy, scene.lights)

    def mapper(historygrams, v_n=segments):
        return PhotonMapper(device, photons, 2.0 * volume.mean_spacing(), order, v_n, 0,
                            historygrams=historygrams, direct="photons")

    # Warm up (kernels compiled, allocations pooled).
    warm = mapper(True)
    warm.update(volume, scene.transfer_function, *args)
    warm.render(volume, camera, size, size, step)
    warm.update(volume, edited, *args)
    warm.render(volume, camera, size, size, step)
    del warm

    trace, gather, plain = [], [], []
    for _ in range(repeats):
        m = mapper(False)
        t0 = time.perf_counter()
        m.update(volume, scene.transfer_function, *args)
        trace.append(ms(t0, device))
        t0 = time.perf_counter()
        m.render(volume, camera, size, size, step)
        gather.append(ms(t0, device))
        one = mapper(False, 1)
        one.update(volume, scene.transfer_function, *args)
        t0 = time.perf_counter()
        one.render(volume, camera, size, size, step)
        plain.append(ms(t0, device))
    # The edit, best of ``repeats`` (each from the same first image: a new mapper's map and
    # segments, then the edit's photon update and image), like the other columns.
    edits = []
    for _ in range(repeats):
        m = mapper(True)
        m.update(volume, scene.transfer_function, *args)
        m.render(volume, camera, size, size, step)
        t0 = time.perf_counter()
        upd = m.update(volume, edited, *args)
        t_trace = ms(t0, device)
        t0 = time.perf_counter()
        m.render(volume, camera, size, size, step)
        t_gather = ms(t0, device)
        edits.append((t_trace + t_gather, t_trace, t_gather, upd, m.last_render))
    _, t_trace, t_gather, upd, rend = min(edits, key=lambda e: e[0])
    full_ms = min(trace) + min(gather)
    return {
        "name": name, "dims": volume.dims, "photons": photons, "order": order,
        "segments": segments, "interactions": m.map.total,
        "trace_ms": min(trace), "gather_ms": min(gather),
        "overhead": min(gather) / min(plain) - 1.0,
        "update_trace_ms": t_trace, "photon_fraction": upd["photon_fraction"],
        "update_gather_ms": t_gather, "segment_fraction": rend["segment_fraction"],
        "speedup": full_ms / (t_trace + t_gather),
        "update_share": (t_trace + t_gather) / full_ms,
    }


def illumination_volume(n, photons, device, repeats):
    """The photon-density illumination volume on an n³ grid (CT phantom, 2 lights)."""
    volume = ct_phantom(n)
    scene = default_scene("ct", volume)
    m = PhotonMapper(device, photons, 2.0 * volume.mean_spacing(), 0, 1, 0)
    tf, u = scene.transfer_function, scene.resolved_unit_distance(volume)
    args = (volume, tf, u, scene.albedo, scene.anisotropy, scene.lights, volume.dims)
    photon_illumination(m, *args)  # warm-up
    fluence_grid(m.grid, m.extinction, volume.dims, volume.extent, device, to_numpy=False)
    gather, host, total, trace = [], [], [], []
    for _ in range(repeats):
        m = PhotonMapper(device, photons, 2.0 * volume.mean_spacing(), 0, 1, 0)
        t0 = time.perf_counter()
        m.update(volume, tf, u, scene.albedo, scene.anisotropy, scene.lights)
        trace.append(ms(t0, device))
        t0 = time.perf_counter()
        fluence_grid(m.grid, m.extinction, volume.dims, volume.extent, device, to_numpy=False)
        gather.append(ms(t0, device))
        t0 = time.perf_counter()
        m.fluence(volume, volume.dims)
        host.append(ms(t0, device))
        t0 = time.perf_counter()
        photon_illumination(m, *args)
        total.append(ms(t0, device))
    return {"n": n, "photons": photons, "interactions": m.map.total, "trace_ms": min(trace),
            "fluence_ms": min(gather), "fluence_host_ms": min(host), "volume_ms": min(total)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--small", action="store_true",
                        help="CPU sizes: 48³ volumes, 64² images, 1/50 of the photons")
    parser.add_argument("--device", default=None)
    parser.add_argument("--image", type=int, default=None, help="image width = height")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--cases", nargs="+", default=["cornell", "engine", "cenovix"])
    args = parser.parse_args(argv)
    device = resolve_device(args.device)
    size = args.image or (64 if args.small else 512)
    repeats = args.repeats or (1 if args.small else 3)
    print(f"device {device}, image {size}², photons carry all light (direct='photons'), "
          f"radius 2 voxels, best of {repeats}")
    rows = []
    table = cases(args.small)
    for name in args.cases:
        make, photons, order, segments = table[name]
        row = run_case(name, make, photons, order, segments, size, device, repeats)
        rows.append(row)
        print(f"  {name}: {row}")
    print("\n| data set | P_n | S_n | trace ms (paper s) | gather ms (paper s) | V_n | init "
          "overhead (paper) | update trace ms / photons (paper) | update gather ms / "
          "segments (paper) | speed-up (paper) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        p = PAPER[r["name"]]
        dims = "×".join(str(d) for d in r["dims"])
        print(f"| {r['name']} {dims} | {r['photons'] / 1e6:.2f} M | {r['order']} | "
              f"{r['trace_ms']:.1f} ({p[0]}) | {r['gather_ms']:.1f} ({p[1]}) | {r['segments']} | "
              f"{100 * r['overhead']:.0f}% ({p[3]}) | {r['update_trace_ms']:.1f} / "
              f"{100 * r['photon_fraction']:.1f}% ({p[4]}) | {r['update_gather_ms']:.1f} / "
              f"{100 * r['segment_fraction']:.1f}% ({p[5]}) | {r['speedup']:.1f}x ({p[6]}) |")

    n = 48 if args.small else 256
    photons = 2_000_000 // (50 if args.small else 1)
    vol = illumination_volume(n, photons, device, repeats)
    trace4 = run_trace(4_000_000 // (50 if args.small else 1), device, args.small)
    print("\nTargets (issue 9; H100/H200):")
    cornell = next((r for r in rows if r["name"] == "cornell"), rows[0])
    print(f"| full photon trace, {trace4['photons'] / 1e6:.2f} M photons (+ hash) | "
          f"{trace4['ms']:.1f} ms | target <= 15 ms (4 M) |")
    print(f"| gather {size}² ({cornell['name']}) | {cornell['gather_ms']:.1f} ms | "
          f"target <= 30 ms |")
    print(f"| Historygram update of a local edit ({cornell['name']}) | "
          f"{100 * cornell['update_share']:.1f}% of a full recompute | target <= 10% |")
    print(f"| photon-density volume {n}³, {photons / 1e6:.2f} M photons: fluence gather | "
          f"{vol['fluence_ms']:.1f} ms | target <= 20 ms |")
    print(f"| ... returned as a numpy array (gather + copy to the host) | "
          f"{vol['fluence_host_ms']:.1f} ms | |")
    print(f"| ... with the photon trace | {vol['trace_ms'] + vol['fluence_ms']:.1f} ms | |")
    print(f"| ... whole volume (update + fluence + transmittance) | {vol['volume_ms']:.1f} ms "
          f"| |")


def run_trace(photons, device, small):
    """A full trace (with hash) of ``photons`` photons through the Cornell box, S_n = 1."""
    volume = cornell_sphere(48 if small else 256)
    scene = cornell_sphere_scene(volume)
    args = (volume, scene.transfer_function, scene.resolved_unit_distance(volume),
            scene.albedo, scene.anisotropy, scene.lights)
    PhotonMapper(device, photons, 2.0 * volume.mean_spacing(), 1, 1, 0,
                 direct="photons").update(*args)
    best = []
    for _ in range(1 if small else 3):
        m = PhotonMapper(device, photons, 2.0 * volume.mean_spacing(), 1, 1, 0,
                         direct="photons")
        t0 = time.perf_counter()
        m.update(*args)
        best.append(ms(t0, device))
    return {"photons": photons, "ms": min(best)}


if __name__ == "__main__":
    main()
