"""The communicator the distributed core runs on, and one warp device per rank.

The distributed methods talk through the MPI that ParaView (or ``mpirun``) already
runs: ``MPI_COMM_WORLD`` through mpi4py, or any mpi4py communicator handed in. mpi4py
is imported only when a communicator is asked for, so the core imports without it; a
single process without mpi4py gets :class:`SelfComm`, a one-rank stand-in with the
few methods the core uses.

One GPU per rank: :func:`rank_device` maps the rank's *local* rank (its index among the
ranks on the same host, from ``MPI_Comm_split_type(MPI_COMM_TYPE_SHARED)``) to
``cuda:<local rank mod CUDA devices>``, or ``cpu`` where warp sees no CUDA device.
"""

from __future__ import annotations

import os
from dataclasses import dataclass


class SelfComm:
    """A one-rank communicator for a single process without mpi4py.

    Implements the subset of mpi4py's ``Comm`` the core calls on one rank (rank, size,
    barrier, the lower-case collectives); point-to-point messages to oneself are never
    needed there and raise.
    """

    def Get_rank(self) -> int:
        return 0

    def Get_size(self) -> int:
        return 1

    def Barrier(self) -> None:
        return None

    def allreduce(self, value, op=None):
        return value

    def allgather(self, value):
        return [value]

    def bcast(self, value, root: int = 0):
        return value

    def gather(self, value, root: int = 0):
        return [value]

    def Dup(self):
        return self

    def Free(self) -> None:
        return None


def mpi():
    """The ``mpi4py.MPI`` module (imported on first use), or ``None`` without mpi4py."""
    try:
        from mpi4py import MPI
    except ImportError:
        return None
    return MPI


def world(comm=None):
    """``comm`` if given, else ``MPI_COMM_WORLD`` (mpi4py), else a :class:`SelfComm`."""
    if comm is not None:
        return comm
    MPI = mpi()
    return MPI.COMM_WORLD if MPI is not None else SelfComm()


def world_size() -> int:
    """Ranks in ``MPI_COMM_WORLD`` without importing mpi4py when no launcher started us.

    Reads the launcher's environment (Open MPI, MPICH/Hydra, PMI, Slurm) first; imports
    mpi4py only when one of them says there are several ranks.
    """
    for key in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS"):
        if os.environ.get(key, "").isdigit():
            n = int(os.environ[key])
            if n <= 1:
                return 1
            MPI = mpi()
            return MPI.COMM_WORLD.Get_size() if MPI is not None else 1
    return 1


def local_rank(comm=None) -> int:
    """This rank's index among the ranks of ``comm`` on the same host."""
    comm = world(comm)
    if isinstance(comm, SelfComm) or comm.Get_size() == 1:
        return 0
    MPI = mpi()
    try:
        node = comm.Split_type(MPI.COMM_TYPE_SHARED, key=comm.Get_rank())
        try:
            return node.Get_rank()
        finally:
            node.Free()
    except (AttributeError, NotImplementedError):  # MPI-2 library: the launcher's variable
        for key in ("OMPI_COMM_WORLD_LOCAL_RANK", "MPI_LOCALRANKID", "SLURM_LOCALID"):
            if os.environ.get(key, "").isdigit():
                return int(os.environ[key])
        return comm.Get_rank()


def rank_device(comm=None, device: str | None = None) -> str:
    """The warp device of this rank: ``device`` if given, else ``cuda:<local rank mod n>``
    with ``n`` the CUDA devices warp sees, else ``"cpu"``.

    ``VTKILLUM_DEVICE=cpu`` (see :mod:`vtkillum.core.device`) forces the CPU on every rank.
    """
    from vtkillum.core.device import init_warp, resolve_device

    if device is not None:
        return resolve_device(device)
    if os.environ.get("VTKILLUM_DEVICE", "").strip().lower() not in ("", "auto"):
        return resolve_device(None)
    import warp as wp

    init_warp()
    count = wp.get_cuda_device_count()
    if count == 0:
        return "cpu"
    return f"cuda:{local_rank(comm) % count}"


@dataclass
class Parallel:
    """A communicator with its rank, size and this rank's warp device.

    Build it with :meth:`create`; every distributed function takes one (or ``None``:
    ``MPI_COMM_WORLD``).
    """

    comm: object
    rank: int
    size: int
    device: str

    @classmethod
    def create(cls, comm=None, device: str | None = None) -> Parallel:
        """The :class:`Parallel` of ``comm`` (default ``MPI_COMM_WORLD``), device per rank."""
        if isinstance(comm, Parallel):
            return comm if device is None else cls(comm.comm, comm.rank, comm.size,
                                                   rank_device(comm.comm, device))
        comm = world(comm)
        return cls(comm, comm.Get_rank(), comm.Get_size(), rank_device(comm, device))
