"""Register caps and block sizes of the photon kernels (GPU tuning).

For a full 512² gather of the Cornell box (4.2 M photons) times the per-sample gather
(``sample_light_kernel``) and the segment shading (``shade_segment_kernel``) compiled under
several register caps and launched with several block sizes, and (``--trace``) the tracing
kernel of a 4 M photon trace; checks that every variant writes the same bits as the
library's kernel. How ``SAMPLE_REGISTERS``, ``SHADE_REGISTERS`` (segments.py) and
``TRACE_REGISTERS`` (tracing.py) were chosen. ``--cells`` changes the hash's cells per
photon radius (the photons summed stay the same).

python benchmarks/gather_variants.py --device cuda:0 --regs 0 40 48 64 --blocks 128 256
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp
from profile_photon import cornell_case, visible_work

from vtkillum.core.device import resolve_device
from vtkillum.core.photon import segments as S
from vtkillum.core.photon import tracing as T
from vtkillum.core.photon.mapper import PhotonMapper
from vtkillum.core.photon.storage import exclusive_scan


def timed(fn, device, reps=3):
    out = []
    for _ in range(reps):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        out.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(out))


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default=None)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--regs", type=int, nargs="*", default=[0, 40, 48, 64])
    parser.add_argument("--blocks", type=int, nargs="*", default=[128, 256])
    parser.add_argument("--trace", action="store_true")
    parser.add_argument("--shade-regs", type=int, nargs="*", default=[0, 32, 40, 48, 64])
    parser.add_argument("--skip-flat", action="store_true")
    parser.add_argument("--cells", type=int, default=0, help="hash cells per radius")
    parser.add_argument("--save", default=None)
    args = parser.parse_args(argv)
    device = resolve_device(args.device)
    (volume, scene, edited, camera, step, targs, photons, order,
     segments) = cornell_case(args.cells)
    size = args.size
    m = PhotonMapper(device, photons, 2.0 * volume.mean_spacing(), order, segments, 0,
                     direct="photons")
    m.update(volume, scene.transfer_function, *targs)
    image = m.render(volume, camera, size, size, step)
    if args.save:
        np.savez(args.save, full_radiance=image.radiance, full_alpha=image.alpha)
    vp, cam, work, lengths, max_len = visible_work(m, size, size, device)
    n_work = int(work.shape[0])
    offsets = wp.empty(n_work, dtype=wp.int32, device=device)
    total = exclusive_scan(lengths, offsets)
    print(f"segments {n_work}, samples {total}, max_len {max_len}")


    sample_work = wp.empty(total, dtype=wp.int32, device=device)
    wp.launch(S.sample_segments_kernel, dim=n_work * 32,
              inputs=[offsets, lengths, 0, 0, sample_work], device=device)
    lib_rays = wp.empty(n_work, dtype=S.SegmentRay, device=device)
    wp.launch(S.segment_rays_kernel, dim=n_work, inputs=[m.medium, cam, vp, work, lib_rays],
              device=device)
    ref = wp.zeros(total, dtype=wp.vec3, device=device)

    def run_ref():
        wp.launch(S.sample_light_kernel, dim=total,
                  inputs=[m.medium, m.grid, m.extinction, m.surface, vp, lib_rays, offsets,
                          sample_work, 0, ref], device=device, block_dim=S.SAMPLE_BLOCK)

    t_ref = timed(run_ref, device)
    ref_np = ref.numpy()
    print(f"library sample_light_kernel (regs {S.SAMPLE_REGISTERS}, block {S.SAMPLE_BLOCK}): "
          f"{t_ref:.2f} ms")
    for regs in args.regs:
        opts = {} if regs == 0 else {"cuda_max_registers": regs}
        k = wp.kernel(S.sample_light_kernel.func, name=f"light_r{regs}", module="unique",
                      enable_backward=False, **opts)
        for block in args.blocks:
            out = wp.zeros(total, dtype=wp.vec3, device=device)
            tk = timed(lambda: wp.launch(
                k, dim=total, inputs=[m.medium, m.grid, m.extinction, m.surface, vp, lib_rays,
                                      offsets, sample_work, 0, out],
                device=device, block_dim=block), device)
            same = np.array_equal(out.numpy(), ref_np)
            print(f"sample_light regs {regs or 'default'}, block {block}: {tk:.2f} ms "
                  f"(same {same})")
    # The shading of the segments from those lights, under register caps.
    n_seg = size * size * vp.segments

    def shade(kernel, regs_out):
        wp.launch(kernel, dim=n_work,
                  inputs=[m.medium, cam, m.extinction, m.grid, vp, work, offsets, lengths, 0, 0,
                          offsets, 1, ref] + regs_out, device=device)

    def seg_arrays():
        return [wp.zeros(n_seg, dtype=wp.vec3, device=device),
                wp.ones(n_seg, dtype=wp.float32, device=device),
                wp.zeros(n_seg, dtype=wp.uint64, device=device),
                wp.zeros(n_seg, dtype=wp.uint64, device=device),
                wp.zeros(n_seg, dtype=wp.int32, device=device),
                wp.full(n_seg, -1, dtype=wp.int32, device=device)]

    lib = seg_arrays()
    t_lib = timed(lambda: shade(S.shade_segment_kernel, lib), device)
    lib_np = [a.numpy() for a in lib]
    print(f"library shade_segment_kernel (regs {S.SHADE_REGISTERS}): {t_lib:.2f} ms")
    for regs in args.shade_regs:
        opts = {} if regs == 0 else {"cuda_max_registers": regs}
        k = wp.kernel(S.shade_segment_kernel.func, name=f"shade_r{regs}", module="unique",
                      enable_backward=False, **opts)
        out = seg_arrays()
        tk = timed(lambda: shade(k, out), device)
        same = all(np.array_equal(a.numpy(), b) for a, b in zip(out, lib_np))
        print(f"shade regs {regs}: {tk:.2f} ms (same {same})")
    if args.trace:
        trace_variants(volume, scene, device, args)


def trace_variants(volume, scene, device, args):
    from bench_photon import cornell_sphere, cornell_sphere_scene  # noqa: F401

    targs = (volume, scene.transfer_function, scene.resolved_unit_distance(volume),
             scene.albedo, scene.anisotropy, scene.lights)
    m = PhotonMapper(device, 4_000_000, 2.0 * volume.mean_spacing(), 1, 1, 0,
                     direct="photons")
    m.update(*targs)
    pm = m.map
    ref = pm.numpy()
    orig = T.trace_kernel
    for regs in args.regs:
        opts = {} if regs == 0 else {"cuda_max_registers": regs}
        k = wp.kernel(orig.func, name=f"trace_r{regs}", module="unique", enable_backward=False,
                      **opts)
        for block in args.blocks:
            T.trace_kernel = k
            launch = wp.launch

            def patched(kernel, *a, **kw):
                if kernel is k:
                    kw["block_dim"] = block
                return launch(kernel, *a, **kw)

            wp.launch = patched
            try:
                def once():
                    mm = PhotonMapper(device, 4_000_000, 2.0 * volume.mean_spacing(), 1, 1, 0,
                                      direct="photons")
                    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
                    mm.update(*targs)
                    res = wp.timing_end()
                    return mm, sum(r.elapsed for r in res if "trace_r" in r.name)

                once()
                best = []
                for _ in range(3):
                    mm, kt = once()
                    best.append(kt)
                got = mm.map.numpy()
                same = all(np.array_equal(got[key], ref[key]) for key in ref)
                print(f"trace regs {regs or 'default'}, block {block}: kernel "
                      f"{np.median(best):.2f} ms (same map {same})")
            finally:
                wp.launch = launch
                T.trace_kernel = orig


if __name__ == "__main__":
    main()
