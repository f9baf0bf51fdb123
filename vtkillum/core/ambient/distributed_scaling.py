"""Scaling of the distributed ambient radiance cache over ranks: ``mpirun -np N python -m
vtkillum.core.ambient.distributed_scaling [--size 48] [--radius 3] [--repeat 2]``.

Times (wall clock, the slowest rank, best of ``--repeat`` after one warm-up that compiles
the kernels) :func:`~vtkillum.core.ambient.distributed_radiance.distributed_radiance_cache`
(``σ̃t``, the step field and the segment-forwarded tube march; directional lights along x
and diagonally, a point light inside the volume) on a procedural ``size``³ volume, with
its parts (the slowest rank's ``σ̃t`` + step field, march kernels, exchanges), the rounds
and the records forwarded; on one rank also the one-rank
:class:`~vtkillum.core.ambient.cache.AmbientScatteringCache` for comparison. Prints one
table row; run it for 1, 2, 4 ... ranks and compare the rows.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None) -> None:
    from vtkillum.core.ambient.cache import AmbientScatteringCache
    from vtkillum.core.ambient.distributed_radiance import distributed_radiance_cache
    from vtkillum.core.lights import DirectionalLight, PointLight
    from vtkillum.core.parallel import Decomposition, Parallel
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=48)
    parser.add_argument("--radius", type=float, default=3.0, help="voxels")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    par = Parallel.create()
    n = args.size
    whole = (0, n - 1, 0, n - 1, 0, n - 1)
    extent = Decomposition.of(whole, par.size).extents[par.rank]

    def field_on(ext):
        axes = [np.linspace(-1, 1, n)[slice(ext[2 * a], ext[2 * a + 1] + 1)] for a in range(3)]
        x, y, z = np.meshgrid(*axes, indexing="ij")
        return (np.sin(6 * x) * np.cos(5 * y) * np.sin(4 * z) + 1.0).astype(np.float32)

    volume = Volume(field_on(extent), (1.0, 1.0, 1.0), np.asarray(extent[0::2], float))
    tf = TransferFunction(scalars=[0.0, 2.0], opacity=[0.0, 0.3], colors=[[1, 1, 1]] * 2)
    lights = [DirectionalLight((1, 0, 0), (1, 1, 1)), DirectionalLight((1, 1, 1), (1, 1, 1)),
              PointLight((n / 3, n / 2, n / 2), (100, 100, 100))]
    r = float(args.radius)
    out = {}

    def distributed():
        out["result"] = distributed_radiance_cache(volume, extent, whole, tf, 1.0, r, lights,
                                                   comm=par)

    def one_rank():
        cache = AmbientScatteringCache(par.device, data_textures=False)
        cache.update(Volume(field_on(whole), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)), tf, 1.0, 0.9,
                     0.0, lights, r, "world", cache_shape=(n, n, n))

    runs = {"distributed": distributed}
    if par.size == 1:
        runs["one-rank cache"] = one_rank
    if par.rank == 0:
        print(f"| run | ranks | {n}^3, r = {r:g}, 3 lights, device | seconds (slowest rank, "
              f"best of {args.repeat}) | σ̃t + field / march / exchange | rounds | "
              "records forwarded |")
        print("|---|---|---|---|---|---|---|")
    for name, run in runs.items():
        run()  # compile
        best, parts = np.inf, None
        for _ in range(args.repeat):
            par.comm.Barrier()
            t = time.perf_counter()
            run()
            elapsed = par.comm.allreduce(time.perf_counter() - t, op=_max())
            if elapsed < best:
                best = elapsed
                if name == "distributed":
                    res = out["result"]
                    parts = [par.comm.allreduce(res.timings[k], op=_max())
                             for k in ("extinction", "march", "exchange")]
                    forwarded = par.comm.allreduce(res.forwarded)
                    rounds = res.rounds
        if par.rank == 0:
            detail = (" / ".join(f"{p:.3f}" for p in parts) + f" | {rounds} | {forwarded}") \
                if parts else "| |"
            print(f"| {name} | {par.size} | {par.device} | {best:.3f} | {detail} |", flush=True)


def _max():
    from vtkillum.core.parallel.comm import mpi

    MPI = mpi()
    return MPI.MAX if MPI is not None else None


if __name__ == "__main__":
    main()
