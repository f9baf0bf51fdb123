"""Where the time of photon mapping goes on a GPU (the cases of ``bench_photon.py``).

Per stage -- a full photon trace of 4 M photons with the hash, a full 512² gather of the
Cornell box, and the Historygram update after the sphere's colour edit (photon update,
then the render) -- prints the wall time, the GPU activities (warp's activity timing:
kernels, copies, memsets; summed per name) with their total, and the host functions that
took the most time (cProfile; waiting for the device shows up in ``.numpy()`` and
``synchronize``). ``--stats`` adds the work of the per-sample gather: rows and photons
read per sample and how evenly 32 consecutive samples of a segment share it.

python benchmarks/profile_photon.py --device cuda:0 [--stats]
"""

from __future__ import annotations

import argparse
import collections
import cProfile
import io
import pstats
import time

import numpy as np
import warp as wp
from bench_photon import cases

from vtkillum.core.device import resolve_device
from vtkillum.core.photon import segments as S
from vtkillum.core.photon.density import MeanExtinction, mean_sigma
from vtkillum.core.photon.hashgrid import PhotonGrid, row_photons, row_range, slab_range
from vtkillum.core.photon.mapper import PhotonMapper
from vtkillum.core.photon.storage import gather_int_kernel, select
from vtkillum.core.warp_common import CameraParams, Medium, lookup_sigma_t, sample_scalar


def wall(fn, device):
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    out = fn()
    wp.synchronize_device(device)
    return 1e3 * (time.perf_counter() - t0), out


def activities(fn, device, top=14):
    """GPU activities of one ``fn()``: (count, summed ms) per name, biggest first."""
    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    fn()
    wp.synchronize_device(device)
    results = wp.timing_end()
    per = collections.defaultdict(lambda: [0, 0.0])
    for r in results:
        name = r.name.split("(")[0].replace("forward kernel ", "")
        per[name][0] += 1
        per[name][1] += r.elapsed
    total = sum(v[1] for v in per.values())
    n = sum(v[0] for v in per.values())
    lines = [f"    GPU activities: {n}, summed {total:.2f} ms"]
    for name, (c, t) in sorted(per.items(), key=lambda kv: -kv[1][1])[:top]:
        lines.append(f"      {t:8.3f} ms  x{c:<4d} {name}")
    return "\n".join(lines)


def host_profile(fn, top=18):
    pr = cProfile.Profile()
    pr.enable()
    fn()
    pr.disable()
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(top)
    lines = [ln for ln in s.getvalue().splitlines() if ln.strip()][3:]
    return "\n".join("      " + ln for ln in lines)



@wp.kernel
def gather_stats_kernel(m: Medium, cam: CameraParams, grid: PhotonGrid, me: MeanExtinction,
                        vp: S.ViewParams, work: wp.array(dtype=wp.int32),
                        lengths: wp.array(dtype=wp.int32), max_len: int, n_work: int,
                        out: wp.array(dtype=wp.float64), hist: wp.array(dtype=wp.int64)):
    """``wp.tid()`` = 32 slots ``(segment, sample)`` of a grid of ``max_len`` slots per segment
    (32 consecutive samples of a segment where it is long enough): per sample, the rows and
    photons its gather reads (and how many are within the radius)."""
    g = wp.tid()
    rows_sum = float(0.0)
    read_sum = float(0.0)
    hit_sum = float(0.0)
    cost_max = float(0.0)
    cost_sum = float(0.0)
    active = float(0.0)
    r2 = grid.radius * grid.radius
    for lane in range(32):
        t = g * 32 + lane
        w = t // max_len
        kl = t - w * max_len
        if w >= n_work:
            continue
        if kl >= lengths[w]:
            continue
        row, col, i = S.segment_of(cam, vp, work[w])
        o, d, t0, xi, n = S.ray_setup(m, cam, vp, row, col)
        k0, _k1 = S.segment_samples(n, vp.segments, i)
        k = k0 + kl
        p = o + (t0 + (float(k) + xi) * vp.step) * d
        s = sample_scalar(m.scalars, m.inv_spacing, p)
        if lookup_sigma_t(m, s) <= 0.0:
            continue
        if mean_sigma(me, p) <= 0.0:
            continue
        active += 1.0
        rows = int(0)
        read = int(0)
        hit = int(0)
        z0, z1 = slab_range(grid, p)
        for kk in range(z0, z1 + 1):
            j0, j1, rz2 = row_range(grid, p, kk)
            for j in range(j0, j1 + 1):
                a, b = row_photons(grid, p, j, kk, rz2)
                rows += 1
                read += b - a
                for r in range(a, b):
                    v = grid.pos[r] - p
                    if wp.dot(v, v) <= r2:
                        hit += 1
        rows_sum += float(rows)
        read_sum += float(read)
        hit_sum += float(hit)
        c = float(rows) * 4.0 + float(read)
        cost_sum += c
        cost_max = wp.max(cost_max, c)
        b = int(0)
        while (1 << b) <= read and b < 31:
            b += 1
        wp.atomic_add(hist, b, wp.int64(1))
    wp.atomic_add(out, 0, wp.float64(active))
    wp.atomic_add(out, 1, wp.float64(rows_sum))
    wp.atomic_add(out, 2, wp.float64(read_sum))
    wp.atomic_add(out, 3, wp.float64(hit_sum))
    wp.atomic_add(out, 4, wp.float64(cost_sum))
    wp.atomic_add(out, 5, wp.float64(32.0 * cost_max))
    if active > 0.0:
        wp.atomic_add(out, 6, wp.float64(1.0))


