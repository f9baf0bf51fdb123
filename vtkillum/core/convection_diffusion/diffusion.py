"""Diffusion of the composed light volume (Zhang & Ma 2013, §5.6, eq. 23).

The equation and what "implicit" means
--------------------------------------
Eq. 23, ``dL/dt = sigma_hat_s laplace(L)`` per RGB channel with a pure Neumann
boundary, is integrated from the composed light ``L0`` (eq. 22) to ``t = 1`` with
one implicit (backward Euler) step of length 1, as the paper does with
Gauss–Seidel:

    (I - sigma_hat_s laplace) L = L0.

That one step *is* a steady-state problem, the screened Poisson equation, and
it has a physical reading: it is the steady diffusion approximation of multiple
scattering, ``-D laplace(phi) + sigma_a phi = S``, divided by ``sigma_a``, with
diffusion length ``l = sqrt(sigma_hat_s)``. Its Green's function is
``exp(-r / l) / (4 pi sigma_hat_s r)``, the diffusion-theory response to a point
source. So ``sigma_hat_s`` is an *area* (world units squared): the square of the
distance over which light spreads. For a medium with extinction ``sigma_t``,
albedo ``Λ`` and anisotropy ``g``, diffusion theory suggests
``sigma_hat_s = D / sigma_a = 1 / (3 sigma_t (1 - g Λ) sigma_t (1 - Λ))``
(:func:`diffusion_length_squared`). Several smaller explicit or implicit steps
would approach a Gaussian blur instead; the single step is cheaper and closer to
transport theory.

Discretisation
--------------
Finite volumes on the light grid, one control volume per grid point, 7-point
Laplacian with spacing ``h_a`` per axis; a missing neighbour beyond the box
contributes no flux (zero normal derivative). The matrix ``A = I + sum_a
sigma_hat_s / h_a**2 * (graph Laplacian along a)`` is symmetric positive definite
and its columns sum to 1, so ``sum(L) = sum(L0)`` exactly: diffusion moves light,
it never creates or destroys it. (The grid points stand for equal cells of size
``h``; trapezoid weights would not be conserved.)

Solvers (``method``)
--------------------
``"multigrid"`` (default)
    Geometric V(2,2) cycles with red–black Gauss–Seidel smoothing, cell-centred
    restriction and trilinear prolongation, an exact dense solve on the coarsest
    grid (:mod:`~vtkillum.core.convection_diffusion.multigrid`). Convergence per cycle is independent
    of the grid size and of ``sigma_hat_s``.
``"cg"``
    Conjugate gradients with the diagonal as preconditioner, per channel, all
    scalars kept on the device. Iterations grow like ``sqrt(sigma_hat_s) / h``.
``"gauss-seidel"``
    Red–black Gauss–Seidel (the paper's solver, in a parallel ordering).
    Iterations grow like ``sigma_hat_s / h**2``.
``"dct"``
    Exact direct solve on the host with numpy FFTs: the Neumann Laplacian is
    diagonal in the DCT-II basis. One "iteration"; used as the reference.

Iteration counts are V-cycles, CG iterations or red+black sweeps respectively;
``residuals`` holds the relative residual ``max_c ||b - A x||_c / ||b||_c`` before
the first and after every iteration.

Precision: light volumes are float32, and ``b - A x`` cancels about
``log10(cond A)`` digits, so the relative residual cannot go much below
``2 eps32 (1 + 2 max(sigma_hat_s) sum_a 1 / h_a**2)`` (:func:`residual_floor`). A requested
tolerance below that floor is raised to it, so that a solve with a long diffusion
length on a fine grid stops when it has done all it can instead of spinning to the
iteration cap.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.multigrid import Multigrid
from vtkillum.core.convection_diffusion.stencil import (
    add_channels,
    apply_operator_kernel,
    axis_coefficients,
    diagonal,
    gauss_seidel,
    neighbours,
    residual_norm_kernel,
    sum_squares_kernel,
)
from vtkillum.core.device import resolve_device
from vtkillum.core.graphs import LaunchGraphs, array_key
from vtkillum.core.warp_common import HostReader

SOLVERS = ("multigrid", "cg", "gauss-seidel", "dct")


@dataclass
class DiffusionReport:
    """What one call of :meth:`DiffusionSolver.solve` did.

    Attributes
    ----------
    iterations : int
        Iterations performed (V-cycles, CG iterations, red+black sweeps, or 1 for DCT).
    residuals : list of float
        Relative residual before the first and after each iteration.
    converged : bool
        Whether the last residual is at or below the tolerance.
    fallback : bool
        Physical model: the multigrid iteration diverged and the solve went back to its
        best iterate and on with Gauss–Seidel sweeps.
    stalled : bool
        Physical model: the residual stopped falling above the tolerance (the lagged flux
        limiter settles into a cycle whose residual no iteration lowers), so the solve
        stopped early; ``converged`` stays False.
    nested : bool
        Physical model: the solve started with nested iteration (a cold start, or a warm
        start corrected coarse to fine because it was far from the solution).
    """

    iterations: int = 0
    residuals: list = field(default_factory=list)
    converged: bool = False
    fallback: bool = False
    stalled: bool = False
    nested: bool = False


def residual_floor(scattering, spacing) -> float:
    """Smallest relative residual float32 arithmetic can show for this operator."""
    c = float(np.max(scattering)) * float(np.sum(1.0 / np.asarray(spacing, dtype=np.float64) ** 2))
    return 2.0 * float(np.finfo(np.float32).eps) * (1.0 + 2.0 * c)


def diffusion_length_squared(sigma_t: float, albedo: float, anisotropy: float = 0.0) -> float:
    """``sigma_hat_s = D / sigma_a`` of diffusion theory for a homogeneous medium (world units²).

    ``D = 1 / (3 sigma_t')`` with the reduced extinction ``sigma_t' = sigma_t (1 - g Λ)``
    and ``sigma_a = sigma_t (1 - Λ)``. Use it to pick ``scattering`` for a material;
    ``albedo = 1`` (no absorption) has an infinite diffusion length and is refused.
    """
    if not (sigma_t > 0 and 0 <= albedo < 1 and -1 < anisotropy < 1):
        raise ValueError("need sigma_t > 0, albedo in [0, 1) and anisotropy in (-1, 1)")
    return 1.0 / (3.0 * sigma_t * (1.0 - anisotropy * albedo) * sigma_t * (1.0 - albedo))


class DiffusionSolver:
    """Solve ``(I - sigma_hat_s laplace) x = b`` per RGB channel on one light grid.

    Parameters
    ----------
    shape : (3,) int
        Light-grid points per axis.
    spacing : (3,) float
        Light-grid spacing (world units).
    scattering : (3,) float
        ``sigma_hat_s`` per channel (world units², >= 0).
    method : str
        One of :data:`SOLVERS`.
    device : str, optional
        Warp device.
    """

    def __init__(self, shape, spacing, scattering, method: str = "multigrid",
                 device: str | None = None):
        if method not in SOLVERS:
            raise ValueError(f"unknown diffusion solver {method!r}; choose one of {SOLVERS}")
        s = np.asarray(scattering, dtype=np.float64).reshape(-1)
        if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s < 0):
            raise ValueError(
                f"scattering (sigma_hat_s) must be three non-negative numbers (world units², "
                f"one per RGB channel), got {scattering!r}"
            )
        self.shape = tuple(int(n) for n in shape)
        self.spacing = np.asarray(spacing, dtype=np.float64)
        self.scattering = s
        self.method = method
        self.device = resolve_device(device)
        self.coeffs = axis_coefficients(s, self.spacing)
        #: Relative residual below which float32 round-off dominates.
        self.floor = residual_floor(s, self.spacing)
        self._norms = wp.zeros(6, dtype=wp.float64, device=self.device)
        self._norms_host = HostReader(self._norms)  # read after every iteration
        self._work = {}
        self._multigrid = None
        #: Captured iterations (multigrid, Gauss-Seidel; :mod:`~vtkillum.core.graphs`).
        self.graphs = LaunchGraphs(self.device)
        if method == "multigrid":
            self._multigrid = Multigrid(self.shape, self.spacing, s, self.device)

    # --- public ----------------------------------------------------------------------------
    def solve(self, b: wp.array3d, x: wp.array3d, max_iterations: int = 100,
              tolerance: float = 1e-4, callback=None) -> DiffusionReport:
        """Improve ``x`` in place towards the solution for right-hand side ``b``.

        Parameters
        ----------
        b : warp.array3d of vec3
            The composed light ``L0`` (eq. 22).
        x : warp.array3d of vec3
            Initial guess (``b``, or a previous solution for a warm start); overwritten.
        max_iterations : int
            Iteration budget of this call (progressive refinement continues in the next).
        tolerance : float
            Stop once the relative residual is at or below this (or below
            :func:`residual_floor`, whichever is larger).
        callback : callable, optional
            ``callback(iteration, residual)`` after every iteration (progress reports).
        """
        self._check(b)
        self._check(x)
        tolerance = max(float(tolerance), self.floor)
        report = DiffusionReport()
        b_norm = self._b_norm(b)
        report.residuals.append(self.residual(x, b, b_norm))
        if not np.any(self.scattering > 0):  # A = I
            wp.copy(x, b)
            report.residuals.append(0.0)
            report.iterations, report.converged = 1, True
            return report
        if report.residuals[-1] <= tolerance:
            report.converged = True
            return report
        if self.method == "dct":
            x.assign(diffuse_dct(b.numpy(), self.scattering, self.spacing))
            report.iterations = 1
            report.residuals.append(self.residual(x, b, b_norm))
        elif self.method == "cg":
            self._cg(b, x, b_norm, max_iterations, tolerance, report, callback)
        else:
            step = self._multigrid.vcycle if self.method == "multigrid" else self._gs_sweep

            def iteration():  # replayed from a captured graph (vtkillum.core.graphs)
                step(x, b)
                self._launch_residual(x, b)

            for _ in range(int(max_iterations)):
                self.graphs.run((self.method,) + array_key(x, b), iteration)
                report.iterations += 1
                report.residuals.append(self._read_residual(b_norm))
                if callback is not None:
                    callback(report.iterations, report.residuals[-1])
                if report.residuals[-1] <= tolerance:
                    break
        report.converged = report.residuals[-1] <= tolerance
        return report

    def residual(self, x: wp.array3d, b: wp.array3d, b_norm=None) -> float:
        """Relative residual ``max_c ||b - A x||_c / ||b||_c`` (0 for a zero ``b``)."""
        if b_norm is None:
            b_norm = self._b_norm(b)
        self._launch_residual(x, b)
        return self._read_residual(b_norm)

    def _launch_residual(self, x: wp.array3d, b: wp.array3d) -> None:
        self._norms.zero_()
        wp.launch(residual_norm_kernel, dim=(self.shape[1], self.shape[2]), device=self.device,
                  inputs=[x, b, *self.coeffs, self._norms])

    def _read_residual(self, b_norm) -> float:
        r = np.sqrt(self._norms_host.read()[:3])
        return float(np.max(np.where(b_norm > 0, r / np.maximum(b_norm, 1e-300), 0.0)))

    def apply(self, x: wp.array3d, out: wp.array3d | None = None) -> wp.array3d:
        """``A x`` (for tests and diagnostics)."""
        out = wp.empty_like(x) if out is None else out
        wp.launch(apply_operator_kernel, dim=self.shape, device=self.device,
                  inputs=[x, out, *self.coeffs])
        return out

    # --- internals -------------------------------------------------------------------------
    def _check(self, a) -> None:
        if tuple(a.shape) != self.shape or a.dtype != wp.vec3:
            raise ValueError(f"expected a vec3 array of shape {self.shape}, got {a.dtype} {a.shape}")

    def _b_norm(self, b) -> np.ndarray:
        self._norms.zero_()
        wp.launch(sum_squares_kernel, dim=(self.shape[1], self.shape[2]), device=self.device,
                  inputs=[b, self._norms])
        return np.sqrt(self._norms_host.read()[:3])

    def _gs_sweep(self, x, b) -> None:
        gauss_seidel(x, b, self.coeffs, 1)

    def _buffers(self, *names):
        for name in names:
            if name not in self._work:
                self._work[name] = wp.empty(self.shape, dtype=wp.vec3, device=self.device)
        return [self._work[n] for n in names]

    def _cg(self, b, x, b_norm, max_iterations, tolerance, report, callback=None) -> None:
        r, z, p, q = self._buffers("r", "z", "p", "q")
        scal = wp.zeros(CG_SCALARS, dtype=wp.float64, device=self.device)
        lines = (self.shape[1], self.shape[2])
        wp.launch(cg_init_kernel, dim=lines, device=self.device,
                  inputs=[x, b, r, z, p, *self.coeffs, scal])
        wp.launch(cg_shift_kernel, dim=1, device=self.device, inputs=[scal])
        scale = 1.0 / np.maximum(b_norm, 1e-300)
        for _ in range(int(max_iterations)):
            wp.launch(matvec_dot_kernel, dim=lines, device=self.device,
                      inputs=[p, q, *self.coeffs, scal])
            wp.launch(cg_update_kernel, dim=lines, device=self.device,
                      inputs=[x, r, z, p, q, *self.coeffs, scal])
            wp.launch(cg_direction_kernel, dim=self.shape, device=self.device,
                      inputs=[z, p, scal])
            # The recursive residual r tracks b - A x up to round-off; its norm costs nothing.
            rr = np.sqrt(np.maximum(scal.numpy()[9:12], 0.0))
            wp.launch(cg_shift_kernel, dim=1, device=self.device, inputs=[scal])
            report.iterations += 1
            report.residuals.append(float(np.max(np.where(b_norm > 0, rr * scale, 0.0))))
            if callback is not None:
                callback(report.iterations, report.residuals[-1])
            if report.residuals[-1] <= tolerance:
                break
        report.residuals[-1] = self.residual(x, b, b_norm)


def diffuse_dct(b: np.ndarray, scattering, spacing) -> np.ndarray:
    """Exact solution of ``(I - sigma_hat_s laplace) x = b`` with numpy FFTs (host).

    The finite-volume Neumann Laplacian along an axis of ``n`` points has the DCT-II
    vectors ``cos(pi k (i + 1/2) / n)`` as eigenvectors, with eigenvalues
    ``-4 sin(pi k / (2 n))**2 / h**2``.

    Parameters
    ----------
    b : ndarray (nx, ny, nz, 3)
    scattering : (3,) float
    spacing : (3,) float

    Returns
    -------
    ndarray (nx, ny, nz, 3) float32
    """
    b = np.asarray(b, dtype=np.float64)
    s = np.asarray(scattering, dtype=np.float64)
    coef = dct2(dct2(dct2(b, 0), 1), 2)
    lam = np.zeros(b.shape[:3])
    for a, n in enumerate(b.shape[:3]):
        k = np.arange(n)
        ev = 4.0 * np.sin(np.pi * k / (2 * n)) ** 2 / float(spacing[a]) ** 2
        lam = lam + ev.reshape([-1 if i == a else 1 for i in range(3)])
    coef /= 1.0 + lam[..., None] * s
    return idct2(idct2(idct2(coef, 0), 1), 2).astype(np.float32)


def dct2(x: np.ndarray, axis: int) -> np.ndarray:
    """Unnormalised DCT-II ``X_k = sum_i x_i cos(pi k (2 i + 1) / (2 n))`` along ``axis``."""
    n = x.shape[axis]
    y = np.concatenate([x, np.flip(x, axis)], axis=axis)
    f = np.fft.rfft(y, axis=axis)
    f = np.take(f, np.arange(n), axis=axis)
    shape = [1] * x.ndim
    shape[axis] = n
    phase = np.exp(-0.5j * np.pi * np.arange(n) / n).reshape(shape)
    return 0.5 * np.real(f * phase)


def idct2(c: np.ndarray, axis: int) -> np.ndarray:
    """Inverse of :func:`dct2`."""
    n = c.shape[axis]
    shape = [1] * c.ndim
    shape[axis] = n
    phase = np.exp(0.5j * np.pi * np.arange(n) / n).reshape(shape)
    f = 2.0 * c * phase
    pad = [(0, 0)] * c.ndim
    pad[axis] = (0, 1)  # the Nyquist coefficient of the even extension is zero
    y = np.fft.irfft(np.pad(f, pad), n=2 * n, axis=axis)
    return np.take(y, np.arange(n), axis=axis)


# --- device functions ------------------------------------------------------------------------------
#: Layout of the CG scalars (float64): rz, pq, rz_new, rr, three channels each.
RZ = wp.constant(0)
PQ = wp.constant(3)
RZ_NEW = wp.constant(6)
RR = wp.constant(9)
CG_SCALARS = 12

@wp.func
def channel_ratio(acc: wp.array(dtype=wp.float64), num: int, den: int, c: int):
    d = acc[den + c]
    if d == wp.float64(0.0):
        return 0.0
    return float(acc[num + c] / d)


# --- kernels -----------------------------------------------------------------------------------------
@wp.kernel
def cg_init_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                   r: wp.array3d(dtype=wp.vec3), z: wp.array3d(dtype=wp.vec3),
                   p: wp.array3d(dtype=wp.vec3), cx: wp.vec3, cy: wp.vec3, cz: wp.vec3,
                   scal: wp.array(dtype=wp.float64)):
    """``r = b - A x``, ``z = p = D^-1 r``; adds ``r.z`` to ``RZ_NEW`` and ``r.r`` to ``RR``.

    ``wp.tid() = (j, k)`` is a line along x.
    """
    j, k = wp.tid()
    rz = wp.vec3(0.0)
    rr = wp.vec3(0.0)
    for i in range(x.shape[0]):
        off, diag = neighbours(x, i, j, k, cx, cy, cz)
        res = b[i, j, k] - wp.cw_mul(diag, x[i, j, k]) + off
        pre = wp.cw_div(res, diag)
        r[i, j, k] = res
        z[i, j, k] = pre
        p[i, j, k] = pre
        rz += wp.cw_mul(res, pre)
        rr += wp.cw_mul(res, res)
    add_channels(scal, RZ_NEW, rz)
    add_channels(scal, RR, rr)


@wp.kernel
def matvec_dot_kernel(p: wp.array3d(dtype=wp.vec3), q: wp.array3d(dtype=wp.vec3), cx: wp.vec3,
                      cy: wp.vec3, cz: wp.vec3, scal: wp.array(dtype=wp.float64)):
    """``q = A p`` along line ``wp.tid() = (j, k)``; adds ``p.q`` per channel to ``PQ``."""
    j, k = wp.tid()
    pq = wp.vec3(0.0)
    for i in range(p.shape[0]):
        off, diag = neighbours(p, i, j, k, cx, cy, cz)
        v = wp.cw_mul(diag, p[i, j, k]) - off
        q[i, j, k] = v
        pq += wp.cw_mul(p[i, j, k], v)
    add_channels(scal, PQ, pq)


@wp.kernel
def cg_update_kernel(x: wp.array3d(dtype=wp.vec3), r: wp.array3d(dtype=wp.vec3),
                     z: wp.array3d(dtype=wp.vec3), p: wp.array3d(dtype=wp.vec3),
                     q: wp.array3d(dtype=wp.vec3), cx: wp.vec3, cy: wp.vec3, cz: wp.vec3,
                     scal: wp.array(dtype=wp.float64)):
    """``x += α p``, ``r -= α q``, ``z = D^-1 r`` with ``α = rz / pq`` per channel.

    ``wp.tid() = (j, k)`` is a line along x; adds the new ``r.z`` to ``RZ_NEW`` and
    ``r.r`` to ``RR``.
    """
    j, k = wp.tid()
    alpha = wp.vec3(channel_ratio(scal, RZ, PQ, 0), channel_ratio(scal, RZ, PQ, 1),
                    channel_ratio(scal, RZ, PQ, 2))
    shape = wp.vec3i(x.shape[0], x.shape[1], x.shape[2])
    rz = wp.vec3(0.0)
    rr = wp.vec3(0.0)
    for i in range(x.shape[0]):
        x[i, j, k] = x[i, j, k] + wp.cw_mul(alpha, p[i, j, k])
        res = r[i, j, k] - wp.cw_mul(alpha, q[i, j, k])
        pre = wp.cw_div(res, diagonal(shape, i, j, k, cx, cy, cz))
        r[i, j, k] = res
        z[i, j, k] = pre
        rz += wp.cw_mul(res, pre)
        rr += wp.cw_mul(res, res)
    add_channels(scal, RZ_NEW, rz)
    add_channels(scal, RR, rr)


@wp.kernel
def cg_direction_kernel(z: wp.array3d(dtype=wp.vec3), p: wp.array3d(dtype=wp.vec3),
                        scal: wp.array(dtype=wp.float64)):
    """``p = z + β p`` with ``β = rz_new / rz`` per channel, at ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    beta = wp.vec3(channel_ratio(scal, RZ_NEW, RZ, 0), channel_ratio(scal, RZ_NEW, RZ, 1),
                   channel_ratio(scal, RZ_NEW, RZ, 2))
    p[i, j, k] = z[i, j, k] + wp.cw_mul(beta, p[i, j, k])


@wp.kernel
def cg_shift_kernel(scal: wp.array(dtype=wp.float64)):
    """Single thread: ``rz = rz_new``; clear the accumulators for the next iteration."""
    for c in range(3):
        scal[RZ + c] = scal[RZ_NEW + c]
        scal[RZ_NEW + c] = wp.float64(0.0)
        scal[PQ + c] = wp.float64(0.0)
        scal[RR + c] = wp.float64(0.0)
