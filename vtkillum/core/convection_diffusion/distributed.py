"""The convection–diffusion light volume across MPI ranks, one block of the light grid and
one warp device per rank, the data never gathered whole (issue 36).

Entry point: :func:`distributed_light_volume`. Each rank holds

* a *piece* of the data: the point scalars of a box of the data grid that covers what its
  light-grid block needs (:func:`required_data_extent`: the footprints of the block's
  points and of one light-grid layer around it, plus the trilinear neighbours), and
* a *block* ``[lo, hi)`` of the light grid (the filter's output piece; default: the
  pieces of VTK's extent translator, the points each owns:
  :func:`~vtkillum.core.convection_diffusion.distributed_layout.owner_blocks`).

and gets back its block of the one-rank light volume
(:class:`~vtkillum.core.convection_diffusion.solver.ConvectionDiffusionSolver`).

Stages across ranks
-------------------
1. **Opacity**: every rank resamples ``sigma_t`` (and ``color sigma_t``) on its ghosted
   block from its piece, with the transfer-function tables of the *global* data range (one
   ``allreduce``): the same kernel arithmetic as the one-rank
   :func:`~vtkillum.core.convection_diffusion.opacity.light_grid_optics_kernel`, at global
   coordinates, so the values are the one-rank values bit for bit. No communication
   besides the range.
2. **Convection**, a pipelined sweep (KBA): a point of the one-rank sweep depends only on
   its upstream neighbours (one step against the light along each axis it steps on, the
   diagonal ones included for short characteristics), so a block can be swept once the
   layer of points upstream of it is known. Per light, a rank posts receives for that
   layer from every rank whose block it overlaps, sweeps its block when they arrived (its
   part of the light's wavefronts or layers, the one-rank kernels' per-point arithmetic at
   global coordinates), and sends the parts of its block that lie in the upstream layers
   of other blocks. All lights' receives are posted at once and a rank sweeps whichever
   light is ready first, so several lights are in flight: with lights from different
   corners, different ranks start at once. Result: the one-rank transmittance exactly
   (same operations in a different order of independent points).
3. **Composition** (eq. 22): pointwise, no communication.
4. **Diffusion**, by model:

   ``"paper"`` (eq. 23)
       the multigrid of :mod:`~vtkillum.core.convection_diffusion.distributed_multigrid`:
       the one-rank V-cycle's hierarchy and operators, red–black Gauss–Seidel with a halo
       exchange before each colour (the same iterates as one rank), coarse levels gathered
       onto rank 0 once they are small.
   ``"physical"`` (default of the one-rank solver)
       * the δ-Eddington beams (``g > 0``): ``sigma_t*`` pointwise on the ghosted block
         (the one-rank ``delta_sigma_kernel``), then one more pipelined sweep per light
         through it (stage 2's sweep, exact);
       * the first-scattered source ``Q`` and its first moments (dipole per axis):
         pointwise, the one-rank ``first_scattered_kernel`` at global indices
         (:func:`block_first_scattered_kernel`), exact;
       * the flux-limited diffusion on the blocks
         (:class:`~vtkillum.core.convection_diffusion.distributed_radiative.DistributedRadiativeDiffusion`,
         default ``diffusion="distributed"``): the one-rank lagged limiter, leakage,
         homogenized V(2,2) cycle, nested start and Anderson mixing with halo exchanges,
         coarse levels gathered onto rank 0, norms and Gram matrix by float64
         ``Allreduce``: the one-rank iterates up to the order of those sums.
         ``diffusion="gathered"`` instead gathers ``Q``, the moments, ``sigma_t`` and
         ``color sigma_t`` (light-grid sized) onto rank 0, which runs the one-rank
         :class:`~vtkillum.core.convection_diffusion.radiative.RadiativeDiffusion` and
         scatters ``phi_s`` back (the one-rank solve bit for bit);
       * the reconstruction filter along thick surfaces
         (:func:`~vtkillum.core.convection_diffusion.reconstruction.filter_along_surfaces`,
         radius one cell): on each rank's ghosted block after a halo exchange of
         ``phi_s`` (``sigma_t`` is already ghosted); its bounds tests use the array's
         shape, and the ghosted box is the block grown by one point and clipped to the
         grid, so every owned point sees exactly its one-rank neighbourhood.

What is simplified
------------------
* The distributed flux-limited solve always starts cold (no warm start, no captured
  graphs); its coarse levels below ``gather_cells`` cells run on rank 0.
* No partial recomputation (Algorithm 1) and no warm start across calls: every call
  recomputes its block.
* Ghost transfers go through host buffers (``numpy``), also on CUDA devices (no
  CUDA-aware MPI assumed).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.composition import first_scattered_at, light_at
from vtkillum.core.convection_diffusion.convection import (
    CHARACTERISTICS,
    EXPONENTIAL,
    MAX_STEP_DEPTH,
    SCHEMES,
    _light_vector,
    _scheme_id,
    boundary_value,
    characteristic_value,
    grid_index,
    light_direction_at,
    sweep_plan,
    upwind_sums,
    wavefront_distance,
)
from vtkillum.core.convection_diffusion.diffusion import SOLVERS, DiffusionReport
from vtkillum.core.convection_diffusion.distributed_layout import (
    Halo,
    Layout,
    extent_block,
    intersect,
    mpi,
    owner_blocks,
    read_region,
    region,
    write_region,
)
from vtkillum.core.convection_diffusion.distributed_multigrid import DistributedMultigrid
from vtkillum.core.convection_diffusion.distributed_radiative import DistributedRadiativeDiffusion
from vtkillum.core.convection_diffusion.opacity import MAX_SUBSAMPLES, footprint_optics
from vtkillum.core.convection_diffusion.reconstruction import filter_along_surfaces
from vtkillum.core.lights import DIRECTIONAL, pack_lights
from vtkillum.core.warp_common import (
    Medium,
    component,
    grid_point,
    set_table_range,
)

#: MPI tags of the convection's face messages: ``CONVECTION_TAG + light``; the
#: δ-Eddington beams' sweep uses ``BEAM_TAG + light``.
CONVECTION_TAG = 1000
BEAM_TAG = 5000
#: MPI tag of the halo exchange of ``phi_s`` before the surface filter.
PHI_HALO_TAG = 6000
#: Diffusion solvers of the distributed physical model.
PHYSICAL_SOLVERS = ("multigrid", "gauss-seidel")


@dataclass
class LocalLightVolume:
    """This rank's block of the light volume (:func:`distributed_light_volume`).

    Attributes
    ----------
    shape : tuple of int
        The whole light grid's points per axis.
    spacing : ndarray (3,)
        Light-grid spacing (world units).
    lo, hi : ndarray (3,) int
        This rank's block ``[lo, hi)`` of light-grid points.
    sigma : ndarray (bx, by, bz) float32
        Extinction on the block (1/world units).
    transmittance : ndarray (n_lights, bx, by, bz) float32
        ``T_l`` of every light.
    composed : ndarray (bx, by, bz, 3)
        ``phi_d = sum_l T_l E_l`` (eq. 22).
    scattered_fluence : ndarray (bx, by, bz, 3)
        ``"paper"``: the diffused light volume ``L``; ``"physical"``: the scattered
        fluence ``phi_s``; clamped at 0 (as the one-rank ``scattered_fluence``).
    rendered_scattered_fluence : ndarray (bx, by, bz, 3) or None
        ``"physical"``: ``phi_s`` filtered along thick surfaces, >= 0 (the one-rank
        ``rendered_scattered_fluence``, what the ray caster reads); None for ``"paper"``.
    source : ndarray (bx, by, bz, 3) or None
        ``"physical"``: the first-scattered source ``Q`` (the one-rank ``source``).
    model : str
        The diffusion model.
    diffusion : DiffusionReport
        Iterations and relative residuals of the diffusion (the same on every rank).
    ms : dict
        Milliseconds per stage on this rank (``opacity``, ``convection``, ``composition``,
        ``diffusion``), ``convection_wait``: of the convection, the time spent waiting for
        upstream faces.
    mode : str
        What ran, for the log line.
    """

    shape: tuple
    spacing: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    sigma: np.ndarray
    transmittance: np.ndarray
    composed: np.ndarray
    scattered_fluence: np.ndarray | None
    rendered_scattered_fluence: np.ndarray | None = None
    source: np.ndarray | None = None
    model: str = "paper"
    diffusion: DiffusionReport = field(default_factory=DiffusionReport)
    ms: dict = field(default_factory=dict)
    mode: str = ""

    @property
    def fluence(self) -> np.ndarray | None:
        """All light as an isotropic fluence, as the one-rank solver's: ``L`` (paper) or
        ``phi_d + phi_s`` (physical)."""
        if self.model == "paper" or self.scattered_fluence is None:
            return self.scattered_fluence
        return self.composed + self.scattered_fluence


def light_shape(dims, scale: float = 0.5, shape=None) -> tuple:
    """The light grid's points per axis for data of ``dims`` points (as
    :func:`~vtkillum.core.convection_diffusion.opacity.light_grid_shape`)."""
    if shape is not None:
        return tuple(int(v) for v in shape)
    return tuple(max(2, round(float(scale) * n)) for n in dims)


def _footprint(dims, spacing, shape):
    extent = (np.asarray(dims) - 1) * np.asarray(spacing, dtype=np.float64)
    h = extent / (np.asarray(shape) - 1)
    sub = np.clip(np.ceil(h / np.asarray(spacing) - 1e-6), 1, MAX_SUBSAMPLES).astype(int)
    return extent, h, sub


def required_data_extent(lo, hi, dims, spacing, shape) -> tuple[np.ndarray, np.ndarray]:
    """Data points ``[dlo, dhi)`` a rank needs for light-grid block ``[lo, hi)``: the
    footprints (one light-grid spacing, centred) of the block's points and of one layer
    around it, each sample's trilinear cell, clipped to the data. The filter's
    ``RequestUpdateExtent`` asks for this (VTK extent: ``dlo .. dhi - 1``)."""
    dims = np.asarray(dims, dtype=np.int64)
    _, h, _ = _footprint(dims, spacing, shape)
    glo = np.maximum(np.asarray(lo) - 1, 0)
    ghi = np.minimum(np.asarray(hi) + 1, np.asarray(shape))
    sp = np.asarray(spacing, dtype=np.float64)
    start = np.floor((glo * h - 0.5 * h) / sp).astype(np.int64) - 1
    stop = np.ceil(((ghi - 1) * h + 0.5 * h) / sp).astype(np.int64) + 2
    return np.clip(start, 0, dims), np.clip(stop, 0, dims)


def distributed_light_volume(scalars, piece_start, dims, spacing, transfer_function,
                             unit_distance: float, lights, *, origin=(0.0, 0.0, 0.0),
                             direction=None, value_range=None, light_volume_scale: float = 0.5,
                             light_volume_shape=None, block=None,
                             diffusion_model: str = "physical", scattering=(0.0, 0.0, 0.0),
                             solver: str = "multigrid", tolerance: float | None = None,
                             iterations: int = 0, source_radius: float = 0.0,
                             convection_scheme: str = "characteristics",
                             albedo: float = 0.9, anisotropy: float = 0.0,
                             flux_limiter: str = "levermore-pomraning",
                             first_moment: bool = True, delta_scaling: bool = True,
                             anderson: bool = True,
                             gather_cells: int | None = None, diffusion: str = "distributed",
                             comm=None,
                             device: str | None = None) -> LocalLightVolume:
    """This rank's block of the convection–diffusion light volume; collective over ``comm``.

    Parameters
    ----------
    scalars : ndarray (px, py, pz)
        This rank's piece of the data (point scalars, ``[i, j, k]``), covering at least
        :func:`required_data_extent` of its block.
    piece_start : (3,) int
        Global data index of ``scalars[0, 0, 0]``.
    dims, spacing, origin, direction
        The whole data grid (as :class:`~vtkillum.core.volume.Volume`).
    transfer_function, unit_distance, lights
        As :meth:`ConvectionDiffusionSolver.update` (every rank passes the same).
    value_range : (float, float), optional
        The whole data's range (the transfer-function tables span it); reduced over the
        ranks' pieces when omitted.
    light_volume_scale, light_volume_shape, scattering, tolerance, iterations,
    source_radius, convection_scheme
        As :class:`ConvectionDiffusionSolver`.
    block : (lo, hi) or VTK extent, optional
        This rank's light-grid block: ``[lo, hi)``, or the points it owns as a VTK extent
        (inclusive, e.g. ``Decomposition.owner_extent`` of its output piece; the blocks
        must not overlap). Default: :func:`owner_blocks` (VTK's pieces of the light grid).
    diffusion_model : str
        ``"physical"`` (default, as the one-rank solver) or ``"paper"``; see the module
        docstring for what runs where.
    solver : str
        ``"multigrid"`` (paper: distributed); the physical model also takes
        ``"gauss-seidel"`` (rank 0's solve).
    tolerance : float, optional
        Relative residual of the diffusion; default the one-rank
        :data:`~vtkillum.core.convection_diffusion.solver.DEFAULT_TOLERANCE`.
    albedo, anisotropy : float
        The physical model's single-scattering albedo and Henyey–Greenstein ``g`` (as
        :meth:`ConvectionDiffusionSolver.update`).
    flux_limiter, first_moment, delta_scaling, anderson
        The physical model's options, as :class:`ConvectionDiffusionSolver`.
    gather_cells : int, optional
        Multigrid levels of at most this many cells are gathered onto rank 0 (default
        :data:`~vtkillum.core.convection_diffusion.distributed_multigrid.GATHER_CELLS`;
        the physical model's: ``distributed_radiative.GATHER_CELLS``).
    diffusion : str
        The physical model's flux-limited solve: ``"distributed"`` (default, on the
        blocks) or ``"gathered"`` (on rank 0's gathered light grid, bit for bit the
        one-rank solve).
    comm : mpi4py communicator, optional
        Default ``MPI_COMM_WORLD``.
    device : str, optional
        This rank's warp device; default :func:`vtkillum.core.parallel.rank_device`
        (``cuda:<local rank>``, or ``VTKILLUM_DEVICE``).
    """
    from vtkillum.core.parallel import Parallel

    par = Parallel.create(comm, device)
    MPI, comm, device = mpi(), par.comm, par.device
    if diffusion_model not in ("paper", "physical"):
        raise ValueError(f"diffusion_model must be 'paper' or 'physical', got {diffusion_model!r}")
    allowed = PHYSICAL_SOLVERS if diffusion_model == "physical" else ("multigrid",)
    if solver not in allowed:
        raise ValueError(f"the distributed {diffusion_model} diffusion solves with one of "
                         f"{allowed} (one-rank: {SOLVERS}), got {solver!r}")
    from vtkillum.core.convection_diffusion.solver import DEFAULT_TOLERANCE

    tolerance = DEFAULT_TOLERANCE if tolerance is None else float(tolerance)
    if diffusion not in ("distributed", "gathered"):
        raise ValueError(f"diffusion must be 'distributed' or 'gathered', got {diffusion!r}")
    if convection_scheme not in SCHEMES:
        raise ValueError(f"convection_scheme must be one of {sorted(SCHEMES)}")
    ms = {}
    dims = tuple(int(v) for v in dims)
    spacing = np.asarray(spacing, dtype=np.float64)
    direction = np.eye(3) if direction is None else np.asarray(direction, dtype=np.float64)
    shape = light_shape(dims, light_volume_scale, light_volume_shape)
    extent, h, sub = _footprint(dims, spacing, shape)
    if block is None:
        blocks = owner_blocks(shape, comm.Get_size())
    else:
        if len(block) == 6:
            block = extent_block(block)
        blocks = comm.allgather((np.asarray(block[0], np.int64), np.asarray(block[1], np.int64)))
    layout = Layout(shape, blocks, comm.Get_rank())
    scalars = np.ascontiguousarray(np.asarray(scalars, dtype=np.float32))
    piece_start = np.asarray(piece_start, dtype=np.int64)
    if value_range is None:
        vmin = comm.allreduce(float(scalars.min()), op=MPI.MIN)
        vmax = comm.allreduce(float(scalars.max()), op=MPI.MAX)
        value_range = (vmin, vmax)
    need_lo, need_hi = required_data_extent(layout.lo, layout.hi, dims, spacing, shape)
    problem = None
    if not layout.empty and (np.any(piece_start > need_lo)
                             or np.any(piece_start + np.asarray(scalars.shape) < need_hi)):
        problem = (f"rank {layout.rank}: the data piece [{piece_start.tolist()}, "
                   f"{(piece_start + scalars.shape).tolist()}) does not cover the points "
                   f"[{need_lo.tolist()}, {need_hi.tolist()}) that light-grid block "
                   f"[{layout.lo.tolist()}, {layout.hi.tolist()}) needs (required_data_extent)")
    problems = [p for p in comm.allgather(problem) if p is not None]
    if problems:  # on every rank, so that none waits in a collective
        raise ValueError("; ".join(problems))

    # 1. opacity on the ghosted block
    t = time.perf_counter()
    glo, ghi = layout.ghost()
    local = layout.local_shape
    sigma = wp.zeros(local, dtype=wp.float32, device=device)
    color_sigma = wp.zeros(local, dtype=wp.vec3, device=device)
    medium, piece = _medium(scalars, transfer_function, unit_distance, value_range, extent,
                            spacing, device)
    if not layout.empty:
        wp.launch(block_optics_kernel, dim=tuple(int(v) for v in ghi - glo), device=device,
                  inputs=[medium, piece, wp.vec3i(*piece_start), wp.vec3i(*dims),
                          wp.vec3(*h.astype(np.float32)), wp.vec3i(*sub), wp.vec3i(*glo),
                          sigma, color_sigma])
    ms["opacity"] = _ms(t, device)

    # 2. convection, pipelined over the ranks
    kinds, vecs, rgbs = pack_lights(lights, direction, origin)
    if len(kinds) == 0:
        raise ValueError("convection-diffusion needs at least one light")
    r_s = float(source_radius) if source_radius > 0 else 2.0 * float(h.max())
    T = wp.zeros((len(kinds),) + local, dtype=wp.float32, device=device)
    t = time.perf_counter()
    wait = convect_pipelined(comm, layout, sigma, h, [(int(k), v) for k, v in zip(kinds, vecs)],
                             T, r_s, convection_scheme)
    ms["convection"] = _ms(t, device)
    ms["convection_wait"] = 1000.0 * wait

    # 3. composition, in units of the brightest light (as the one-rank solver)
    t = time.perf_counter()
    scale = float(max(np.max(rgbs), 1e-30))
    rgbs_n = (rgbs / scale).astype(np.float32)
    dirs = [v / max(float(np.linalg.norm(v)), 1e-30) if k == DIRECTIONAL else v
            for k, v in zip(kinds, vecs.astype(np.float64))]
    b = wp.zeros(local, dtype=wp.vec3, device=device)
    if not layout.empty:
        wp.launch(block_compose_kernel, dim=layout.block_shape, device=device,
                  inputs=[T, len(kinds), wp.array(np.asarray(kinds, np.int32), dtype=wp.int32,
                                                  device=device),
                          wp.array(np.asarray(dirs, np.float32), dtype=wp.vec3, device=device),
                          wp.array(rgbs_n, dtype=wp.vec3, device=device), b,
                          wp.vec3(*h.astype(np.float32)), r_s, wp.vec3i(*glo),
                          wp.vec3i(*layout.lo)])
    ms["composition"] = _ms(t, device)

    # 4. diffusion
    report = DiffusionReport()
    fluence = None
    mode = "distributed convection"
    if diffusion_model == "paper":
        t = time.perf_counter()
        s = np.asarray(scattering, dtype=np.float64).reshape(-1)
        s = np.repeat(s, 3) if s.size == 1 else s
        x = wp.clone(b)
        kwargs = {} if gather_cells is None else {"gather_cells": int(gather_cells)}
        mg = DistributedMultigrid(comm, layout, h, s, device, **kwargs)
        from vtkillum.core.convection_diffusion.solver import MAX_ITERATIONS

        report = mg.solve(b, x, int(iterations) or MAX_ITERATIONS["multigrid"], float(tolerance))
        fluence = np.maximum(x[layout.block_region()].numpy(), 0.0) * np.float32(scale)
        ms["diffusion"] = _ms(t, device)
        mode += (f" + distributed multigrid ({mg.distributed_levels} levels on "
                 f"{comm.Get_size()} ranks, coarse levels from {mg.gathered_shape} on rank 0)")
    rendered = source = None
    if diffusion_model == "physical":
        physical = _physical(comm, layout, device, sigma, color_sigma, T, h, kinds, vecs, dirs,
                             rgbs_n, r_s, convection_scheme, float(albedo), float(anisotropy),
                             flux_limiter, bool(first_moment), bool(delta_scaling),
                             bool(anderson), solver, int(iterations), tolerance, ms,
                             diffusion, gather_cells)
        phi, rendered_dev, q, report, solve_mode = physical
        sl = layout.block_region()
        fluence = np.maximum(phi[sl].numpy(), 0.0) * np.float32(scale)
        rendered = np.maximum(rendered_dev[sl].numpy(), 0.0) * np.float32(scale)
        source = q[sl].numpy() * np.float32(scale)
        mode += solve_mode
    sl = layout.block_region()
    return LocalLightVolume(
        shape=shape, spacing=h, lo=layout.lo.copy(), hi=layout.hi.copy(),
        sigma=sigma[sl].numpy().copy(),
        transmittance=np.stack([T[i][sl].numpy() for i in range(len(kinds))]),
        composed=b[sl].numpy() * np.float32(scale), scattered_fluence=fluence,
        rendered_scattered_fluence=rendered, source=source, model=diffusion_model,
        diffusion=report, ms=ms, mode=mode)


def _physical(comm, layout, device, sigma, color_sigma, T, h, kinds, vecs, dirs, rgbs_n, r_s,
              scheme, albedo, anisotropy, limiter, first_moment, delta_scaling, anderson,
              solver, iterations, tolerance, ms, diffusion="distributed", gather_cells=None):
    """The physical model after the convection: δ-Eddington beams, the first-scattered
    source and its moments on the block, the flux-limited solve on rank 0, ``phi_s``
    scattered back and filtered along surfaces with a halo (the one-rank
    ``ConvectionDiffusionSolver.update`` and ``_diffuse_physical`` of a cold start).
    Returns ``(phi_s, filtered phi_s, Q, report, mode text)``, ghosted device arrays in
    units of the brightest light."""
    from vtkillum.core.convection_diffusion.solver import (
        MAX_ITERATIONS,
        delta_fraction,
        delta_sigma_kernel,
    )

    local = layout.local_shape
    t = time.perf_counter()
    f = delta_fraction(anisotropy) if delta_scaling else 0.0
    beams, beam_sigma, a_src, g_src = None, sigma, albedo, anisotropy
    if f > 0:  # δ-Eddington: the forward peak stays in the beam (the solver's _delta_beams)
        beam_sigma = wp.zeros(local, dtype=wp.float32, device=device)
        if not layout.empty:
            wp.launch(delta_sigma_kernel, dim=local, device=device,
                      inputs=[sigma, color_sigma, float(f * albedo), beam_sigma])
        beams = wp.zeros((len(kinds),) + local, dtype=wp.float32, device=device)
        convect_pipelined(comm, layout, beam_sigma, h, [(int(k), v) for k, v in zip(kinds, vecs)],
                          beams, r_s, scheme, tag=BEAM_TAG)
        a_src, g_src = albedo * (1.0 - f), anisotropy / (1.0 + anisotropy)
    ms["beams"] = _ms(t, device)
    t = time.perf_counter()
    q = wp.zeros(local, dtype=wp.vec3, device=device)
    moment = tuple(wp.zeros(local, dtype=wp.vec3, device=device) for _ in range(3))
    glo, _ = layout.ghost()
    if not layout.empty:
        from vtkillum.core.convection_diffusion.composition import light_tables

        wp.launch(block_first_scattered_kernel, dim=layout.block_shape, device=device,
                  inputs=[beams if beams is not None else T, len(kinds),
                          *light_tables(kinds, np.asarray(dirs, np.float32), rgbs_n, device),
                          beam_sigma, color_sigma, q, wp.vec3(*h.astype(np.float32)),
                          float(r_s), float(a_src), float(g_src), int(first_moment),
                          *moment, wp.vec3i(*glo), wp.vec3i(*layout.lo),
                          wp.vec3i(*layout.shape)])
    ms["source"] = _ms(t, device)

    # the flux-limited diffusion: on the blocks (default), or on rank 0's gathered light grid
    t = time.perf_counter()
    budget = iterations or MAX_ITERATIONS[solver]
    if diffusion == "gathered":
        phi, result = _physical_gathered(comm, layout, device, q, moment, sigma, color_sigma,
                                         h, limiter, albedo, anisotropy, first_moment,
                                         anderson, solver, budget, tolerance)
        where = f"on rank 0's gathered light grid {tuple(int(v) for v in layout.shape)}"
    else:
        kwargs = {} if gather_cells is None else {"gather_cells": int(gather_cells)}
        rd = DistributedRadiativeDiffusion(comm, layout, h, limiter, device, **kwargs)
        rd.anderson = anderson
        rd.set_medium(rd.load(sigma, layout), rd.load(color_sigma, layout), albedo,
                      anisotropy)
        wm = tuple(rd.load(m, layout) for m in moment) if first_moment else None
        x = wp.zeros(rd.levels[0].layout.local_shape, dtype=wp.vec3, device=device)
        result = rd.solve(rd.load(q, layout), x, budget, tolerance, method=solver,
                          displacement=wm, cold=True)
        phi = wp.zeros(local, dtype=wp.vec3, device=device)
        rd.store(x, phi, layout)
        where = (f"on the blocks ({rd.distributed_levels} levels on {comm.Get_size()} ranks, "
                 f"coarse levels from {rd.gathered_shape} on rank 0)")
    ms["diffusion"] = _ms(t, device)

    # the reconstruction filter: local, with a one-layer halo of phi_s
    t = time.perf_counter()
    Halo(comm, layout).exchange(phi, PHI_HALO_TAG)
    rendered = filter_along_surfaces(phi, sigma, h) if not layout.empty else wp.zeros_like(phi)
    ms["reconstruction"] = _ms(t, device)
    text = (" + physical model: first-scattered source on the blocks"
            + (" with δ-Eddington beams swept across ranks" if f > 0 else "")
            + f", flux-limited diffusion ({solver}) {where}, surface filter with halo")
    return phi, rendered, q, result, text


def _physical_gathered(comm, layout, device, q, moment, sigma, color_sigma, h, limiter, albedo,
                       anisotropy, first_moment, anderson, solver, budget, tolerance):
    """The flux-limited solve on rank 0 (``diffusion="gathered"``): ``Q``, the moments,
    ``sigma_t`` and ``color sigma_t`` gathered, the one-rank ``RadiativeDiffusion`` of a
    cold start, ``phi_s`` scattered back by blocks (the one-rank result bit for bit).
    Returns ``(phi_s ghosted, report)``."""
    from vtkillum.core.convection_diffusion.radiative import RadiativeDiffusion

    fields = [q, *moment] if first_moment else [q]
    whole = _gather_blocks(comm, layout, fields + [sigma, color_sigma])
    pieces, result = None, None
    if comm.Get_rank() == 0:
        gshape = tuple(int(v) for v in layout.shape)
        arrays = [wp.array(a, dtype=wp.vec3 if a.ndim == 4 else wp.float32, device=device)
                  for a in whole]
        wq, wm = arrays[0], (tuple(arrays[1:4]) if first_moment else None)
        rd = RadiativeDiffusion(gshape, h, limiter, device)
        rd.anderson = anderson
        rd.set_medium(arrays[-2], arrays[-1], albedo, anisotropy)
        x = wp.zeros(gshape, dtype=wp.vec3, device=device)
        result = rd.solve(wq, x, budget, tolerance, method=solver, displacement=wm, cold=True,
                          nested_above=None)
        xs = x.numpy()
        pieces = [xs[region(lo, hi, (0, 0, 0))] if np.all(hi > lo) else None
                  for lo, hi in layout.blocks]
    mine = comm.scatter(pieces, root=0)
    result = comm.bcast(result, root=0)
    phi = wp.zeros(layout.local_shape, dtype=wp.vec3, device=device)
    if mine is not None:
        write_region(phi, layout.block_region(), mine)
    return phi, result


def _gather_blocks(comm, layout, arrays) -> list | None:
    """Rank 0: the whole grid of each ghosted array of ``arrays`` (numpy), from every rank's
    block; other ranks: None."""
    parts = [read_region(a, layout.block_region()) if not layout.empty else None
             for a in arrays]
    gathered = comm.gather(parts, root=0)
    if comm.Get_rank() != 0:
        return None
    out = []
    for n, a in enumerate(arrays):
        comps = (3,) if a.dtype == wp.vec3 else ()
        whole = np.zeros(tuple(int(v) for v in layout.shape) + comps, dtype=np.float32)
        for (lo, hi), rank_parts in zip(layout.blocks, gathered):
            if rank_parts[n] is not None:
                whole[region(lo, hi, (0, 0, 0))] = rank_parts[n]
        out.append(whole)
    return out


def _ms(t0: float, device: str) -> float:
    wp.synchronize_device(device)
    return 1000.0 * (time.perf_counter() - t0)


def _medium(scalars, tf, unit_distance, value_range, extent, spacing, device):
    """The transfer-function tables of the global data range (as ``make_medium``'s) and
    the piece on the device."""
    sig, col, lo, hi = tf.lookup_tables(unit_distance, value_range)
    piece = wp.array(scalars, dtype=wp.float32, device=device)
    m = Medium()
    m.scalars = piece
    m.extent = wp.vec3(*np.asarray(extent).astype(np.float32))
    m.inv_spacing = wp.vec3(*(1.0 / spacing).astype(np.float32))
    m.sigma_table = wp.array(sig, dtype=wp.float32, device=device)
    m.color_table = wp.array(col, dtype=wp.vec3, device=device)
    set_table_range(m, lo, hi, len(sig))
    m.occupied = wp.ones((1, 1, 1), dtype=wp.int32, device=device)
    m.block = wp.vec3(*np.asarray(extent).astype(np.float32))
    m.inv_block = wp.vec3(1.0, 1.0, 1.0)
    return m, piece


# --- the pipelined sweep ---------------------------------------------------------------------------
def upstream_signs(plan, lo, hi) -> np.ndarray:
    """Per axis, where block ``[lo, hi)``'s points find their upstream neighbours outside
    it: +1 at ``lo - 1`` (block beyond the light's no-upwind range), -1 at ``hi``, 0 none."""
    s = np.zeros(3, np.int64)
    for a in range(3):
        if lo[a] > plan.hi[a]:
            s[a] = 1
        elif hi[a] - 1 < plan.lo[a]:
            s[a] = -1
    return s


def upstream_box(plan, lo, hi):
    """Block ``[lo, hi)`` grown by the layer of points upstream of it."""
    s = upstream_signs(plan, lo, hi)
    return lo - (s > 0), hi + (s < 0)


def _wavefront_range(plan, lo, hi):
    """First and last wavefront (or layer) of the light's sweep with a point in the block."""
    rmin, rmax = np.zeros(3, np.int64), np.zeros(3, np.int64)
    for a in range(3):
        def r(i, a=a):
            return max(i - plan.hi[a], plan.lo[a] - i, 0)
        last = hi[a] - 1
        rmin[a] = 0 if (lo[a] <= plan.hi[a] and last >= plan.lo[a]) else min(r(lo[a]), r(last))
        rmax[a] = max(r(lo[a]), r(last))
    if plan.layers:
        return int(rmin[plan.primary]), int(rmax[plan.primary])
    return int(rmin.sum()), int(rmax.sum())


def convect_pipelined(comm, layout: Layout, sigma: wp.array3d, spacing, lights, T: wp.array4d,
                      source_radius: float, scheme: str = "characteristics",
                      tag: int = CONVECTION_TAG) -> float:
    """Transmittance of every light on this rank's block (``T[l]``, ghosted arrays),
    pipelined over the ranks (see the module docstring); returns the seconds spent waiting
    for upstream faces. ``tag + light`` tags the messages."""
    MPI = mpi()
    me = layout.rank
    shape = tuple(int(v) for v in layout.shape)
    spacing = np.asarray(spacing, dtype=np.float64)
    scheme_id = _scheme_id(scheme)
    glo, _ = layout.ghost()
    device = sigma.device
    h32 = wp.vec3(*spacing.astype(np.float32))
    jobs = []
    for n, (kind, vec) in enumerate(lights):
        vec = _light_vector(kind, vec)
        plan = sweep_plan(kind, vec, shape, spacing, scheme)
        recvs, sends = [], []
        for q, (qlo, qhi) in enumerate(layout.blocks):
            if q == me or not np.all(qhi > qlo) or layout.empty:
                continue
            box = intersect(qlo, qhi, *upstream_box(plan, layout.lo, layout.hi))
            if box is not None:  # q owns part of my upstream layer
                recvs.append((q, region(*box, glo)))
            box = intersect(layout.lo, layout.hi, *upstream_box(plan, qlo, qhi))
            if box is not None:  # part of my block is upstream of q's
                sends.append((q, region(*box, glo)))
        buffers, requests = [], []
        for q, sl in recvs:
            buf = np.empty(tuple(s.stop - s.start for s in sl), dtype=np.float32)
            requests.append(comm.Irecv(buf, source=q, tag=tag + n))
            buffers.append((sl, buf))
        jobs.append({"n": n, "kind": kind, "vec": vec.astype(np.float32), "plan": plan,
                     "sends": sends, "buffers": buffers, "requests": requests})
    outgoing, waited = [], 0.0
    todo = list(jobs)
    while todo:
        ready = [j for j in todo if MPI.Request.Testall(j["requests"])]
        if not ready:
            t = time.perf_counter()
            MPI.Request.Waitany([r for j in todo for r in j["requests"]])
            waited += time.perf_counter() - t
            continue
        job = ready[0]
        todo.remove(job)
        out = T[job["n"]]
        for sl, buf in job["buffers"]:
            write_region(out, sl, buf)
        if not layout.empty:
            _sweep_block(sigma, out, job, layout, h32, source_radius, scheme_id, glo, device)
        for q, sl in job["sends"]:
            buf = read_region(out, sl)
            outgoing.append((comm.Isend(buf, dest=q, tag=tag + job["n"]), buf))
    MPI.Request.Waitall([r for r, _ in outgoing])
    return waited


def _sweep_block(sigma, out, job, layout, h32, source_radius, scheme_id, glo, device):
    plan = job["plan"]
    lo, hi = layout.lo, layout.hi
    first, second = [a for a in range(3) if a != plan.primary]
    m0, m1 = _wavefront_range(plan, lo, hi)
    dim = (2, int(hi[first] - lo[first]), int(hi[second] - lo[second]))
    cmd = wp.launch(block_sweep_kernel, dim=dim, device=device, record_cmd=True,
                    inputs=[sigma, out, m0, plan.primary, int(plan.layers), wp.vec3i(*plan.lo),
                            wp.vec3i(*plan.hi), wp.vec3i(*plan.inflow), int(job["kind"]),
                            wp.vec3(*job["vec"]), h32, float(source_radius), scheme_id,
                            wp.vec3i(*glo), wp.vec3i(*lo), wp.vec3i(*hi)])
    for m in range(m0, m1 + 1):
        cmd.set_param_at_index(2, m)
        cmd.launch()


# --- kernels ---------------------------------------------------------------------------------------
@wp.kernel
def block_optics_kernel(m: Medium, piece: wp.array3d(dtype=wp.float32), start: wp.vec3i,
                        dims: wp.vec3i, h: wp.vec3, sub: wp.vec3i, off: wp.vec3i,
                        sigma: wp.array3d(dtype=wp.float32),
                        color_sigma: wp.array3d(dtype=wp.vec3)):
    """``light_grid_optics_kernel`` at global light-grid point ``wp.tid() + off`` of a
    ghosted block, sampling the data piece (the same footprint function, same values)."""
    i, j, k = wp.tid()
    st, cs = footprint_optics(m, piece, start, dims, h, sub,
                              grid_point(i + off[0], j + off[1], k + off[2], h))
    sigma[i, j, k] = st
    color_sigma[i, j, k] = cs


@wp.func
def block_upwind_point(sigma: wp.array3d(dtype=wp.float32), T: wp.array3d(dtype=wp.float32),
                       g: wp.vec3i, off: wp.vec3i, lo: wp.vec3i, hi: wp.vec3i, inflow: wp.vec3i,
                       kind: int, vec: wp.vec3, h: wp.vec3, source_radius: float, scheme: int,
                       dominant: int):
    """``upwind_point`` of :mod:`~vtkillum.core.convection_diffusion.convection` at global
    point ``g``, stored at ``g - off`` of the ghosted arrays (the stencil's index tests are
    shift-invariant, so they run on local indices with the range shifted)."""
    x = wp.vec3(float(g[0]) * h[0], float(g[1]) * h[1], float(g[2]) * h[2])
    u, dist = light_direction_at(kind, vec, x)
    idx = g - off
    s = sigma[idx[0], idx[1], idx[2]]
    value = boundary_value(g, inflow, kind, dist, source_radius, s)
    if value < 0.0 and scheme == CHARACTERISTICS:
        value = characteristic_value(sigma, T, idx, u, h, lo - off, hi - off, dominant)
    elif value < 0.0:
        value = 1.0
        num, den = upwind_sums(T, idx, u, h, lo - off, hi - off)
        if den > 0.0:
            if scheme == EXPONENTIAL:
                value = num / den * wp.exp(-wp.min(s / den, MAX_STEP_DEPTH))
            else:
                value = num / (den + s)
    T[idx[0], idx[1], idx[2]] = value


@wp.kernel
def block_sweep_kernel(sigma: wp.array3d(dtype=wp.float32), T: wp.array3d(dtype=wp.float32),
                       m: int, primary: int, layers: int, lo: wp.vec3i, hi: wp.vec3i,
                       inflow: wp.vec3i, kind: int, vec: wp.vec3, h: wp.vec3,
                       source_radius: float, scheme: int, off: wp.vec3i, blo: wp.vec3i,
                       bhi: wp.vec3i):
    """Wavefront (or layer) ``m`` of one light restricted to block ``[blo, bhi)``:
    ``wp.tid() = (side, a, b)``, line ``(a, b)`` of the block along the non-primary axes
    (``sweep_point`` of the one-rank sweep, global indices, points outside the block
    skipped)."""
    side, a, b = wp.tid()
    first = 0
    if primary == 0:
        first = 1
    second = 2
    if primary == 2:
        second = 1
    ga = component(blo, first) + a
    gb = component(blo, second) + b
    dominant = -1
    r_other = 0
    if layers != 0:
        dominant = primary
    else:
        base = grid_index(primary, 0, ga, gb)
        r_other = (wavefront_distance(base[0], lo[0], hi[0])
                   + wavefront_distance(base[1], lo[1], hi[1])
                   + wavefront_distance(base[2], lo[2], hi[2])
                   - wavefront_distance(0, component(lo, primary), component(hi, primary)))
    rp = m - r_other
    if rp < 0:
        return
    lp = component(lo, primary)
    hp = component(hi, primary)
    p0 = component(blo, primary)
    p1 = component(bhi, primary)
    if rp == 0:
        if side == 0:
            for p in range(wp.max(lp, p0), wp.min(hp + 1, p1)):
                block_upwind_point(sigma, T, grid_index(primary, p, ga, gb), off, lo, hi,
                                   inflow, kind, vec, h, source_radius, scheme, dominant)
        return
    p = hp + rp
    if side == 1:
        p = lp - rp
    if p >= p0 and p < p1:
        block_upwind_point(sigma, T, grid_index(primary, p, ga, gb), off, lo, hi, inflow, kind,
                           vec, h, source_radius, scheme, dominant)


@wp.kernel
def block_compose_kernel(T: wp.array4d(dtype=wp.float32), count: int,
                         kinds: wp.array(dtype=wp.int32), vecs: wp.array(dtype=wp.vec3),
                         rgbs: wp.array(dtype=wp.vec3), out: wp.array3d(dtype=wp.vec3),
                         h: wp.vec3, source_radius: float, off: wp.vec3i, blo: wp.vec3i):
    """``compose_kernel`` (eq. 22) at global point ``wp.tid() + blo``."""
    ti, tj, tk = wp.tid()
    g = wp.vec3i(ti + blo[0], tj + blo[1], tk + blo[2])
    x = grid_point(g[0], g[1], g[2], h)
    i = g[0] - off[0]
    j = g[1] - off[1]
    k = g[2] - off[2]
    acc = wp.vec3(0.0)
    for n in range(count):
        e, _u = light_at(kinds[n], vecs[n], rgbs[n], x, source_radius)
        acc = acc + T[n, i, j, k] * e
    out[i, j, k] = acc


@wp.kernel
def block_first_scattered_kernel(T: wp.array4d(dtype=wp.float32), count: int,
                                 kinds: wp.array(dtype=wp.int32), vecs: wp.array(dtype=wp.vec3),
                                 rgbs: wp.array(dtype=wp.vec3),
                                 sigma: wp.array3d(dtype=wp.float32),
                                 color_sigma: wp.array3d(dtype=wp.vec3),
                                 out: wp.array3d(dtype=wp.vec3), h: wp.vec3,
                                 source_radius: float, albedo: float, g: float,
                                 with_displacement: int, px: wp.array3d(dtype=wp.vec3),
                                 py: wp.array3d(dtype=wp.vec3), pz: wp.array3d(dtype=wp.vec3),
                                 off: wp.vec3i, blo: wp.vec3i, shape: wp.vec3i):
    """``composition.first_scattered_kernel`` at global light-grid point ``wp.tid() + blo``
    of a grid of ``shape`` points, stored at ``- off`` in the ghosted arrays (same
    operations: the cell's box faces are the global ones)."""
    ti, tj, tk = wp.tid()
    gi = ti + blo[0]
    gj = tj + blo[1]
    gk = tk + blo[2]
    i = gi - off[0]
    j = gj - off[1]
    k = gk - off[2]
    acc, mx, my, mz = first_scattered_at(T, count, kinds, vecs, rgbs, sigma, color_sigma, h,
                                         source_radius, albedo, g, with_displacement, i, j, k,
                                         wp.vec3i(gi, gj, gk), shape)
    out[i, j, k] = acc
    if with_displacement != 0:
        px[i, j, k] = mx
        py[i, j, k] = my
        pz[i, j, k] = mz