def cornell_case(cells: int = 0):
    """The benchmark's Cornell box: ``(volume, scene, edited scene, camera, step, update
    arguments after the transfer function, photons, S_n, V_n)``; ``cells`` > 0 sets the hash
    cells per radius first."""
    if cells:
        import vtkillum.core.photon.hashgrid as hashgrid

        hashgrid.CELLS_PER_RADIUS = cells
        print(f"hash cells per radius: {cells}")
    make, photons, order, segments = cases(False)["cornell"]
    volume, scene, edited = make()
    targs = (scene.resolved_unit_distance(volume), scene.albedo, scene.anisotropy, scene.lights)
    return (volume, scene, edited, scene.resolved_camera(volume),
            scene.resolved_step_size(volume), targs, photons, order, segments)


def visible_work(m: PhotonMapper, width, height, device):
    """The visible segments of ``m``'s last view, as the full render flags them.

    Returns ``(vp, cam, work, lengths, max_len)``: view parameters, camera, the segment
    indices, their sample counts and the longest a segment can be.
    """
    _, vp, cam, _, _ = m._view
    h, w = height, width
    n_seg = h * w * vp.segments
    state = wp.zeros(n_seg, dtype=wp.int32, device=device)
    t = wp.ones(n_seg, dtype=wp.float32, device=device)
    flags = wp.zeros(n_seg, dtype=wp.int32, device=device)
    seg_len = wp.zeros(n_seg, dtype=wp.int32, device=device)
    wp.launch(S.visible_segments_kernel, dim=(h, w),
              inputs=[m.medium, cam, vp, t, state, flags, seg_len], device=device)
    tiles_x = (w + 7) // 8
    tiles = tiles_x * ((h + 3) // 4)
    n_tiled = vp.segments * tiles * 32
    tflag = wp.empty(n_tiled, dtype=wp.int32, device=device)
    tidx = wp.empty(n_tiled, dtype=wp.int32, device=device)
    wp.launch(S.tiled_flags_kernel, dim=n_tiled, inputs=[cam, vp, tiles_x, tiles, flags, tflag,
                                                          tidx], device=device)
    _, work = select(tflag, tidx, device)
    n_work = int(work.shape[0])
    lengths = wp.empty(n_work, dtype=wp.int32, device=device)
    wp.launch(gather_int_kernel, dim=n_work, inputs=[work, seg_len, lengths], device=device)
    ext = m.medium.extent
    diagonal = float(np.linalg.norm([ext[0], ext[1], ext[2]]))
    max_len = (int(np.ceil(diagonal / vp.step)) + 2) // vp.segments + 2
    return vp, cam, work, lengths, max_len


def gather_stats(m: PhotonMapper, width, height, device):
    """Rows/photons per sample of the full per-sample gather of ``m``'s last view."""
    vp, cam, work, lengths, max_len = visible_work(m, width, height, device)
    n_work = int(work.shape[0])
    out = wp.zeros(8, dtype=wp.float64, device=device)
    hist = wp.zeros(32, dtype=wp.int64, device=device)
    warps = (n_work * max_len + 31) // 32
    ms, _ = wall(lambda: wp.launch(gather_stats_kernel, dim=warps,
                                   inputs=[m.medium, cam, m.grid, m.extinction, vp, work,
                                           lengths, max_len, n_work, out, hist],
                                   device=device), device)
    o = out.numpy()
    lens = lengths.numpy()
    print(f"\n## per-sample gather work ({ms:.0f} ms to count)")
    print(f"    segments {n_work}, samples {int(lens.sum())} (mean {lens.mean():.1f})")
    print(f"    gathering samples {o[0]:.0f}: rows/sample {o[1] / o[0]:.1f}, photons read/sample "
          f"{o[2] / o[0]:.1f}, within radius {o[3] / o[0]:.1f}")
    print(f"    lane efficiency of 32 consecutive samples of a segment (cost = 4 rows + read): "
          f"sum/32max = {o[4] / max(o[5], 1):.3f}")
    hb = hist.numpy()
    print("    photons read per sample, log2 buckets: " + ", ".join(
        f"<{1 << b}:{c}" for b, c in enumerate(hb) if c))
    reads = np.array([(1 << b) * 0.75 for b in range(32)])
    print(f"    share of reads in samples reading >= 256: "
          f"{(hb[9:] * reads[9:]).sum() / max((hb * reads).sum(), 1):.3f}")


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default=None)
    parser.add_argument("--stats", action="store_true")
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--save", default=None,
                        help="save the full and the edited Cornell images to this .npz")
    parser.add_argument("--once", action="store_true",
                        help="one full update and render of the Cornell box, nothing else "
                             "(a target for ncu)")
    parser.add_argument("--cells", type=int, default=0, help="hash cells per radius")
    args = parser.parse_args(argv)
    device = resolve_device(args.device)
    print(f"device {device} ({wp.get_device(device).name})")
    (volume, scene, edited, camera, step, targs, photons, order,
     segments) = cornell_case(args.cells)
    size = args.size

    def mapper(n, s_n, v_n, hg=True):
        return PhotonMapper(device, n, 2.0 * volume.mean_spacing(), s_n, v_n, 0,
                            historygrams=hg, direct="photons")

    if args.once:
        m = mapper(photons, order, segments)
        m.update(volume, scene.transfer_function, *targs)
        m.render(volume, camera, size, size, step)
        wp.synchronize_device(device)
        return

    # Warm-up: every kernel compiled.
    w = mapper(photons, order, segments)
    w.update(volume, scene.transfer_function, *targs)
    w.render(volume, camera, size, size, step)
    w.update(volume, edited, *targs)
    w.render(volume, camera, size, size, step)
    del w

    # 1. Full trace of 4 M photons with the hash (bench_photon.run_trace).
    for rep in range(3):
        m = mapper(4_000_000, 1, 1)
        ms, _ = wall(lambda: m.update(volume, scene.transfer_function, *targs), device)
        print(f"trace 4M, run {rep}: {ms:.2f} ms; stats ms {m.last_update['ms']}")
    m = mapper(4_000_000, 1, 1)
    print("\n## trace 4 M")
    print(activities(lambda: m.update(volume, scene.transfer_function, *targs), device))
    m = mapper(4_000_000, 1, 1)
    print(host_profile(lambda: (m.update(volume, scene.transfer_function, *targs),
                                wp.synchronize_device(device))))

    # 2. Cornell: full update (4.2 M) and full gather.
    m = mapper(photons, order, segments)
    m.update(volume, scene.transfer_function, *targs)
    for rep in range(2):
        m._view = None
        ms, _ = wall(lambda: m.render(volume, camera, size, size, step), device)
        print(f"gather {size}², run {rep}: {ms:.2f} ms; {m.last_render['ms']}")
    m._view = None
    images = {"full": m.render(volume, camera, size, size, step)}
    m._view = None
    print(f"\n## gather {size}²")
    print(activities(lambda: m.render(volume, camera, size, size, step), device))
    m._view = None
    print(host_profile(lambda: m.render(volume, camera, size, size, step)))
    if args.stats:
        gather_stats(m, size, size, device)

    # 3. The sphere's colour edit: photon update and segment update.
    def edit_cycle(profile):
        m = mapper(photons, order, segments)
        m.update(volume, scene.transfer_function, *targs)
        m.render(volume, camera, size, size, step)
        wp.synchronize_device(device)
        if profile == "wall":
            a, _ = wall(lambda: m.update(volume, edited, *targs), device)
            b, images["edited"] = wall(lambda: m.render(volume, camera, size, size, step),
                                       device)
            print(f"edit: update {a:.2f} ms ({m.last_update['ms']}), render {b:.2f} ms "
                  f"({m.last_render['ms']}, {m.last_render['segment_fraction']:.3f} of "
                  f"segments)")
        elif profile == "gpu":
            print("\n## edit: photon update")
            print(activities(lambda: m.update(volume, edited, *targs), device))
            print("\n## edit: render")
            print(activities(lambda: m.render(volume, camera, size, size, step), device))
        else:
            print("\n## edit: host, update then render")
            print(host_profile(lambda: (m.update(volume, edited, *targs),
                                        m.render(volume, camera, size, size, step))))

    for p in ("wall", "wall", "gpu", "host"):
        edit_cycle(p)
    if args.save:
        np.savez(args.save, **{f"{k}_{a}": getattr(v, a) for k, v in images.items()
                               for a in ("radiance", "alpha")})


if __name__ == "__main__":
    main()
