"""Physically based diffusion of the scattered light: flux-limited diffusion with a
vacuum boundary, solved by nonlinear multigrid (the ``"physical"`` diffusion model).

The equation
------------
The diffusion (P1) approximation of radiative transfer for the fluence ``phi_s`` of
light that has scattered at least once, per RGB channel ``c``:

    -div(D_c grad phi_s,c) + sigma_a,c phi_s,c = Q_c

with the first-scattered source ``Q`` of
:mod:`~vtkillum.core.convection_diffusion.composition` (``sigma_s`` times the direct
fluence), ``sigma_s,c = albedo color_c sigma_t``, ``sigma_a,c = sigma_t - sigma_s,c``,
and the diffusion coefficient of the *reduced* (transport) extinction
``sigma_tr,c = sigma_a,c + sigma_s,c (1 - g)``:

    D_c = 1 / (3 sigma_tr,c)       (classic diffusion; limiter ``"none"``)

Flux limiter
------------
Classic diffusion lets the flux ``|F| = D |grad phi|`` exceed the fluence ``phi``
(faster than light) wherever the medium is thin or empty, and ``D`` is infinite in
vacuum: light would cross empty space instantly and pile up in the box. The flux
limiter of Levermore & Pomraning (1981, default) replaces the coefficient by

    D = lambda(R) / sigma_tr,     R = 2 |grad phi| / (sigma_tr phi),
    lambda(R) = (coth R - 1 / R) / R

which is ``1 / (3 sigma_tr)`` where ``R -> 0`` (diffusive, optically thick) and
``phi / (2 |grad phi|)`` where ``R -> inf`` (free streaming: ``|F| -> phi / 2``),
finite in vacuum. Also available: Wilson's ``D = 1 / (3 sigma_tr + 2 |grad phi| /
phi)``, Larsen's (n = 2) ``D = (9 sigma_tr^2 + (2 |grad phi| / phi)^2)^(-1/2)`` and
``"none"``. ``D`` is capped at the box diagonal (only reached where ``phi`` has no
gradient).

The factor 2 (:data:`FREE_STREAMING`) sets the free-streaming limit to the flux of a
half-range isotropic radiance, ``|F| = phi / 2``: what leaves the surface of a thick
medium into vacuum. With it, flux continuity at a medium's surface *is* the Marshak
vacuum condition (``F . n = phi / 2``, extrapolation length ``2 D``), wherever the
surface lies in the grid; Levermore & Pomraning's own limit ``|F| = phi`` (a
collimated beam) halves the extrapolation length and lets light escape too fast:
image energy 0.86 / 0.83 / 0.69 of the path tracer's on the balls (albedo 0.9 /
0.99) and the cloud of the table below, instead of 1.00 / 1.06 / 0.91 (both measured
without the source moments).

The coefficients depend on the solution; they are *lagged*: every outer iteration
evaluates them from the current ``phi`` on the light grid (the coarser multigrid levels
get theirs from the finer level's) and then runs one multigrid V-cycle of the linear
problem (Picard iteration).
A cold start begins with nested iteration (:meth:`RadiativeDiffusion._nested_start`), and
so does a warm start (the previous solution after an edit) that is far from the new one:
nested iteration then corrects it coarse to fine.

Vacuum boundary
---------------
Nothing enters the box from outside: the Marshak condition, zero incoming partial
current ``J- = phi / 4 - (D / 2) d phi / dn = 0``, i.e. the outgoing flux through a
box face is ``F . n = phi / 2`` (the extrapolated boundary ``phi = 0`` at ``2 D``
beyond the face, to first order). Energy leaves the box there, so that a
high-albedo medium in a box does not keep its light.

Discretisation
--------------
Finite volumes on the light grid, one cell of size ``h`` (per axis) around each
point, 7-point stencil; equations divided by the cell volume:

    sum_faces k_f (phi_i - phi_j) + (sigma_a,i + b_i) phi_i = Q_i

* interior face between cells ``i`` and ``j`` along axis ``a``: ``k_f = D_f / h_a^2``,
  ``D_f`` from the limiter with the face means of ``sigma_tr`` (arithmetic: the
  harmonic mean of the classic ``D``, which keeps the flux continuous across a jump
  of the medium) and of ``phi``, and the face gradient (normal component from the two
  cells, tangential components from their central differences);
* box face of a boundary cell (at ``h_a / 2`` beyond its point): the Marshak flux
  through a face half a cell away, ``F = phi_i 2 D / (4 D + h_a)``, so
  ``b_i = sum_box faces 2 D_i / ((4 D_i + h_a) h_a)`` with the cell's own ``D_i``.

The matrix is a symmetric M-matrix for fixed coefficients, and summing the
equations gives the discrete energy balance exactly (:meth:`energy_balance`):

    emitted  sum Q V  =  absorbed  sum sigma_a phi V  +  escaped  sum b phi V.

Source moments
--------------
The source can carry a dipole density ``p`` (the displacement of the first-scattered
source within its cell and forward by anisotropic scattering,
:mod:`~vtkillum.core.convection_diffusion.composition`): the right-hand side becomes
``Q - div p`` with face-mean fluxes; its negative parts (next to empty cells) are
clipped and the rest rescaled to the same total, so that ``phi >= 0`` and the lagged
limiter does not oscillate.

Multigrid
---------
The hierarchy of :class:`~vtkillum.core.convection_diffusion.multigrid.Multigrid`
(cell-centred coarsening, mean restriction, trilinear prolongation), with the
coarse operators *homogenized* from the finer level's face coefficients (conductances in
series along each axis and in parallel across it; the mean absorption and leakage:
:mod:`~vtkillum.core.convection_diffusion.coarsening`, which says why re-discretizing the
limiter on the restricted ``phi`` and ``sigma_tr`` made the V-cycle diverge on the
benchmark's grids); red–black Gauss–Seidel V(2,2) cycles; the coarsest grid
(at most :data:`COARSEST_CELLS` cells) is relaxed with :data:`COARSE_SWEEPS`
sweeps.

The outer iterations are Anderson-accelerated (:meth:`RadiativeDiffusion._anderson_iteration`,
``anderson=True``). A solve ends at the tolerance, at the iteration budget, or when the
V-cycles stall (:func:`stalled`: the plain lagged-limiter iteration can settle into a cycle
above the tolerance).
Convergence is measured by the relative correction ``max_c ||r_c / diag_c|| /
||phi_c||``, the nonlinear residual ``r = Q - A(phi) phi`` (coefficients of the current
``phi``) scaled by the diagonal: the change a Jacobi step would make, relative to the
solution (``|Q| / diag`` stands in for ``phi`` where that is larger, e.g. at a cold
start). The raw residual would be dominated by empty cavities, whose diffusion
coefficient is capped at the box diagonal, where a change of ``phi`` by 1e-4 gives a
residual as large as the source. The sums run over the medium (``sigma_tr h >= 1e-3``)
and its face neighbours: empty cells further away are never rendered (``sigma_s = 0``
there) and reach the medium only through cells that are counted; left in, their slow
convergence (the lagged limiter spreads a change by about a cell per iteration through
empty space) would set the iteration count while the medium has long converged. The
float32 floor of this measure is ``4 eps32``. With the default tolerance 3e-4 the
image differs from a converged solve by at most 0.32 % on the accuracy suite (1e-4:
0.10 %, 1e-3: 2.4 %; ``docs/convection_diffusion_tolerance.md``); after a transfer-function
edit of the benchmark's grids (32³-128³) a solve takes 4-15 outer iterations.

Accuracy (against the path tracer)
----------------------------------
Relative RMSE ``||img - ref|| / ||ref||`` over pixels and channels, and the image sum
over the reference's (energy), 48x48 images; the reference is ``path`` with 1024
samples per pixel (its own noise, from two halves, in the second column); the
convection–diffusion image is rendered at 4x4 samples per pixel and box-filtered, as
the path tracer's pixels are. Volumes 32^3 (plume 32x32x48), light grids at half
resolution (the default). ``paper`` uses diffusion theory's ``sigma_hat_s = D /
sigma_a`` of the densest material; the old default is ``paper`` with
``sigma_hat_s = 0`` (isotropic single scattering from the light volume).

=============================================  =====  =============  =============  =============
scene                                          noise  physical       paper          old default
=============================================  =====  =============  =============  =============
cloud, albedo 0.95, g 0.4, optical diam. ~40   0.043  0.154 / 0.92   0.543 / 0.55   0.614 / 0.45
ball, albedo 0.9, optical radius 6.5           0.029  0.049 / 1.00   0.555 / 0.53   0.649 / 0.37
ball, albedo 0.99                              0.033  0.065 / 1.05   0.612 / 0.50   0.746 / 0.27
plume (thin wisps, dense core), 0.95, g 0.3    0.037  0.170 / 0.90   0.445 / 0.65   0.471 / 0.62
CT phantom (``builtin:ct:32``), 2 lights       0.031  0.105 / 0.95   0.380 / 0.68   0.391 / 0.67
cloud, point light, albedo 0.9                 0.025  0.079 / 0.97   0.428 / 0.65   0.527 / 0.50
=============================================  =====  =============  =============  =============

Limits: the light grid must resolve the surface layer of thick media. A sharp ball
with ``sigma_t h = 3`` per light cell (64^3 data, albedo 0.9) gives 0.154 / 0.86 at
half resolution, 0.106 / 0.91 with ``light_volume_scale=1`` and 0.053 / 0.98 with 2
(the first-scattered source and the boundary layer sit in a fraction of a cell).
The diffusion model itself, converged in resolution, is 2-7 % too bright at high
albedo (balls 1.02 / 1.07, cloud 1.07 at ``light_volume_scale=2``).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.coarsening import coarse_coefficients
from vtkillum.core.convection_diffusion.diffusion import DiffusionReport
from vtkillum.core.convection_diffusion.multigrid import (
    child_of,
    prolong_add_kernel,
    restrict_kernel,
)
from vtkillum.core.convection_diffusion.stencil import add_channels
from vtkillum.core.graphs import LaunchGraphs, array_key
from vtkillum.core.warp_common import HostReader, axis_offset, capped_kernel, component

#: Flux limiters (see the module docstring).
LIMITERS = {"levermore-pomraning": 0, "wilson": 1, "larsen": 2, "none": 3}
LP = wp.constant(0)
WILSON = wp.constant(1)
LARSEN = wp.constant(2)

#: Free-streaming limit of the flux, ``|F| -> phi / FREE_STREAMING`` (see the module docstring).
FREE_STREAMING = wp.constant(2.0)

#: Register cap of the lagged coefficients' kernels on CUDA (H100, 128³, a face kernel:
#: 63 µs a launch uncapped, 60 with 64, 65 with 48 or 80, 82 with 96).
COEFFICIENT_REGISTERS = 64

#: float32 machine epsilon (the residual measure's floor is four of them).
FLOAT32_EPS = float(np.finfo(np.float32).eps)

#: Coarsening stops at this many cells; the coarsest grid is relaxed, not solved.
COARSEST_CELLS = 64
#: Threads of the one block that relaxes the coarsest grid (:func:`coarse_relax`):
#: at least two warps, so that the block reduction used as a barrier is block-wide.
COARSE_BLOCK = 64
#: A solve stops as stalled when :data:`STALL_WINDOW` outer iterations lower the best
#: residual by less than :data:`STALL_GAIN` (:func:`stalled`): with the re-discretized
#: coarse operators and without Anderson mixing, the benchmark's Bonsai, Blood Vessels and
#: Foot grids settled into a two-cycle at a residual of ~3.7e-4 after ~8 iterations and
#: the remaining 90 of the 100-iteration cap changed nothing (the homogenized operators of
#: :mod:`~vtkillum.core.convection_diffusion.coarsening` converge them; the check stays as
#: a guard).
STALL_WINDOW = 4
STALL_GAIN = 0.05
#: Anderson acceleration: history slots (depth + 1) and the largest mixing weight accepted.
ANDERSON_SLOTS = 4
ANDERSON_MAX_WEIGHT = 20.0
#: Threads per block and cells per thread of the residual norms.
NORM_BLOCK = 256
NORM_CHUNK = wp.constant(4)
#: Red–black sweeps on the coarsest grid (at most 64 cells) per V-cycle. With the
#: homogenized coarse operators 8 sweeps give the same outer iterations as 40 on the
#: benchmark's Foot, Pillars, Buckyball and Machine Room grids (CPU, warm and cold); each
#: sweep is two block barriers in one launch, which every V-cycle and every iteration of the
#: nested start waits for.
COARSE_SWEEPS = 8
PRE_SMOOTH = 2
POST_SMOOTH = 2
#: Optical size ``sigma_tr h`` below which a cell counts as empty for the residual.
MEDIUM_DEPTH = 1.0e-3
#: Nested iteration (cold start, or the correction of a far warm start): outer iterations on
#: the coarsest and on each finer grid.
#: With the homogenized coarse operators 15 and 4 start the benchmark's Foot, Pillars,
#: Buckyball and Bonsai grids as well as 30 and 6 did (the same fine iterations after it,
#: CPU), at half the launches; 10 and 3 cost an iteration more on two of them.
COARSEST_ITERATIONS = 15
NESTED_ITERATIONS = 4
#: A warm start whose relative correction exceeds this is corrected by nested iteration
#: first (``solve(nested_above=...)``, the solver's default). Foot grid (CPU, 64³): edits
#: whose warm start measured 3.5e-3 / 7.5e-3 took 3 / 4 outer iterations from it, while
#: the benchmark's transfer-function swaps (~2e-2) took 9-15 at 64³-128³ and 6-8 after
#: the correction, which costs a few finest-grid iterations.
WARM_NESTED_ABOVE = 1.0e-2
#: A warm start's nested correction iterates from the first level with at most this many
#: cells (the half-resolution grid at least), not from the coarsest: its V-cycles still
#: reach the coarsest grid, and the levels left out would cost their launches (the
#: coarse levels' work is latency, not arithmetic: the whole nested start cost 3-5 ms on
#: an H100). CPU, outer iterations after the benchmark's swaps: Foot (64³), Pillars (50³)
#: and Machine Room the same from level 1 as from the coarsest; Bonsai (128³) 11 / 6 / 11
#: from the coarsest, 12 / 9 / 12 from level 1 (64³) and 10 / 7 / 10 from level 2 (32³).
WARM_NESTED_CELLS = 32 ** 3


class Level:
    """One grid of the hierarchy: shape, spacing, coefficients and work arrays."""

    def __init__(self, shape, spacing, device):
        self.shape = tuple(int(n) for n in shape)
        self.spacing = np.asarray(spacing, dtype=np.float64)
        self.h = wp.vec3(*self.spacing.astype(np.float32))
        self.inv_h = wp.vec3(*(1.0 / self.spacing).astype(np.float32))
        nx, ny, nz = self.shape

        def vec3(s):
            return wp.zeros(s, dtype=wp.vec3, device=device)

        self.sigma_a = vec3(self.shape)
        self.sigma_tr = vec3(self.shape)
        self.absorb = vec3(self.shape)  # sigma_a + the box faces' leakage: the diagonal's own part
        self.kx = vec3((nx - 1, ny, nz))
        self.ky = vec3((nx, ny - 1, nz))
        self.kz = vec3((nx, ny, nz - 1))
        self.q = None  # nested iteration: this level's own source, solution and estimate
        self.sol = None
        self.estimate = None
        self.x = vec3(self.shape)  # coarse-level correction
        self.b = vec3(self.shape)  # coarse-level right-hand side

    def nested_arrays(self, device) -> None:
        """Allocate the nested iteration's arrays of a coarse level (once)."""
        if self.q is None:
            self.q, self.sol, self.estimate = (wp.zeros(self.shape, dtype=wp.vec3, device=device)
                                               for _ in range(3))

    @property
    def coefficients(self):
        return [self.kx, self.ky, self.kz, self.absorb]


