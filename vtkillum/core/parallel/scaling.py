"""Scaling of the distributed methods over ranks: ``mpirun -np N python -m
vtkillum.core.parallel.scaling [--size 64] [--lights 2] [--repeat 3]``.

Times (wall clock, the slowest rank, best of ``--repeat`` after one warm-up that compiles
the kernels) the distributed ``transmittance`` (directional lights along x and
diagonally, and a point light inside the volume) and the distributed ambient extinction
(radius 4 voxels) on a procedural ``size``³ volume, and prints one table row per method.
Run it for 1, 2, 4 ... ranks and compare the rows (``docs/parallel.md``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None) -> None:
    from vtkillum.core.ambient.distributed import distributed_ambient_extinction
    from vtkillum.core.lights import DirectionalLight, PointLight
    from vtkillum.core.parallel import Decomposition, Parallel
    from vtkillum.core.parallel.transmittance import distributed_light_transmittance
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    par = Parallel.create()
    n = args.size
    whole = (0, n - 1, 0, n - 1, 0, n - 1)
    extent = Decomposition.of(whole, par.size).extents[par.rank]
    axes = [np.linspace(-1, 1, n)[slice(extent[2 * a], extent[2 * a + 1] + 1)]
            for a in range(3)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    field = (np.sin(6 * x) * np.cos(5 * y) * np.sin(4 * z) + 1.0).astype(np.float32)
    volume = Volume(field, (1.0, 1.0, 1.0), np.asarray(extent[0::2], float))
    tf = TransferFunction(scalars=[0.0, 2.0], opacity=[0.0, 0.3], colors=[[1, 1, 1]] * 2)
    lights = [DirectionalLight((1, 0, 0), (1, 1, 1)), DirectionalLight((1, 1, 1), (1, 1, 1)),
              PointLight((n / 3, n / 2, n / 2), (100, 100, 100))]
    runs = {
        "transmittance (3 lights)": lambda: distributed_light_transmittance(
            volume, extent, whole, tf, 1.0, lights, comm=par),
        "ambient extinction (r = 4)": lambda: distributed_ambient_extinction(
            volume, extent, whole, tf, 1.0, 4.0, comm=par),
    }
    if par.rank == 0:
        print(f"| method | ranks | {n}^3, device | seconds (slowest rank, best of "
              f"{args.repeat}) |")
        print("|---|---|---|---|")
    for name, run in runs.items():
        run()  # compile
        best = np.inf
        for _ in range(args.repeat):
            par.comm.Barrier()
            t = time.perf_counter()
            run()
            elapsed = par.comm.allreduce(time.perf_counter() - t, op=_max())
            best = min(best, elapsed)
        if par.rank == 0:
            print(f"| {name} | {par.size} | {par.device} | {best:.3f} |", flush=True)


def _max():
    from vtkillum.core.parallel.comm import mpi

    MPI = mpi()
    return MPI.MAX if MPI is not None else None


if __name__ == "__main__":
    main()