class RadiativeDiffusion:
    """``-div(D grad phi) + sigma_a phi = Q`` per RGB channel on a light grid.

    Parameters
    ----------
    shape : (3,) int
        Light-grid points per axis.
    spacing : (3,) float
        Light-grid spacing (world units).
    limiter : str
        One of :data:`LIMITERS`.
    device : str
        Warp device.

    Set the medium with :meth:`set_medium`, then call :meth:`solve`.
    """

    def __init__(self, shape, spacing, limiter: str = "levermore-pomraning",
                 device: str = "cpu"):
        if limiter not in LIMITERS:
            raise ValueError(f"unknown flux limiter {limiter!r}; choose one of {sorted(LIMITERS)}")
        self.device = device
        self.limiter = limiter
        shapes = [tuple(int(n) for n in shape)]
        spacings = [np.asarray(spacing, dtype=np.float64)]
        while int(np.prod(shapes[-1])) > COARSEST_CELLS:
            n = np.asarray(shapes[-1])
            halve = n >= 4
            if not halve.any():
                break
            nc = np.where(halve, (n + 1) // 2, n)
            spacings.append(spacings[-1] * n / nc)
            shapes.append(tuple(int(v) for v in nc))
        self.levels = [Level(s, h, device) for s, h in zip(shapes, spacings)]
        self.shape = shapes[0]
        self.spacing = spacings[0]
        #: Largest diffusion coefficient (world units): the box diagonal.
        self.d_max = float(np.linalg.norm(self.spacing * (np.asarray(self.shape) - 1)))
        #: Cells with a smaller reduced extinction (1/world units) are left out of the residual.
        self.min_sigma = MEDIUM_DEPTH / float(self.spacing.min())
        self._norms = wp.zeros(6, dtype=wp.float64, device=device)
        self._norms_host = HostReader(self._norms)  # read after every outer iteration
        # 1 where the residual norms count a cell (near_medium), set with the medium
        self._counted = wp.zeros(self.shape, dtype=wp.uint8, device=device)
        self._rhs = None
        self._best = None  # the best iterate of a solve (kept: graphs record its address)
        self._has_medium = False
        #: Captured outer iterations and nested starts (:mod:`~vtkillum.core.graphs`).
        self.graphs = LaunchGraphs(device)
        #: Anderson acceleration of the outer iteration (:meth:`_anderson_iteration`).
        self.anderson = True
        self._aa = None
        #: Where a far warm start's nested correction begins: the first level with at most
        #: :data:`WARM_NESTED_CELLS` cells (at least 1; the levels do not change).
        self.warm_nested_top = next(
            (i for i in range(1, len(self.levels))
             if int(np.prod(self.levels[i].shape)) <= WARM_NESTED_CELLS), len(self.levels) - 1)

    # --- public ----------------------------------------------------------------------------
    def set_medium(self, sigma: wp.array3d, color_sigma: wp.array3d, albedo: float,
                   anisotropy: float) -> None:
        """Absorption and reduced extinction from the light grid's optics, on every level.

        Parameters
        ----------
        sigma : warp.array3d of float32
            Cell-mean ``sigma_t`` (1/world units).
        color_sigma : warp.array3d of vec3
            Cell-mean ``color * sigma_t``.
        albedo, anisotropy : float
            Single-scattering albedo and Henyey–Greenstein ``g``.
        """
        key = ("medium", float(albedo), float(anisotropy)) + array_key(sigma, color_sigma)
        self.graphs.run(key, lambda: self._medium(sigma, color_sigma, albedo, anisotropy))
        self._has_medium = True

    def _medium(self, sigma, color_sigma, albedo, anisotropy) -> None:
        """The launches of :meth:`set_medium` (one replayed graph per medium's arrays)."""
        top = self.levels[0]
        # Inside the box the diagonal's own part (``absorb``) is sigma_a: the coefficient
        # updates write only the box faces' cells (:func:`leakage_kernel`). The coarse
        # levels' is always homogenized from the finer level's first (every solve updates
        # the finest level's coefficients before any other): the children's mean, inside
        # their boxes the same bits as the restricted sigma_a below.
        wp.launch(medium_kernel, dim=self.shape, device=self.device,
                  inputs=[sigma, color_sigma, float(albedo), float(anisotropy), top.sigma_a,
                          top.sigma_tr, top.absorb])
        wp.launch(counted_kernel, dim=self.shape, device=self.device,
                  inputs=[top.sigma_tr, self.min_sigma, self._counted])
        for fine, coarse in zip(self.levels, self.levels[1:]):
            ratio = self._ratio(fine, coarse)
            for a, b in ((fine.sigma_a, coarse.sigma_a), (fine.sigma_tr, coarse.sigma_tr)):
                wp.launch(restrict_kernel, dim=coarse.shape, device=self.device,
                          inputs=[a, b, ratio])

    def update_coefficients(self, x: wp.array3d, start: int = 0) -> None:
        """Lagged coefficients (face ``D / h^2``, boundary leakage) from the solution ``x``.

        ``x`` lives on level ``start``; the coarser levels get theirs from that level's by
        homogenization (:mod:`~vtkillum.core.convection_diffusion.coarsening`).
        """
        self._check_medium()
        level = self.levels[start]
        limiter = LIMITERS[self.limiter]
        for kernel, k in zip(FACE_KERNELS, (level.kx, level.ky, level.kz)):
            wp.launch(kernel, dim=k.shape, device=self.device,
                      inputs=[x, level.sigma_tr, k, level.inv_h, self.d_max, limiter])
        wp.launch(leakage_kernel, dim=box_face_cells(level.shape), device=self.device,
                  inputs=[x, level.sigma_tr, level.sigma_a, level.absorb, level.h, self.d_max,
                          limiter])
        for fine, coarse in zip(self.levels[start:], self.levels[start + 1:]):
            coarse_coefficients(fine, coarse, self._ratio(fine, coarse), self.device)

    def _update_coefficients_graphed(self, x: wp.array3d) -> None:
        """:meth:`update_coefficients` of every level as one replayed graph (outside the
        recorded sequences, which record it themselves): on small grids the launches' host
        time is more than their work."""
        self._check_medium()
        self.graphs.run(("coefficients",) + array_key(x), lambda: self.update_coefficients(x))

    def solve(self, q: wp.array3d, x: wp.array3d, max_iterations: int = 100,
              tolerance: float = 1e-4, method: str = "multigrid", callback=None,
              displacement=None, cold: bool = False,
              nested_above: float | None = None) -> DiffusionReport:
        """Improve ``x`` in place towards the solution for source ``q``.

        Parameters
        ----------
        q : warp.array3d of vec3
            First-scattered source ``Q``.
        x : warp.array3d of vec3
            Initial guess (zeros, or a previous solution); overwritten.
        max_iterations : int
            Outer iterations (coefficient update + one V-cycle, or one red–black sweep for
            ``method="gauss-seidel"``) of this call.
        tolerance : float
            Relative nonlinear residual to reach (raised to the float32 floor).
        method : str
            ``"multigrid"`` or ``"gauss-seidel"``.
        callback : callable, optional
            ``callback(iteration, residual)`` after every iteration.
        displacement : (3,) warp.array3d of vec3, optional
            Dipole moment of the source per axis
            (:func:`~vtkillum.core.convection_diffusion.composition.first_scattered_source`):
            the right-hand side becomes ``Q - div(p)``, the source displaced within its cell
            and forward.
        cold : bool
            ``x`` is no estimate (zeros): start with nested iteration (:meth:`_nested_start`).
        nested_above : float, optional
            ``x`` is a previous solution (a warm start): when its relative correction
            exceeds this, correct it by nested iteration before the outer iterations
            (:meth:`_nested_start`; a large edit of the medium or the source changes the
            solution at every scale, which the lagged limiter spreads by about a cell per
            outer iteration on the finest grid).
        """
        if method not in ("multigrid", "gauss-seidel"):
            raise ValueError(f"the physical diffusion model is solved with 'multigrid' or "
                             f"'gauss-seidel', not {method!r}")
        report = DiffusionReport()
        self._update_coefficients_graphed(x)
        rhs = q
        if displacement is not None:
            if self._rhs is None:
                self._rhs = wp.empty_like(q)
            rhs = self._rhs

        if rhs is not q:
            def displaced():
                wp.launch(displaced_source_kernel, dim=self.shape, device=self.device,
                          inputs=[q, *displacement, self.levels[0].h, rhs])
                # Clip the negative parts (a dipole next to an empty cell), keeping the total.
                self._channel_sums(rhs, squares=False)
                wp.launch(clip_rescale_kernel, dim=self.shape, device=self.device,
                          inputs=[rhs, self._norms])

            self.graphs.run(("displaced",) + array_key(q, *displacement, rhs), displaced)
        res, floor = self.residual(x, rhs)
        report.residuals.append(res)
        if res <= max(tolerance, floor):
            report.converged = True
            return report
        far = nested_above is not None and res > nested_above
        if (cold or far) and method == "multigrid" and len(self.levels) > 1:
            report.nested = True
            for coarse in self.levels[1:]:  # allocated before a capture, kept
                coarse.nested_arrays(self.device)
            top = None if cold else self.warm_nested_top
            self.graphs.run(("nested", top) + array_key(rhs, x),
                            lambda: self._nested_start(rhs, x, top))
            self._update_coefficients_graphed(x)
            res, floor = self.residual(x, rhs)
        # The lagged-coefficient V-cycle can diverge where the limited coefficients jump by
        # orders of magnitude between cells (seen on CUDA at 128x128x89): keep the best
        # iterate, and on divergence (non-finite, or 10x worse than the best) go back to it
        # and continue with red-black Gauss-Seidel sweeps, which always converge (slowly).
        # The best iterate is copied at the start of the next iteration's graph (a host copy
        # per iteration cost more than the copy), into an array kept across solves (a new
        # one would be a new graph to record every solve).
        best_res = res if np.isfinite(res) else np.inf
        best = None
        if method == "multigrid":
            if self._best is None or tuple(self._best.shape) != tuple(x.shape):
                self._best = wp.empty_like(x)
            best = self._best
        save_best = best is not None  # x is the best iterate so far
        smoothing_only = method != "multigrid"
        anderson = self._anderson_start(x) if self.anderson and not smoothing_only else None
        for _ in range(int(max_iterations)):
            keep = best if save_best and not smoothing_only else None
            if anderson is not None and not smoothing_only:
                self._anderson_iteration(x, rhs, anderson, keep)
            else:
                self._outer_iteration(x, rhs, smoothing_only, keep)
            save_best = False
            res, floor = self._read_residual()
            report.iterations += 1
            if best is not None and not smoothing_only:
                if not np.isfinite(res) or res > 10.0 * best_res:
                    wp.copy(x, best)
                    self._update_coefficients_graphed(x)
                    res, floor = self.residual(x, rhs)
                    smoothing_only = True
                    report.fallback = True
                elif res < best_res:
                    best_res = res
                    save_best = True
            report.residuals.append(res)
            if callback is not None:
                callback(report.iterations, res)
            if res <= max(tolerance, floor):
                report.converged = True
                break
            if not smoothing_only and stalled(report.residuals):  # Gauss-Seidel is slow, not stalled
                report.stalled = True
                break
        return report

    def _anderson_start(self, x: wp.array3d) -> dict:
        """History of Anderson acceleration (:meth:`_anderson_iteration`) for iterate ``x``:
        :data:`ANDERSON_SLOTS` slots of ``G(x_k)`` and ``F_k = G(x_k) - x_k`` on the device,
        their Gram matrix and which slots are in the history, on the device too."""
        if self._aa is None or tuple(self._aa["G"][0].shape) != tuple(x.shape):
            def field():
                return wp.zeros(x.shape, dtype=wp.vec3, device=self.device)

            self._aa = {"G": [field() for _ in range(ANDERSON_SLOTS)],
                        "F": [field() for _ in range(ANDERSON_SLOTS)],
                        "dots": wp.zeros(ANDERSON_SLOTS, dtype=wp.float64, device=self.device),
                        "alpha": wp.zeros(ANDERSON_SLOTS, dtype=wp.float32, device=self.device),
                        "gram": wp.zeros((ANDERSON_SLOTS, ANDERSON_SLOTS), dtype=wp.float64,
                                         device=self.device),
                        "valid": wp.zeros(ANDERSON_SLOTS, dtype=wp.int32, device=self.device),
                        "work": wp.zeros((ANDERSON_SLOTS + 1, ANDERSON_SLOTS + 1),
                                         dtype=wp.float64, device=self.device)}
        self._aa["gram"].zero_()
        self._aa["valid"].zero_()  # slots in the history
        self._aa["k"] = 0
        return self._aa

    def _anderson_iteration(self, x: wp.array3d, rhs: wp.array3d, aa: dict,
                            best: wp.array3d | None = None) -> None:
        """One outer iteration with Anderson acceleration of depth ``ANDERSON_SLOTS - 1``.

        The outer (Picard) iteration is a fixed-point map ``x -> G(x)``: a V-cycle with the
        coefficients of ``x``. Its convergence is set by the lagged limiter, not by the
        V-cycle (two or three V-cycles per coefficient update take as many outer
        iterations on the Foot grid, CPU). Anderson mixing (Walker & Ni 2011) takes the
        next iterate as the combination
        ``sum_j alpha_j G(x_j)`` of the last iterates' images whose residuals
        ``F_j = G(x_j) - x_j`` combine to the smallest ``||sum_j alpha_j F_j||`` with
        ``sum_j alpha_j = 1``; on the Foot grid (CPU, 64³) it cuts the plain iteration's
        9-11 outer iterations to 7-8 (depth 5 or 8, or weights per channel, gained at most
        one more). Weights beyond :data:`ANDERSON_MAX_WEIGHT` (an
        ill-conditioned history) fall back to the plain step and restart the history.
        The weights are solved on the device (:func:`anderson_weights_kernel`), so that an
        iteration is one replayed graph and one read of the residual norms: the host's
        solve between two graphs cost a synchronisation and left the GPU idle. ``best``:
        copy ``x`` there first.
        """
        slot = aa["k"] % ANDERSON_SLOTS
        aa["k"] += 1
        G, F = aa["G"], aa["F"]

        def record():
            if best is not None:
                wp.copy(best, x)
            # G(x) into slot (the V-cycle runs on the slot, x keeps x_k), F_slot = G(x) - x
            # and <F_slot, F_j> for every slot in one pass
            wp.copy(G[slot], x)
            self.vcycle(G[slot], rhs)
            aa["dots"].zero_()
            n = int(np.prod(x.shape))
            block = _block(self.device, NORM_BLOCK)
            wp.launch_tiled(anderson_dots_kernel, dim=[-(-n // (block * NORM_CHUNK))],
                            block_dim=block, device=self.device,
                            inputs=[G[slot], x, F[slot], *F, aa["dots"], block])
            # the weights from the Gram matrix, on the device (no round trip to the host)
            wp.launch(anderson_weights_kernel, dim=1, device=self.device,
                      inputs=[aa["dots"], aa["gram"], aa["valid"], slot, ANDERSON_MAX_WEIGHT,
                              aa["alpha"], aa["work"]])
            # x = sum_j alpha_j G_j, its coefficients and residual norms
            wp.launch(anderson_mix_kernel, dim=x.shape, device=self.device,
                      inputs=[*G, aa["alpha"], x])
            self.update_coefficients(x)
            self._launch_residual(x, rhs)

        self.graphs.run(("anderson", slot) + array_key(x, rhs, best), record)

    def _outer_iteration(self, x: wp.array3d, rhs: wp.array3d, smoothing_only: bool,
                         best: wp.array3d | None = None) -> None:
        """One outer iteration, replayed from a captured graph: a V-cycle (or one red-black
        sweep), the lagged coefficients of the new iterate and its residual norms
        (read by :meth:`_read_residual`); ``best``: copy ``x`` there first."""
        top = self.levels[0]

        def record():
            if best is not None:
                wp.copy(best, x)
            if smoothing_only:
                relax(top, x, rhs, 1)
            else:
                self.vcycle(x, rhs)
            self.update_coefficients(x)
            self._launch_residual(x, rhs)

        self.graphs.run(("outer", smoothing_only) + array_key(x, rhs, best), record)

    def _nested_start(self, q: wp.array3d, x: wp.array3d, top: int | None = None) -> None:
        """Correct the estimate ``x`` (zeros at a cold start) by nested iteration (full
        multigrid, correction scheme), in place.

        The lagged flux limiter spreads a change of the solution by about a cell per outer
        iteration in optically thin regions, so a cold start, or an edit that changes the
        solution everywhere, needs iterations on the finest grid in proportion to its size.
        The source and ``x`` are restricted down to the coarsest level iterated, whose
        problem is iterated from its restricted ``x``, and each finer grid's from its own
        restricted ``x`` plus the interpolated change its coarser grid made
        (:data:`COARSEST_ITERATIONS`, then :data:`NESTED_ITERATIONS` outer iterations a
        level), which leaves the finest grid only its local corrections. From zeros this
        is plain nested iteration (the interpolated coarser solution). ``top``: the
        coarsest level iterated (default: the coarsest grid; a warm start is corrected
        from :attr:`warm_nested_top`), with :data:`NESTED_ITERATIONS` there unless it is
        the coarsest grid.
        """
        levels = self.levels
        coarsest = len(levels) - 1
        last = coarsest if top is None else max(1, min(int(top), coarsest))
        for fine, coarse in zip(levels[:last], levels[1:last + 1]):
            coarse.nested_arrays(self.device)  # no-op when solve() allocated them
            ratio = self._ratio(fine, coarse)
            src_q, src_x = (q, x) if fine is levels[0] else (fine.q, fine.estimate)
            wp.launch(restrict_kernel, dim=coarse.shape, device=self.device,
                      inputs=[src_q, coarse.q, ratio])
            wp.launch(restrict_kernel, dim=coarse.shape, device=self.device,
                      inputs=[src_x, coarse.estimate, ratio])
        wp.copy(levels[last].sol, levels[last].estimate)
        for index in range(last, 0, -1):
            lv = levels[index]
            iterations = COARSEST_ITERATIONS if index == coarsest else NESTED_ITERATIONS
            for _ in range(iterations):
                self.update_coefficients(lv.sol, index)
                self.vcycle(lv.sol, lv.q, index)
            fine = levels[index - 1]
            target = x
            if index > 1:
                target = fine.sol
                wp.copy(target, fine.estimate)
            wp.launch(difference_kernel, dim=lv.shape, device=self.device,
                      inputs=[lv.sol, lv.estimate, lv.x])  # lv.x: the V-cycle's scratch
            wp.launch(prolong_add_kernel, dim=fine.shape, device=self.device,
                      inputs=[lv.x, target, self._ratio(fine, lv)])

    def vcycle(self, x: wp.array3d, b: wp.array3d, level: int = 0) -> None:
        """One V(2,2) cycle for the current (lagged) coefficients, in place."""
        lv = self.levels[level]
        if level == len(self.levels) - 1:
            coarse_relax(lv, x, b, COARSE_SWEEPS)
            return
        relax(lv, x, b, PRE_SMOOTH)
        coarse = self.levels[level + 1]
        ratio = self._ratio(lv, coarse)
        # the residual is only restricted: computed per child inside the restriction
        wp.launch(residual_restrict_kernel, dim=coarse.shape, device=self.device,
                  inputs=[x, b, coarse.b, *lv.coefficients, ratio])
        coarse.x.zero_()
        self.vcycle(coarse.x, coarse.b, level + 1)
        wp.launch(prolong_add_kernel, dim=lv.shape, device=self.device,
                  inputs=[coarse.x, x, ratio])
        relax(lv, x, b, POST_SMOOTH, reverse=True)

    def residual(self, x: wp.array3d, q: wp.array3d) -> tuple[float, float]:
        """Relative correction ``max_c ||diag(A)^-1 (Q - A x)||_c / ||x||_c`` over the medium
        and its neighbours, and its float32 floor (see the module docstring)."""
        self.graphs.run(("residual",) + array_key(x, q), lambda: self._launch_residual(x, q))
        return self._read_residual()

    def _launch_residual(self, x: wp.array3d, q: wp.array3d) -> None:
        """Sums of :meth:`residual` into ``self._norms`` (device work only)."""
        top = self.levels[0]
        self._norms.zero_()
        block = _block(self.device, NORM_BLOCK)
        cells = int(np.prod(self.shape))
        blocks = -(-cells // (block * NORM_CHUNK))
        wp.launch_tiled(residual_norm_kernel, dim=[blocks], block_dim=block, device=self.device,
                        inputs=[x, q, *top.coefficients, self._counted, self._norms,
                                block])

    def _read_residual(self) -> tuple[float, float]:
        """:meth:`residual` from the sums of :meth:`_launch_residual`.

        Six numbers after every outer iteration: plain floats (numpy's ufuncs on arrays of
        six cost more than the arithmetic), the same IEEE operations as before."""
        floor = 4.0 * FLOAT32_EPS
        sums = self._norms_host.read().tolist()
        if not all(math.isfinite(v) for v in sums):  # a NaN iterate must not read as "converged"
            return float("inf"), floor
        n = [math.sqrt(v) for v in sums]
        rel = 0.0
        for c in range(3):
            if n[c] > 0.0:
                rel = max(rel, 1.0 if n[3 + c] == 0.0 else n[c] / max(n[3 + c], 1e-300))
        return rel, floor

    def apply(self, x: wp.array3d, out: wp.array3d | None = None) -> wp.array3d:
        """``A x`` with the current coefficients (tests and diagnostics)."""
        out = wp.empty_like(x) if out is None else out
        zero = wp.zeros_like(x)
        top = self.levels[0]
        wp.launch(residual_field_kernel, dim=self.shape, device=self.device,
                  inputs=[x, zero, out, *top.coefficients])
        wp.launch(negate_kernel, dim=self.shape, device=self.device, inputs=[out])
        return out

    def energy_balance(self, q: wp.array3d, x: wp.array3d) -> dict:
        """Emitted, absorbed and escaped power per RGB channel (float64, host).

        ``emitted = sum Q V``, ``absorbed = sum sigma_a phi V``, ``escaped = sum b phi V``
        (``V`` the cell volume) with the current coefficients; at convergence
        ``emitted = absorbed + escaped`` up to the residual.
        """
        top = self.levels[0]
        v = float(np.prod(self.spacing))
        phi = x.numpy().astype(np.float64)
        return {
            "emitted": q.numpy().astype(np.float64).sum((0, 1, 2)) * v,
            "absorbed": (top.sigma_a.numpy() * phi).sum((0, 1, 2)) * v,
            "escaped": ((top.absorb.numpy().astype(np.float64) - top.sigma_a.numpy()) * phi
                        ).sum((0, 1, 2)) * v,
        }

    # --- internals -------------------------------------------------------------------------
    def _check_medium(self) -> None:
        if not self._has_medium:
            raise RuntimeError("call set_medium() before solving")

    def _ratio(self, fine: Level, coarse: Level):
        return wp.vec3i(*((np.asarray(fine.shape) != np.asarray(coarse.shape)).astype(int) + 1))

    def _norm(self, a) -> np.ndarray:
        self._channel_sums(a, squares=True)
        return np.sqrt(self._norms_host.read()[:3])

    def _channel_sums(self, a: wp.array3d, squares: bool) -> None:
        """:func:`channel_sums_kernel` of ``a`` into ``self._norms`` (zeroed first)."""
        self._norms.zero_()
        block = _block(self.device, NORM_BLOCK)
        blocks = -(-int(np.prod(a.shape)) // (block * NORM_CHUNK))
        wp.launch_tiled(channel_sums_kernel, dim=[blocks], block_dim=block, device=self.device,
                        inputs=[a, self._norms, block, int(bool(squares))])


def relax(level: Level, x: wp.array3d, b: wp.array3d, sweeps: int, reverse: bool = False) -> None:
    """``sweeps`` red–black Gauss–Seidel sweeps on ``level`` in place."""
    nx, ny, nz = level.shape
    dim = (nx, ny, (nz + 1) // 2)
    colors = (1, 0) if reverse else (0, 1)
    for _ in range(int(sweeps)):
        for color in colors:
            wp.launch(red_black_kernel, dim=dim, device=x.device,
                      inputs=[x, b, *level.coefficients, color])


def stalled(residuals) -> bool:
    """Whether the last :data:`STALL_WINDOW` outer iterations lowered the best residual
    by less than the fraction :data:`STALL_GAIN` (``residuals[0]`` is the start's)."""
    if len(residuals) <= STALL_WINDOW + 1:
        return False
    recent = min(residuals[-STALL_WINDOW:])
    before = min(residuals[1:-STALL_WINDOW])
    return bool(np.isfinite(before) and recent > (1.0 - STALL_GAIN) * before)


def coarse_relax(level: Level, x: wp.array3d, b: wp.array3d, sweeps: int) -> None:
    """:func:`relax` on a small grid in one launch: one thread block runs every sweep,
    with a block barrier between the colours (``2 * sweeps`` launches otherwise, each
    costing more than the work on the coarsest grid)."""
    block = _block(x.device, COARSE_BLOCK)
    wp.launch_tiled(coarse_relax_kernel, dim=[1], block_dim=block, device=x.device,
                    inputs=[x, b, *level.coefficients, int(sweeps), block])


def _block(device, threads: int) -> int:
    """Threads per block of a tiled launch: ``threads`` on CUDA; the CPU runs one."""
    return threads if wp.get_device(device).is_cuda else 1


# --- device functions ----------------------------------------------------------------------------
@wp.func
def limited_coefficient(sigma_tr: float, grad: float, phi: float, d_max: float, limiter: int):
    """Diffusion coefficient ``D`` (world units) of one channel; see the module docstring.

    Levermore–Pomraning as ``D = (coth R - 1/R) / (R sigma_tr)`` with ``R = 2 |grad phi| /
    (sigma_tr phi)``, ``coth R = (1 + e) / (1 - e)``, ``e = exp(-2 R)``: ``D = (R (1 + e) -
    (1 - e)) / (R^2 (1 - e) sigma_tr)``, and its Taylor series ``(1/3 - R^2/45 + ...) /
    sigma_tr`` below ``R = 0.5``, where the difference of ``coth R`` and ``1 / R`` cancels
    (relative error ``~3 eps / R^2``; the difference of ``1 / tanh R`` and ``1 / R``, with the
    series only below ``R = 0.01``, was up to 3.6e-3 off there). Both branches are
    evaluated and one selected, so a warp does not diverge and the limiter costs two
    divisions (``R`` and ``D``); ``e`` underflows to 0 for large ``R``, where the fraction
    is ``(R - 1) / R^2 / sigma_tr`` (``coth R = 1`` to float32). The series' first omitted
    term is below 1e-8 at ``R = 0.5``; the whole limiter is within 2e-6 of float64 for
    every ``R``.
    """
    d = d_max
    if limiter == 3 or phi <= 0.0 or grad <= 0.0:
        if 3.0 * sigma_tr * d_max > 1.0:
            d = 1.0 / (3.0 * sigma_tr)
        return d
    fg = FREE_STREAMING * grad  # g phi, g = 2 |grad phi| / phi (1/world units)
    if limiter == WILSON:
        d = 1.0 / (3.0 * sigma_tr + fg / phi)
    elif limiter == LARSEN:
        g = fg / phi
        d = 1.0 / wp.sqrt(9.0 * sigma_tr * sigma_tr + g * g)
    else:
        ps = phi * sigma_tr
        if ps * 1.0e4 <= fg:
            d = phi / fg  # R = g / sigma_tr -> inf (or vacuum): free streaming, D = 1 / g
        else:
            r = fg / ps
            r2 = r * r
            e = wp.exp(-2.0 * r)
            series = 1.0 / 3.0 + r2 * (-1.0 / 45.0 + r2 * (2.0 / 945.0 + r2 * (
                -1.0 / 4725.0 + r2 * (2.0 / 93555.0))))
            small = r < 0.5
            num = wp.where(small, series, r * (1.0 + e) - (1.0 - e))
            den = wp.where(small, sigma_tr, r2 * (1.0 - e) * sigma_tr)
            d = num / den
    return wp.min(d, d_max)


@wp.func
def limited_vec(sigma_tr: wp.vec3, grad_sq: wp.vec3, phi: wp.vec3, d_max: float, limiter: int):
    return wp.vec3(
        limited_coefficient(sigma_tr[0], wp.sqrt(grad_sq[0]), phi[0], d_max, limiter),
        limited_coefficient(sigma_tr[1], wp.sqrt(grad_sq[1]), phi[1], d_max, limiter),
        limited_coefficient(sigma_tr[2], wp.sqrt(grad_sq[2]), phi[2], d_max, limiter),
    )


@wp.func
def central_difference(phi: wp.array3d(dtype=wp.vec3), p: wp.vec3i, axis: int, h: float):
    """``d phi / dx_axis`` at point ``p`` (``h`` the spacing along ``axis``): central inside,
    one-sided at the box faces."""
    e = axis_offset(axis, 1)
    i = component(p, axis)
    n = component(wp.vec3i(phi.shape[0], phi.shape[1], phi.shape[2]), axis)
    lo = p
    hi = p
    steps = float(0.0)
    if i > 0:
        lo = p - e
        steps += 1.0
    if i < n - 1:
        hi = p + e
        steps += 1.0
    if steps == 0.0:
        return wp.vec3(0.0)
    return (phi[hi[0], hi[1], hi[2]] - phi[lo[0], lo[1], lo[2]]) / (steps * h)


@wp.func
def gradient_sq(phi: wp.array3d(dtype=wp.vec3), p: wp.vec3i, h: wp.vec3):
    """``|grad phi|^2`` per channel at point ``p``."""
    gx = central_difference(phi, p, 0, h[0])
    gy = central_difference(phi, p, 1, h[1])
    gz = central_difference(phi, p, 2, h[2])
    return wp.cw_mul(gx, gx) + wp.cw_mul(gy, gy) + wp.cw_mul(gz, gz)


@wp.func
def dense(sigma_tr: wp.array3d(dtype=wp.vec3), i: int, j: int, k: int, min_sigma: float):
    st = sigma_tr[i, j, k]
    return wp.max(st[0], wp.max(st[1], st[2])) >= min_sigma


@wp.func
def near_medium(sigma_tr: wp.array3d(dtype=wp.vec3), i: int, j: int, k: int, min_sigma: float):
    """Whether the cell or one of its face neighbours has ``max_c sigma_tr >= min_sigma``."""
    if dense(sigma_tr, i, j, k, min_sigma):
        return True
    if i > 0 and dense(sigma_tr, i - 1, j, k, min_sigma):
        return True
    if i < sigma_tr.shape[0] - 1 and dense(sigma_tr, i + 1, j, k, min_sigma):
        return True
    if j > 0 and dense(sigma_tr, i, j - 1, k, min_sigma):
        return True
    if j < sigma_tr.shape[1] - 1 and dense(sigma_tr, i, j + 1, k, min_sigma):
        return True
    if k > 0 and dense(sigma_tr, i, j, k - 1, min_sigma):
        return True
    if k < sigma_tr.shape[2] - 1 and dense(sigma_tr, i, j, k + 1, min_sigma):
        return True
    return False


@wp.func
def add_block_channels(acc: wp.array(dtype=wp.float64), start: int, v: wp.vec3, lane: int):
    """Sum ``v`` over the block of a tiled launch (a tile reduction per channel) and add it
    to ``acc[start:start + 3]`` once, from lane 0."""
    t0 = wp.tile_sum(wp.tile(v[0]))
    t1 = wp.tile_sum(wp.tile(v[1]))
    t2 = wp.tile_sum(wp.tile(v[2]))
    if lane == 0:
        add_channels(acc, start, wp.vec3(t0[0], t1[0], t2[0]))


@wp.func
def grid_cell(cell: int, ny: int, nz: int):
    """Indices ``(i, j, k)`` of the row-major linear index ``cell`` of an ``(nx, ny, nz)`` grid."""
    return cell // (ny * nz), (cell // nz) % ny, cell % nz


@wp.func
def gauss_seidel_point(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                       kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                       kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                       i: int, j: int, k: int):
    """Solve cell ``(i, j, k)``'s equation for its ``x`` from its neighbours' (per channel;
    a cell without coupling or absorption keeps 0)."""
    off, diag = neighbours(x, i, j, k, kx, ky, kz)
    diag += absorb[i, j, k]
    v = wp.vec3(0.0)
    for c in range(3):
        if diag[c] > 0.0:
            v[c] = (b[i, j, k][c] + off[c]) / diag[c]
    x[i, j, k] = v


@wp.func
def neighbours(x: wp.array3d(dtype=wp.vec3), i: int, j: int, k: int,
               kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
               kz: wp.array3d(dtype=wp.vec3)):
    """Off-diagonal sum ``sum k_f x_nbr`` and ``sum k_f`` over the interior faces of a cell."""
    off = wp.vec3(0.0)
    diag = wp.vec3(0.0)
    if i > 0:
        c = kx[i - 1, j, k]
        off += wp.cw_mul(c, x[i - 1, j, k])
        diag += c
    if i < x.shape[0] - 1:
        c = kx[i, j, k]
        off += wp.cw_mul(c, x[i + 1, j, k])
        diag += c
    if j > 0:
        c = ky[i, j - 1, k]
        off += wp.cw_mul(c, x[i, j - 1, k])
        diag += c
    if j < x.shape[1] - 1:
        c = ky[i, j, k]
        off += wp.cw_mul(c, x[i, j + 1, k])
        diag += c
    if k > 0:
        c = kz[i, j, k - 1]
        off += wp.cw_mul(c, x[i, j, k - 1])
        diag += c
    if k < x.shape[2] - 1:
        c = kz[i, j, k]
        off += wp.cw_mul(c, x[i, j, k + 1])
        diag += c
    return off, diag


# --- kernels -------------------------------------------------------------------------------------
@wp.kernel
def medium_kernel(sigma: wp.array3d(dtype=wp.float32), color_sigma: wp.array3d(dtype=wp.vec3),
                  albedo: float, g: float, sigma_a: wp.array3d(dtype=wp.vec3),
                  sigma_tr: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3)):
    """``sigma_a = sigma_t - sigma_s`` and ``sigma_tr = sigma_t - g sigma_s`` at ``wp.tid()``,
    and ``absorb = sigma_a`` (the box faces' cells get their leakage with the coefficients).

    ``sigma_s = albedo * color_sigma`` (RGB, 1/world units), clamped to ``sigma_t``.
    """
    i, j, k = wp.tid()
    st = sigma[i, j, k]
    ss = albedo * color_sigma[i, j, k]
    ss = wp.vec3(wp.min(ss[0], st), wp.min(ss[1], st), wp.min(ss[2], st))
    sa = wp.vec3(st) - ss
    sigma_a[i, j, k] = sa
    absorb[i, j, k] = sa
    sigma_tr[i, j, k] = wp.vec3(st) - g * ss


@wp.func
def leak_at(phi: wp.array3d(dtype=wp.vec3), sigma_tr: wp.array3d(dtype=wp.vec3), p: wp.vec3i,
            h: wp.vec3, d_max: float, limiter: int):
    """Marshak leakage ``b = sum_box faces 2 D / ((4 D + h_a) h_a)`` of cell ``p``.

    Zero for interior cells (1/world units).
    """
    out = wp.vec3(0.0)
    on_box = False
    for a in range(3):
        if p[a] == 0 or p[a] == phi.shape[a] - 1:
            on_box = True
    if on_box:
        d = limited_vec(sigma_tr[p[0], p[1], p[2]], gradient_sq(phi, p, h), phi[p[0], p[1], p[2]],
                        d_max, limiter)
        for a in range(3):
            faces = float(0.0)
            if p[a] == 0:
                faces += 1.0
            if p[a] == phi.shape[a] - 1:
                faces += 1.0
            if faces > 0.0:
                ha = h[a]
                out += faces * wp.vec3(2.0 * d[0] / ((4.0 * d[0] + ha) * ha),
                                       2.0 * d[1] / ((4.0 * d[1] + ha) * ha),
                                       2.0 * d[2] / ((4.0 * d[2] + ha) * ha))
    return out


def _face_kernel(axis: int):
    """The lagged coefficient ``k = D_f / h_axis^2`` of every face between a point ``p``
    and its ``+axis`` neighbour ``q``, a thread per face, ``wp.tid() = p``.

    Face means of ``sigma_tr`` and ``phi``; face gradient from the two points (normal) and
    the mean of their central differences along the two tangential axes (one-sided at the
    box faces, 0 on a grid one point thick). ``inv_h``: ``1 / h`` per axis.

    One kernel per axis, the axis a compile-time constant: with a run-time axis (one launch
    for the three faces and the leakage) every offset and spacing was a select, the
    kernel spilled at its 64-register cap (Nsight Compute, H100, 128³: 9.1 M local-memory
    requests, a third of its stalls) and took ~1400 instructions a thread; a branch per
    literal axis inside one kernel inlined all four bodies (14.1 ms instead of 8.6 for the
    Vortex teaser edit's 72 launches).
    """
    t0 = 1 if axis == 0 else 0  # the tangential axes, in increasing order
    t1 = 1 if axis == 2 else 2
    normal = wp.vec3i(*(int(a == axis) for a in range(3)))
    across0 = wp.vec3i(*(int(a == t0) for a in range(3)))
    across1 = wp.vec3i(*(int(a == t1) for a in range(3)))

    def face_coefficients(phi: wp.array3d(dtype=wp.vec3), sigma_tr: wp.array3d(dtype=wp.vec3),
                          k: wp.array3d(dtype=wp.vec3), inv_h: wp.vec3, d_max: float,
                          limiter: int):
        i, j, l = wp.tid()
        p = wp.vec3i(i, j, l)
        q = p + wp.static(normal)
        a = phi[p[0], p[1], p[2]]
        b = phi[q[0], q[1], q[2]]
        inv_ha = inv_h[wp.static(axis)]
        g = (b - a) * inv_ha
        grad_sq = wp.cw_mul(g, g)
        g = tangential_difference(phi, p, q, wp.static(across0), p[wp.static(t0)],
                                  phi.shape[wp.static(t0)], inv_h[wp.static(t0)])
        grad_sq += wp.cw_mul(g, g)
        g = tangential_difference(phi, p, q, wp.static(across1), p[wp.static(t1)],
                                  phi.shape[wp.static(t1)], inv_h[wp.static(t1)])
        grad_sq += wp.cw_mul(g, g)
        s = 0.5 * (sigma_tr[p[0], p[1], p[2]] + sigma_tr[q[0], q[1], q[2]])
        d = limited_vec(s, grad_sq, 0.5 * (a + b), d_max, limiter)
        k[i, j, l] = d * (inv_ha * inv_ha)

    return capped_kernel(COEFFICIENT_REGISTERS, name=f"face_coefficients_{axis}",
                         module="unique")(face_coefficients)


@wp.func
def tangential_difference(phi: wp.array3d(dtype=wp.vec3), p: wp.vec3i, q: wp.vec3i,
                          e: wp.vec3i, c: int, n: int, inv_h: float):
    """``d phi / dx_t`` at the face between points ``p`` and ``q`` (neighbours across the
    face, at the same index ``c`` along the tangential axis ``t``, unit vector ``e``, ``n``
    points): the mean of their central differences, one-sided at the box faces and 0 on a
    grid one point thick (the neighbours' indices clamped, no branch)."""
    lo = c - wp.max(c - 1, 0)
    hi = wp.min(c + 1, n - 1) - c
    pl = p - lo * e
    ph = p + hi * e
    ql = q - lo * e
    qh = q + hi * e
    diff = (phi[ph[0], ph[1], ph[2]] - phi[pl[0], pl[1], pl[2]]) + (phi[qh[0], qh[1], qh[2]]
                                                                   - phi[ql[0], ql[1], ql[2]])
    steps = lo + hi
    return diff * (wp.where(steps == 2, 0.25, wp.where(steps == 1, 0.5, 0.0)) * inv_h)


#: :func:`_face_kernel` per axis.
FACE_KERNELS = tuple(_face_kernel(a) for a in range(3))


def box_face_cells(shape) -> int:
    """Number of cells of a grid of ``shape`` on its box faces (:func:`box_face_cell`)."""
    nx, ny, nz = (int(n) for n in shape)
    ix, iy = max(nx - 2, 0), max(ny - 2, 0)
    return min(nx, 2) * ny * nz + min(ny, 2) * ix * nz + min(nz, 2) * ix * iy


@wp.func
def box_face_cell(t: int, nx: int, ny: int, nz: int):
    """The ``t``-th cell on the box faces of an ``(nx, ny, nz)`` grid, each once: the two
    x faces whole, then the y faces without their x edges, then the z faces without any
    edge (``t < box_face_cells``)."""
    i = int(0)
    j = int(0)
    k = int(0)
    ix = wp.max(nx - 2, 0)
    n_x = wp.min(nx, 2) * ny * nz
    n_y = wp.min(ny, 2) * ix * nz
    if t < n_x:
        f = t // (ny * nz)
        r = t - f * ny * nz
        i = f * (nx - 1)
        j = r // nz
        k = r - j * nz
    elif t < n_x + n_y:
        u = t - n_x
        f = u // (ix * nz)
        r = u - f * ix * nz
        i = 1 + r // nz
        j = f * (ny - 1)
        k = r - (i - 1) * nz
    else:
        iy = wp.max(ny - 2, 0)
        u = t - n_x - n_y
        f = u // (ix * iy)
        r = u - f * ix * iy
        i = 1 + r // iy
        j = 1 + r - (i - 1) * iy
        k = f * (nz - 1)
    return i, j, k


@capped_kernel(COEFFICIENT_REGISTERS)
def leakage_kernel(phi: wp.array3d(dtype=wp.vec3), sigma_tr: wp.array3d(dtype=wp.vec3),
                   sigma_a: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                   h: wp.vec3, d_max: float, limiter: int):
    """``absorb = sigma_a`` plus the box faces' leakage at box-face cell ``wp.tid()``
    (:func:`box_face_cell`): the part of the diagonal that couples to no neighbour (one
    array for the smoother and the residuals to read instead of two). Inside the box it
    is ``sigma_a``, set with the medium.

    Only the box-face cells are launched: over the whole grid, every warp holding one of
    a row's two end cells ran the limiter for it (half the warps at 128³), and the launch
    took as long as a face kernel (68 µs, H100)."""
    i, j, k = box_face_cell(wp.tid(), phi.shape[0], phi.shape[1], phi.shape[2])
    absorb[i, j, k] = sigma_a[i, j, k] + leak_at(phi, sigma_tr, wp.vec3i(i, j, k), h, d_max,
                                                  limiter)


@wp.kernel
def red_black_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                     kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                     kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                     color: int):
    """Gauss–Seidel update of the points with ``(i + j + k) % 2 == color``.

    ``wp.tid() = (i, j, kk)``; the point is ``k = 2 kk + ((i + j + color) % 2)``.
    """
    i, j, kk = wp.tid()
    k = 2 * kk + (i + j + color) % 2
    if k >= x.shape[2]:
        return
    gauss_seidel_point(x, b, kx, ky, kz, absorb, i, j, k)


@wp.kernel
def residual_field_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                          r: wp.array3d(dtype=wp.vec3), kx: wp.array3d(dtype=wp.vec3),
                          ky: wp.array3d(dtype=wp.vec3), kz: wp.array3d(dtype=wp.vec3),
                          absorb: wp.array3d(dtype=wp.vec3)):
    """``r = b - A x`` at point ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    off, diag = neighbours(x, i, j, k, kx, ky, kz)
    diag += absorb[i, j, k]
    r[i, j, k] = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + off


@wp.kernel
def residual_restrict_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                             bc: wp.array3d(dtype=wp.vec3), kx: wp.array3d(dtype=wp.vec3),
                             ky: wp.array3d(dtype=wp.vec3), kz: wp.array3d(dtype=wp.vec3),
                             absorb: wp.array3d(dtype=wp.vec3), ratio: wp.vec3i):
    """Coarse right-hand side at coarse cell ``wp.tid()``: the mean residual ``b - A x`` of
    its children (``restrict_kernel`` of ``residual_field_kernel``'s values, without the
    residual field in between)."""
    ci, cj, ck = wp.tid()
    s = wp.vec3(0.0)
    count = float(0.0)
    shape = wp.vec3i(x.shape[0], x.shape[1], x.shape[2])
    for child in range(8):
        i, j, k, ok = child_of(ci, cj, ck, ratio, child, shape)
        if ok:
            off, diag = neighbours(x, i, j, k, kx, ky, kz)
            diag += absorb[i, j, k]
            s += b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + off
            count += 1.0
    bc[ci, cj, ck] = s / count


@wp.kernel
def counted_kernel(sigma_tr: wp.array3d(dtype=wp.vec3), min_sigma: float,
                   counted: wp.array3d(dtype=wp.uint8)):
    """``counted = 1`` where :func:`near_medium` (the cells of the residual norms), else 0:
    set once per medium, so that the norms of every outer iteration read a byte per cell
    instead of up to seven ``sigma_tr``."""
    i, j, k = wp.tid()
    counted[i, j, k] = wp.uint8(0)
    if near_medium(sigma_tr, i, j, k, min_sigma):
        counted[i, j, k] = wp.uint8(1)


@wp.kernel
def residual_norm_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                         kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                         kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                         counted: wp.array3d(dtype=wp.uint8), acc: wp.array(dtype=wp.float64),
                         block: int):
    """Add ``sum_i |(b - A x) / diag(A)|^2`` to ``acc[0:3]`` and ``sum_i max(|x|, |b| /
    diag(A))^2`` to ``acc[3:6]``, over the medium and its face neighbours (the cells
    marked in ``counted``, :func:`counted_kernel`).

    Tiled launch: block ``wp.tid()[0]`` sums :data:`NORM_CHUNK` runs of ``block``
    consecutive cells (one per lane, coalesced), reduces over the block and adds once.
    """
    blk, lane = wp.tid()
    ny = x.shape[1]
    nz = x.shape[2]
    cells = x.shape[0] * ny * nz
    s = wp.vec3(0.0)
    m = wp.vec3(0.0)
    for run in range(NORM_CHUNK):
        cell = (blk * NORM_CHUNK + run) * block + lane
        if cell < cells:
            i, j, k = grid_cell(cell, ny, nz)
            if counted[i, j, k] != wp.uint8(0):
                off, diag = neighbours(x, i, j, k, kx, ky, kz)
                diag += absorb[i, j, k]
                xi = x[i, j, k]
                r = b[i, j, k] - wp.cw_mul(diag, xi) + off
                for c in range(3):
                    if diag[c] > 0.0:
                        e = r[c] / diag[c]
                        v = wp.max(wp.abs(xi[c]), wp.abs(b[i, j, k][c]) / diag[c])
                        s[c] = s[c] + e * e
                        m[c] = m[c] + v * v
    add_block_channels(acc, 0, s, lane)
    add_block_channels(acc, 3, m, lane)


@wp.kernel
def difference_kernel(a: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                      out: wp.array3d(dtype=wp.vec3)):
    i, j, k = wp.tid()
    out[i, j, k] = a[i, j, k] - b[i, j, k]


@wp.kernel
def anderson_dots_kernel(g: wp.array3d(dtype=wp.vec3), x: wp.array3d(dtype=wp.vec3),
                         f: wp.array3d(dtype=wp.vec3), f0: wp.array3d(dtype=wp.vec3),
                         f1: wp.array3d(dtype=wp.vec3), f2: wp.array3d(dtype=wp.vec3),
                         f3: wp.array3d(dtype=wp.vec3), acc: wp.array(dtype=wp.float64),
                         block: int):
    """``f = g - x`` (``f`` is one of the four history slots ``f0 .. f3``) and
    ``acc[j] += <f, f_j>`` (all cells and channels) for every slot; tiled like
    :func:`residual_norm_kernel`."""
    blk, lane = wp.tid()
    ny = x.shape[1]
    nz = x.shape[2]
    cells = x.shape[0] * ny * nz
    d = wp.vec4(0.0)
    for run in range(NORM_CHUNK):
        cell = (blk * NORM_CHUNK + run) * block + lane
        if cell < cells:
            i, j, k = grid_cell(cell, ny, nz)
            v = g[i, j, k] - x[i, j, k]
            f[i, j, k] = v  # before the reads below: f is also one of f0 .. f3
            d = d + wp.vec4(wp.dot(v, f0[i, j, k]), wp.dot(v, f1[i, j, k]),
                            wp.dot(v, f2[i, j, k]), wp.dot(v, f3[i, j, k]))
    d0 = wp.tile_sum(wp.tile(d[0]))
    d1 = wp.tile_sum(wp.tile(d[1]))
    d2 = wp.tile_sum(wp.tile(d[2]))
    d3 = wp.tile_sum(wp.tile(d[3]))
    if lane == 0:
        wp.atomic_add(acc, 0, wp.float64(d0[0]))
        wp.atomic_add(acc, 1, wp.float64(d1[0]))
        wp.atomic_add(acc, 2, wp.float64(d2[0]))
        wp.atomic_add(acc, 3, wp.float64(d3[0]))


@wp.kernel
def anderson_weights_kernel(dots: wp.array(dtype=wp.float64), gram: wp.array2d(dtype=wp.float64),
                            valid: wp.array(dtype=wp.int32), slot: int, max_weight: float,
                            alpha: wp.array(dtype=wp.float32),
                            work: wp.array2d(dtype=wp.float64)):
    """Anderson mixing weights (one thread): enter ``dots = <F_slot, F_j>`` into the Gram
    matrix, then ``alpha`` over the slots in the history (``valid``) minimising
    ``||sum_j alpha_j F_j||`` with ``sum_j alpha_j = 1``: ``alpha = w / sum(w)`` with
    ``(Gram + 1e-10 tr(Gram) I) w = 1`` (Gaussian elimination with partial pivoting, in
    float64). A singular or non-finite system, or a weight beyond ``max_weight`` (an
    ill-conditioned history), gives the plain step (``alpha = e_slot``) and restarts the
    history from ``slot``. ``work`` is scratch of ``(slots + 1, slots + 1)``: the history's
    slots in row 0, the augmented system below.
    """
    nslots = gram.shape[0]
    finite = int(1)
    for j in range(nslots):
        d = dots[j]
        gram[slot, j] = d
        gram[j, slot] = d
        if not wp.isfinite(d):
            finite = 0
        alpha[j] = wp.float32(0.0)
    alpha[slot] = wp.float32(1.0)
    valid[slot] = 1
    # slots in the history: work[0, 0 .. n-1] (their order does not change the solution)
    n = int(0)
    trace = wp.float64(0.0)
    for j in range(nslots):
        if valid[j] != 0:
            work[0, n] = wp.float64(j)
            trace += gram[j, j]
            n += 1
    if n < 2 or finite == 0:
        return
    reg = wp.float64(1.0e-10) * wp.max(trace, wp.float64(1.0e-300))
    # the augmented system [A | 1] in work[1 ..][0 .. n], row a of A in work[1 + a]
    for a in range(n):
        ja = int(work[0, a])
        for b in range(n):
            v = gram[ja, int(work[0, b])]
            if a == b:
                v += reg
            work[1 + a, b] = v
        work[1 + a, n] = wp.float64(1.0)
    ok = int(1)
    for c in range(n):
        pivot = c
        for r in range(c + 1, n):
            if wp.abs(work[1 + r, c]) > wp.abs(work[1 + pivot, c]):
                pivot = r
        if work[1 + pivot, c] == wp.float64(0.0) or not wp.isfinite(work[1 + pivot, c]):
            ok = 0
        if ok != 0:
            if pivot != c:
                for b in range(n + 1):
                    t = work[1 + c, b]
                    work[1 + c, b] = work[1 + pivot, b]
                    work[1 + pivot, b] = t
            for r in range(c + 1, n):
                f = work[1 + r, c] / work[1 + c, c]
                for b in range(c, n + 1):
                    work[1 + r, b] = work[1 + r, b] - f * work[1 + c, b]
    total = wp.float64(0.0)
    if ok != 0:
        for cc in range(n):  # back substitution, w into column n
            c = n - 1 - cc
            v = work[1 + c, n]
            for b in range(c + 1, n):
                v -= work[1 + c, b] * work[1 + b, n]
            work[1 + c, n] = v / work[1 + c, c]
            total += work[1 + c, n]
        if total == wp.float64(0.0) or not wp.isfinite(total):
            ok = 0
    if ok != 0:
        for a in range(n):
            wa = work[1 + a, n] / total
            if not wp.isfinite(wa) or wp.abs(wa) > wp.float64(max_weight):
                ok = 0
    if ok != 0:
        alpha[slot] = wp.float32(0.0)
        for a in range(n):
            alpha[int(work[0, a])] = wp.float32(work[1 + a, n] / total)
    else:
        for j in range(nslots):  # restart the history from this step
            valid[j] = 0
        valid[slot] = 1


@wp.kernel
def anderson_mix_kernel(g0: wp.array3d(dtype=wp.vec3), g1: wp.array3d(dtype=wp.vec3),
                        g2: wp.array3d(dtype=wp.vec3), g3: wp.array3d(dtype=wp.vec3),
                        alpha: wp.array(dtype=wp.float32), out: wp.array3d(dtype=wp.vec3)):
    """``out = sum_j alpha_j g_j`` (slots with weight 0 are not read)."""
    i, j, k = wp.tid()
    v = wp.vec3(0.0)
    if alpha[0] != 0.0:
        v += alpha[0] * g0[i, j, k]
    if alpha[1] != 0.0:
        v += alpha[1] * g1[i, j, k]
    if alpha[2] != 0.0:
        v += alpha[2] * g2[i, j, k]
    if alpha[3] != 0.0:
        v += alpha[3] * g3[i, j, k]
    out[i, j, k] = v


@wp.kernel
def coarse_relax_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                        kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                        kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                        sweeps: int, block: int):
    """``sweeps`` red–black Gauss–Seidel sweeps in one thread block (tiled launch of
    one block of ``block`` lanes; lane ``l`` updates cells ``l, l + block, ...``).

    When every cell has its own lane (the coarsest grid on CUDA), each lane keeps its
    cell's coefficients and right-hand side in registers and reads only the neighbours'
    ``x`` per sweep (the same update as the general loop, summed in another order).
    """
    _blk, lane = wp.tid()
    nx = x.shape[0]
    ny = x.shape[1]
    nz = x.shape[2]
    cells = nx * ny * nz
    if cells <= block:  # uniform over the block: the barriers below are reached by all
        owned = lane < cells
        i = int(0)
        j = int(0)
        k = int(0)
        cxm = wp.vec3(0.0)
        cxp = wp.vec3(0.0)
        cym = wp.vec3(0.0)
        cyp = wp.vec3(0.0)
        czm = wp.vec3(0.0)
        czp = wp.vec3(0.0)
        diag = wp.vec3(0.0)
        rhs = wp.vec3(0.0)
        color = int(-1)
        if owned:
            i, j, k = grid_cell(lane, ny, nz)
            if i > 0:
                cxm = kx[i - 1, j, k]
            if i < nx - 1:
                cxp = kx[i, j, k]
            if j > 0:
                cym = ky[i, j - 1, k]
            if j < ny - 1:
                cyp = ky[i, j, k]
            if k > 0:
                czm = kz[i, j, k - 1]
            if k < nz - 1:
                czp = kz[i, j, k]
            diag = cxm + cxp + cym + cyp + czm + czp + absorb[i, j, k]
            rhs = b[i, j, k]
            color = (i + j + k) % 2
        for _sweep in range(sweeps):
            for c2 in range(2):
                if color == c2:
                    off = wp.vec3(0.0)
                    if i > 0:
                        off += wp.cw_mul(cxm, x[i - 1, j, k])
                    if i < nx - 1:
                        off += wp.cw_mul(cxp, x[i + 1, j, k])
                    if j > 0:
                        off += wp.cw_mul(cym, x[i, j - 1, k])
                    if j < ny - 1:
                        off += wp.cw_mul(cyp, x[i, j + 1, k])
                    if k > 0:
                        off += wp.cw_mul(czm, x[i, j, k - 1])
                    if k < nz - 1:
                        off += wp.cw_mul(czp, x[i, j, k + 1])
                    v = wp.vec3(0.0)
                    for c in range(3):
                        if diag[c] > 0.0:
                            v[c] = (rhs[c] + off[c]) / diag[c]
                    x[i, j, k] = v
                wp.tile_sum(wp.tile(1.0))  # block barrier
        return
    for _sweep in range(sweeps):
        for color in range(2):
            cell = lane
            while cell < cells:
                i, j, k = grid_cell(cell, ny, nz)
                if (i + j + k) % 2 == color:
                    gauss_seidel_point(x, b, kx, ky, kz, absorb, i, j, k)
                cell += block
            # Block barrier (a block-wide reduction synchronises): the next colour reads
            # what this one wrote.
            wp.tile_sum(wp.tile(1.0))


@wp.kernel
def displaced_source_kernel(q: wp.array3d(dtype=wp.vec3), px: wp.array3d(dtype=wp.vec3),
                            py: wp.array3d(dtype=wp.vec3), pz: wp.array3d(dtype=wp.vec3),
                            h: wp.vec3, rhs: wp.array3d(dtype=wp.vec3)):
    """``rhs = Q - div(p)`` at cell ``wp.tid()``: the flux of the dipole density ``p``
    through each interior face is the face mean of ``p`` (none through the box faces).
    """
    i, j, k = wp.tid()
    out = q[i, j, k]
    if i < q.shape[0] - 1:
        out -= 0.5 * (px[i, j, k] + px[i + 1, j, k]) / h[0]
    if i > 0:
        out += 0.5 * (px[i, j, k] + px[i - 1, j, k]) / h[0]
    if j < q.shape[1] - 1:
        out -= 0.5 * (py[i, j, k] + py[i, j + 1, k]) / h[1]
    if j > 0:
        out += 0.5 * (py[i, j, k] + py[i, j - 1, k]) / h[1]
    if k < q.shape[2] - 1:
        out -= 0.5 * (pz[i, j, k] + pz[i, j, k + 1]) / h[2]
    if k > 0:
        out += 0.5 * (pz[i, j, k] + pz[i, j, k - 1]) / h[2]
    rhs[i, j, k] = out


@wp.kernel
def channel_sums_kernel(a: wp.array3d(dtype=wp.vec3), acc: wp.array(dtype=wp.float64),
                        block: int, squares: int):
    """Per channel, ``sum a^2`` into ``acc[0:3]`` (``squares`` 1), or ``sum a`` into
    ``acc[0:3]`` and ``sum max(a, 0)`` into ``acc[3:6]`` (``squares`` 0).

    Tiled like :func:`residual_norm_kernel`: a block's sums are added once. A thread per
    line of the grid (16k threads at 128³, three float64 atomic additions each to the same
    addresses) took 116-164 µs at 128³ on an H100.
    """
    blk, lane = wp.tid()
    ny = a.shape[1]
    nz = a.shape[2]
    cells = a.shape[0] * ny * nz
    s = wp.vec3(0.0)
    p = wp.vec3(0.0)
    for run in range(NORM_CHUNK):
        cell = (blk * NORM_CHUNK + run) * block + lane
        if cell < cells:
            i, j, k = grid_cell(cell, ny, nz)
            v = a[i, j, k]
            if squares != 0:
                s += wp.cw_mul(v, v)
            else:
                s += v
                p += wp.vec3(wp.max(v[0], 0.0), wp.max(v[1], 0.0), wp.max(v[2], 0.0))
    add_block_channels(acc, 0, s, lane)
    if squares == 0:  # the same for every lane of the block
        add_block_channels(acc, 3, p, lane)


@wp.kernel
def clip_rescale_kernel(a: wp.array3d(dtype=wp.vec3), acc: wp.array(dtype=wp.float64)):
    """``a = max(a, 0) * sum(a) / sum(max(a, 0))`` per channel at ``wp.tid()``."""
    i, j, k = wp.tid()
    v = a[i, j, k]
    out = wp.vec3(0.0)
    for c in range(3):
        pos = float(acc[3 + c])
        if pos > 0.0 and v[c] > 0.0:
            out[c] = v[c] * float(acc[c]) / pos
    a[i, j, k] = out


@wp.kernel
def negate_kernel(a: wp.array3d(dtype=wp.vec3)):
    """``a = -a`` at ``wp.tid()``."""
    i, j, k = wp.tid()
    a[i, j, k] = -a[i, j, k]
