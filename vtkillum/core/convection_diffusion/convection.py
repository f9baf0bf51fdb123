"""Convection–absorption of one light through the light volume (Zhang & Ma 2013, §4.1–4.5, §5.4).

What is convected
-----------------
Per light we solve for the *transmittance* ``T(x)`` from the light to ``x``: the
steady state of eq. 12 with unit boundary value,

    u(x) . grad T(x) = -sigma(x) T(x),        T = 1 where light enters,

``u`` the unit travel direction of the light at ``x`` (constant for a
directional light, ``(x - x_P) / |x - x_P|`` for a point light) and ``sigma`` the
grey extinction ``sigma_t`` (1/world units). The light's irradiance multiplies
``T`` afterwards (composition, eq. 22): ``E`` for a directional light,
``I / d**2`` for a point light. This differs from the paper on purpose: eq. 2 of
the paper drops the divergence of ``u``, so a convected point-light energy density
does not fall off with distance and the paper needs an ad-hoc Gaussian falloff
``G`` on the boundary (eqs. 8, 14). Transmittance is constant along a ray in
vacuum for any light, so convecting ``T`` and applying the exact inverse-square
law analytically is both simpler and physically right: the paper's
``G(x, x_P) rho_P`` becomes ``I / max(d, r_s)**2`` (``r_s`` the source radius).

Absorption uses ``sigma_t``, not ``sigma_a``: ``T`` is the transmittance of the
*unscattered* light, so that with no diffusion the light volume is exactly the
single-scattering fluence ``sum_l T_l E_l`` of the project's convention
(:mod:`vtkillum.core.illumination`), opaque walls block light whatever their
albedo, and a homogeneous slab gives ``exp(-sigma_t x)``. The diffusion step
then spreads this light (see :mod:`~vtkillum.core.convection_diffusion.diffusion`).

Boundary conditions (eqs. 6–11, 14–15)
--------------------------------------
* Dirichlet ``T = 1`` on the faces through which light enters: a face whose
  outward normal ``n`` has ``n . u < 0`` (directional, eq. 6) or
  ``n . (x - x_P) < 0`` with the light beyond that face (point light outside,
  eq. 8). Outside the box is vacuum.
* Outflow faces need no condition: the stencils never read across them. This
  *is* the zero-gradient (Neumann) condition of eqs. 7, 9, 10 for an upwind
  scheme.
* Point lights: points closer than the source radius ``r_s`` to the light are a
  Dirichlet region (eqs. 11, 14, 15; the paper's ``r_s = 2 dx``) with
  ``T = exp(-sigma(x) d)``, the transmittance through a locally homogeneous
  medium (the paper's ``rho_P``, i.e. ``T = 1``, in vacuum).

Discretisations (``scheme``)
----------------------------
``"upwind"`` — the paper's first-order upwind differences (eqs. 17–20) on the
light grid (spacing ``h_a`` per axis). At steady state, one equation per point:

    sum_a w_a (T_p - T_up(a)) + sigma_p T_p = 0,    w_a = |u_a| / h_a,

i.e. ``T_p = sum_a w_a T_up(a) / (sum_a w_a + sigma_p)``, ``up(a)`` the neighbour
one step against the light along axis ``a``.

``"exponential"`` — the same stencil with exponential fitting: the factor
``1 / (1 + sigma Δs)`` becomes ``exp(-sigma Δs)``, ``Δs = 1 / sum_a w_a`` being the
distance from ``p`` back along ``-u`` to the plane through its upwind neighbours:
``T_p = exp(-sigma_p Δs) sum_a w_a T_up(a) / sum_a w_a``. The plain factor lets
``1 / (1 + sigma h)`` through an opaque point (10 % for ``sigma h = 9``, a one-voxel
wall on a half-resolution light grid, where ``exp(-9) = 0.01 %`` is right). It is
the upwind system with ``sigma' = (exp(sigma Δs) - 1) / Δs``.

``"characteristics"`` (default) — short characteristics: follow the ray from
``p`` back towards the light to where it first crosses a grid plane (at distance
``t = min_a h_a / |u_a|``), interpolate ``T`` bilinearly there from the four
upstream points of that plane, and attenuate over ``t`` with the trapezoidal
mean extinction: ``T_p = T(q) exp(-t (sigma_p + sigma(q)) / 2)``. Same upstream
points (plus one diagonal), but far less crosswind smearing: the mean error of
``T`` against ray-marched transmittance is about half the upwind scheme's on a
smoke plume, and exact for axis-aligned and for 45° light in homogeneous media.

All three keep ``0 <= T <= 1`` and are exact for axis-aligned light in homogeneous
media except ``"upwind"`` (first order: ``(1 + sigma h)^-i``).

The one-sweep solution
----------------------
The paper reaches the steady state by explicit time stepping (eq. 16, CFL 1/2),
"4–5 iterations per layer". But every point depends only on upstream points, so
the system is triangular: visiting points in an order where each comes after
its upstream points solves it *exactly in one pass*. A single layer along the
dominant axis is not such an order for oblique light (a point also depends on
its in-layer neighbours, which is why the paper iterates each layer). The order
used here is by *wavefronts*: with ``r_a(i) = max(i - hi_a, lo_a - i, 0)`` the
index distance from the light along axis ``a`` (``lo_a = hi_a`` = the inflow face
for a directional light; ``lo_a, hi_a`` = floor/ceil of the light's grid
coordinate for a point light), an upstream point has ``r`` one less on every axis
it steps along, so all points with ``m = r_x + r_y + r_z`` depend only on points
with smaller ``m``. One launch per wavefront ``m = 0, 1, ...`` updates all its
points in parallel. For an axis-aligned light the wavefronts are exactly the
paper's layers. :func:`convect_light_iterated` implements the paper's iteration
(Jacobi sweeps for ``"characteristics"``), which converges to the same numbers
(tested).

A directional light's short characteristics need fewer launches: every point
interpolates in the grid plane one step back along the same axis ``d``, the one
with the largest ``|u_a| / h_a``, so the layers along ``d`` are such an order
after all: ``n_d`` launches instead of ``n_x + n_y + n_z - 2`` wavefronts (the
sweep is bound by its launches' latency, not by its work). The upwind stencils
read their in-layer neighbours and keep the wavefronts, and so do point lights,
whose ``d`` changes from point to point.

For point lights, the grid planes that straddle the light (``lo_a <= i <= hi_a``)
take no upstream step along ``a``: their upwind neighbour would lie on the other
side of the light, and keeping it would make the two planes depend on each
other. There ``|u_a| < h_a / d``, so the dropped term is small away from the source
region. Directional components below ``1e-6`` are treated as zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from vtkillum.core.graphs import array_key
from vtkillum.core.lights import DIRECTIONAL, POINT
from vtkillum.core.warp_common import (
    axis_offset,
    cached_tables,
    capped_kernel,
    component,
    grid_index,
    grid_point,
)

#: Direction components smaller than this are treated as exactly zero.
PARALLEL_EPS = 1.0e-6
POINT_KIND = wp.constant(POINT)

#: Discretisations, see the module docstring.
SCHEMES = {"upwind": 0, "exponential": 1, "characteristics": 2}
EXPONENTIAL = wp.constant(1)
CHARACTERISTICS = wp.constant(2)
#: Largest optical depth of one step evaluated in the exponential (beyond: T = 0 anyway).
MAX_STEP_DEPTH = wp.constant(80.0)
#: Register cap of the sweep kernel on CUDA: uncapped it takes 166, one block per SM, and a
#: launch of five lights' lines runs in ten waves (H100, 128³, five lights with their
#: δ-Eddington beams: 5.07 ms uncapped, 3.30 with 64, 3.44 with 48, 3.79 with 128).
SWEEP_REGISTERS = 64


@dataclass
class SweepPlan:
    """Geometry of one light's sweep over a light grid (all in grid indices).

    Attributes
    ----------
    lo, hi : (3,) int
        Per axis, the index range ``[lo, hi]`` of points with no upwind neighbour along
        that axis (``r_a = 0``).
    inflow : (3,) int
        Per axis, the index of the Dirichlet inflow face, or -1 when light does not
        enter through a face normal to that axis.
    primary : int
        Axis along which each thread walks: the one with most wavefronts, or with
        ``layers`` the axis of the layers.
    wavefronts : int
        Number of launches: wavefronts ``max(m) + 1``, or layers.
    layers : bool
        Sweep layer by layer along ``primary`` (a directional light's short
        characteristics, see the module docstring), not by wavefronts.
    """

    lo: np.ndarray
    hi: np.ndarray
    inflow: np.ndarray
    primary: int
    wavefronts: int
    layers: bool = False


def sweep_plan(kind: int, vec, shape, spacing, scheme: str = "characteristics") -> SweepPlan:
    """Sweep order for one light (see the module docstring).

    Parameters
    ----------
    kind : int
        ``DIRECTIONAL`` or ``POINT`` (:mod:`vtkillum.core.lights`).
    vec : (3,) float
        Travel direction (directional) or position (point), in the local frame.
    shape : (3,) int
        Light-grid points per axis.
    spacing : (3,) float
        Light-grid spacing (world units).
    scheme : str
        The discretisation (:data:`SCHEMES`): only short characteristics sweep a
        directional light by layers.
    """
    n = np.asarray(shape, dtype=np.int64)
    vec = np.asarray(vec, dtype=np.float64)
    lo = np.zeros(3, np.int64)
    hi = np.zeros(3, np.int64)
    inflow = -np.ones(3, np.int64)
    for a in range(3):
        if kind == DIRECTIONAL:
            if vec[a] > PARALLEL_EPS:
                lo[a] = hi[a] = inflow[a] = 0
            elif vec[a] < -PARALLEL_EPS:
                lo[a] = hi[a] = inflow[a] = n[a] - 1
            else:
                lo[a], hi[a] = 0, n[a] - 1
        elif kind == POINT:
            c = vec[a] / spacing[a]
            lo[a] = int(np.clip(np.floor(c), 0, n[a] - 1))
            hi[a] = int(np.clip(np.ceil(c), 0, n[a] - 1))
            if c < 0:
                inflow[a] = 0
            elif c > n[a] - 1:
                inflow[a] = n[a] - 1
        else:
            raise ValueError(f"unknown light kind {kind!r}")
    rmax = np.maximum(n - 1 - hi, lo)
    if kind == DIRECTIONAL and _scheme_id(scheme) == SCHEMES["characteristics"]:
        # the characteristics' axis, as the kernel ranks it (float32), which it is then given
        u32 = np.abs(vec.astype(np.float32))
        c = [u32[a] / np.float32(spacing[a]) if abs(vec[a]) > PARALLEL_EPS else np.float32(0)
             for a in range(3)]
        d = int(np.argmax(c))  # the first of equal ones, like the kernel
        return SweepPlan(lo, hi, inflow, d, int(rmax[d]) + 1, layers=True)
    return SweepPlan(lo, hi, inflow, int(np.argmax(rmax)), int(rmax.sum()) + 1)


def convect_light(sigma: wp.array3d, spacing, kind: int, vec, source_radius: float = 0.0,
                  out: wp.array3d | None = None, scheme: str = "characteristics",
                  graphs=None, second=None) -> wp.array3d:
    """Steady-state upwind transmittance of one light, exactly, in one ordered sweep.

    Parameters
    ----------
    sigma : warp.array3d of float32
        Extinction at the light-grid points (1/world units), indexed ``[i, j, k]``.
    spacing : (3,) float
        Light-grid spacing (world units).
    kind : int
        ``DIRECTIONAL`` or ``POINT``.
    vec : (3,) float
        Travel direction (directional, need not be normalised) or position (point), in
        the volume's local frame (world units).
    source_radius : float
        Point lights: radius of the Dirichlet source region ``T = 1`` (eq. 15).
    out : warp.array3d of float32, optional
        Where to write (same shape and device as ``sigma``); allocated when omitted.
    scheme : str
        ``"characteristics"`` (default), ``"exponential"`` or ``"upwind"`` (the paper's).
    graphs : vtkillum.core.graphs.LaunchGraphs, optional
        Replay the sweep (one launch per wavefront or layer) from a captured graph,
        recorded once per light, grid and arrays.
    second : (warp.array3d, warp.array3d), optional
        ``(sigma2, out2)``: convect the same light through a second extinction field in
        the same launches (the δ-Eddington beams of the physical model): the sweep is
        bound by its launches' latency, so the second field costs almost nothing.

    Returns
    -------
    warp.array3d of float32
        Transmittance ``T`` in [0, 1] at every light-grid point.
    """
    shape = tuple(sigma.shape)
    if out is None:
        out = wp.empty(shape, dtype=wp.float32, device=sigma.device)
    paired = None
    if second is not None:
        sigma2, out2 = second
        if tuple(out2.shape) != shape:
            raise ValueError("the second field of a paired sweep must have the grid's shape")
        paired = (sigma2, out2.reshape((1, *shape)))
    convect_lights(sigma, spacing, [(kind, vec)], out.reshape((1, *shape)), [0],
                   source_radius, scheme, graphs, paired)
    return out


def convect_lights(sigma: wp.array3d, spacing, lights, out: wp.array4d, slots,
                   source_radius: float = 0.0, scheme: str = "characteristics", graphs=None,
                   second=None) -> None:
    """:func:`convect_light` for several lights in the same launches.

    Wavefront (or layer) ``m`` of every light is one launch, so ``n`` lights cost about
    as much as the one with most (the sweep is bound by its launches' latency). A
    launch has a thread per line along each light's ``primary`` axis, per side of the
    light and per field (with ``second``): a thread updates one point.

    Parameters
    ----------
    sigma, spacing, source_radius, scheme, graphs
        As :func:`convect_light`.
    lights : sequence of (kind, vec)
        ``kind`` ``DIRECTIONAL`` or ``POINT``, ``vec`` as for :func:`convect_light`.
    out : warp.array4d of float32
        ``(slots, nx, ny, nz)``: light ``n`` writes ``out[slots[n]]``.
    slots : sequence of int
        Distinct slots of ``out``, one per light.
    second : (warp.array3d, warp.array4d), optional
        ``(sigma2, out2)``: each light also through ``sigma2`` into ``out2[slot]``.
    """
    shape = tuple(sigma.shape)
    device = sigma.device
    scheme_id = _scheme_id(scheme)
    spacing = np.asarray(spacing, dtype=np.float64)
    if tuple(out.shape[1:]) != shape or len(set(slots)) != len(slots):
        raise ValueError("convect_lights: out must be (slots, *grid) and the slots distinct")
    plans, vecs = [], []
    for kind, vec in lights:
        vec = _light_vector(kind, vec)
        plans.append(sweep_plan(kind, vec, shape, spacing, scheme))
        vecs.append(vec.astype(np.float32))
    if not plans:
        return
    dims = [[shape[a] for a in range(3) if a != p.primary] for p in plans]
    # a thread per (light, field and side of the light, line): one point each
    parts = 4 if second is not None else 2
    dim = (len(plans), parts, max(d[0] for d in dims), max(d[1] for d in dims))
    wavefronts = max(p.wavefronts for p in plans)
    sigma2, out2 = second if second is not None else (sigma, out)
    if tuple(sigma2.shape) != shape or tuple(out2.shape) != tuple(out.shape):
        raise ValueError("the second field of a paired sweep must have the grid's shape")

    key = ("convect-batch", tuple((int(k), tuple(v.tolist())) for (k, _), v in zip(lights, vecs)),
           tuple(int(i) for i in slots), tuple(spacing.astype(np.float32).tolist()),
           float(source_radius), scheme_id, second is not None) + array_key(sigma, out, sigma2,
                                                                           out2)
    if graphs is not None and graphs.recorded(key):
        graphs.run(key, None)  # the tables below live in the recording
        return

    def table(values, dtype):
        return wp.array(np.asarray(values), dtype=dtype, device=device)

    # the tables depend on the lights, slots, spacing (key[1:4]), grid shape and scheme
    params = cached_tables(("convect-tables", str(device), shape, scheme_id) + key[1:4], lambda: [
        table(list(slots), int), table([p.primary for p in plans], int),
        table([int(p.layers) for p in plans], int),
        table([p.lo for p in plans], wp.vec3i), table([p.hi for p in plans], wp.vec3i),
        table([p.inflow for p in plans], wp.vec3i),
        table([int(k) for k, _ in lights], int), table(vecs, wp.vec3)])
    h32 = spacing.astype(np.float32)

    def sweep():
        cmd = wp.launch(batched_sweep_kernel, dim=dim, device=device, record_cmd=True,
                        inputs=[sigma, out, 0, *params, wp.vec3(*h32), float(source_radius),
                                scheme_id, sigma2, out2])
        for m in range(wavefronts):
            cmd.set_param_at_index(2, m)
            cmd.launch()

    if graphs is None:
        sweep()
    else:  # the recording reads the tables: the key holds their content, the graph them
        graphs.run(key, sweep, keep=params)


def convect_light_iterated(sigma: wp.array3d, spacing, kind: int, vec, source_radius: float = 0.0,
                           max_iterations: int = 100000, tolerance: float = 1e-7,
                           initial: wp.array3d | None = None, check_every: int = 16,
                           scheme: str = "characteristics"):
    """The paper's scheme: explicit upwind time steps (eq. 16) until the steady state.

    Every point is advanced by ``c dt = min(h) / 2`` (the paper's CFL number 1/2) per
    iteration, with the same stencil and boundary handling as :func:`convect_light`;
    absorption is treated implicitly per step, ``T <- (T - c dt sum_a w_a (T - T_up)) /
    (1 + c dt sigma)``, which is stable for any ``sigma`` and has the same fixed point
    (with ``sigma'`` of the module docstring for ``scheme="exponential"``). Short
    characteristics have no time-dependent form; for them each iteration is a Jacobi
    sweep of the steady equations (exact after as many sweeps as there are wavefronts).
    Used to verify the one-sweep solution and to count the iterations it saves.

    Parameters
    ----------
    sigma, spacing, kind, vec, source_radius, scheme
        As :func:`convect_light`.
    max_iterations : int
        Upper bound on time steps.
    tolerance : float
        Stop when the largest change of ``T`` in one step is below this.
    initial : warp.array3d, optional
        Starting field (e.g. the previous time step's solution); zeros inside,
        boundary values applied, when omitted (the paper's initialisation, §5.3).
    check_every : int
        Steps between convergence checks (each costs a device-to-host copy).

    Returns
    -------
    T : warp.array3d of float32
    iterations : int
        Time steps taken.
    """
    shape = tuple(sigma.shape)
    device = sigma.device
    scheme_id = _scheme_id(scheme)
    vec = np.asarray(vec, dtype=np.float64)
    if kind == DIRECTIONAL:
        vec = vec / np.linalg.norm(vec)
    spacing = np.asarray(spacing, dtype=np.float64)
    plan = sweep_plan(kind, vec, shape, spacing)
    cur = wp.zeros(shape, dtype=wp.float32, device=device) if initial is None else wp.clone(initial)
    nxt = wp.empty_like(cur)
    change = wp.zeros(1, dtype=wp.float32, device=device)
    dt = 0.5 * float(spacing.min())
    common = [wp.vec3i(*plan.lo), wp.vec3i(*plan.hi), wp.vec3i(*plan.inflow), int(kind),
              wp.vec3(*vec.astype(np.float32)), wp.vec3(*spacing.astype(np.float32)),
              float(source_radius), scheme_id, dt]
    it = 0
    while it < max_iterations:
        change.zero_()
        wp.launch(upwind_step_kernel, dim=shape, device=device,
                  inputs=[sigma, cur, nxt, *common, change])
        cur, nxt = nxt, cur
        it += 1
        if it % check_every == 0 or it == max_iterations:
            if float(change.numpy()[0]) < tolerance:
                break
    return cur, it


def _light_vector(kind: int, vec) -> np.ndarray:
    """A directional light's unit travel direction, or a point light's position."""
    vec = np.asarray(vec, dtype=np.float64)
    if kind == DIRECTIONAL:
        norm = np.linalg.norm(vec)
        if norm == 0:
            raise ValueError("a directional light needs a non-zero direction")
        vec = vec / norm
    return vec


def _scheme_id(scheme: str) -> int:
    if scheme not in SCHEMES:
        raise ValueError(f"unknown convection scheme {scheme!r}; choose one of {sorted(SCHEMES)}")
    return SCHEMES[scheme]


# --- device functions ----------------------------------------------------------------------------
@wp.func
def wavefront_distance(i: int, lo: int, hi: int):
    """Index distance from the no-upwind range ``[lo, hi]`` along one axis."""
    return wp.max(wp.max(i - hi, lo - i), 0)


@wp.func
def light_direction_at(kind: int, vec: wp.vec3, x: wp.vec3):
    """Unit travel direction at ``x`` and distance to a point light (0 for directional)."""
    if kind == POINT_KIND:
        d = x - vec
        dist = wp.length(d)
        if dist > 0.0:
            return d / dist, dist
        return wp.vec3(0.0, 0.0, 0.0), 0.0
    return vec, 0.0


@wp.func
def boundary_value(idx: wp.vec3i, inflow: wp.vec3i, kind: int, dist: float, source_radius: float,
                   sigma: float):
    """Dirichlet value at a boundary point, or -1 for an interior point.

    Inflow faces get 1 (vacuum outside); a point light's source region gets the
    transmittance ``exp(-sigma d)`` through a locally homogeneous medium.
    """
    if kind == POINT_KIND and dist <= source_radius:
        return wp.exp(-wp.min(sigma * dist, MAX_STEP_DEPTH))
    if idx[0] == inflow[0] or idx[1] == inflow[1] or idx[2] == inflow[2]:
        return 1.0
    return -1.0


@wp.func
def effective_sigma(sigma: float, den: float, scheme: int):
    """Absorption in the upwind equation: ``sigma``, or ``sigma'`` for exponential fitting."""
    if scheme == EXPONENTIAL:
        return den * (wp.exp(wp.min(sigma / den, MAX_STEP_DEPTH)) - 1.0)
    return sigma


@wp.func
def upwind_sums(T: wp.array3d(dtype=wp.float32), idx: wp.vec3i, u: wp.vec3, h: wp.vec3,
                lo: wp.vec3i, hi: wp.vec3i):
    """``sum_a w_a T_up(a)`` and ``sum_a w_a`` over the axes with an upwind neighbour."""
    i = idx[0]
    j = idx[1]
    k = idx[2]
    num = float(0.0)
    den = float(0.0)
    w = wp.abs(u[0]) / h[0]
    if i > hi[0]:
        num += w * T[i - 1, j, k]
        den += w
    elif i < lo[0]:
        num += w * T[i + 1, j, k]
        den += w
    w = wp.abs(u[1]) / h[1]
    if j > hi[1]:
        num += w * T[i, j - 1, k]
        den += w
    elif j < lo[1]:
        num += w * T[i, j + 1, k]
        den += w
    w = wp.abs(u[2]) / h[2]
    if k > hi[2]:
        num += w * T[i, j, k - 1]
        den += w
    elif k < lo[2]:
        num += w * T[i, j, k + 1]
        den += w
    return num, den


@wp.func
def upstream_step(i: int, lo: int, hi: int):
    """+1 if the upwind neighbour is at ``i - 1``, -1 if at ``i + 1``, 0 if there is none."""
    if i > hi:
        return 1
    if i < lo:
        return -1
    return 0


@wp.func
def characteristic_value(sigma: wp.array3d(dtype=wp.float32), T: wp.array3d(dtype=wp.float32),
                         idx: wp.vec3i, u: wp.vec3, h: wp.vec3, lo: wp.vec3i, hi: wp.vec3i,
                         dominant: int):
    """Short characteristic: ``T`` interpolated where the ray back towards the light first
    crosses a grid plane, times the transmittance of that step (trapezoidal ``sigma``).

    ``dominant``: the axis of that plane when the sweep's order relies on it (a
    directional light swept by layers), or -1 to find it here."""
    s = wp.vec3i(upstream_step(idx[0], lo[0], hi[0]), upstream_step(idx[1], lo[1], hi[1]),
                 upstream_step(idx[2], lo[2], hi[2]))
    c = wp.vec3(wp.where(s[0] != 0, wp.abs(u[0]) / h[0], 0.0),
                wp.where(s[1] != 0, wp.abs(u[1]) / h[1], 0.0),
                wp.where(s[2] != 0, wp.abs(u[2]) / h[2], 0.0))
    # d, a, b are run-time axes: components by select (component)
    d = 0
    cd = c[0]
    if dominant >= 0:
        d = dominant
        cd = component(c, d)
    else:
        if c[1] > cd:
            d = 1
            cd = c[1]
        if c[2] > cd:
            d = 2
            cd = c[2]
    if cd <= 0.0:
        return 1.0  # no upstream point: the light's own cell
    t = 1.0 / cd
    a = (d + 1) % 3
    b = (d + 2) % 3
    fa = wp.min(component(c, a) * t, 1.0)
    fb = wp.min(component(c, b) * t, 1.0)
    p00 = idx - axis_offset(d, component(s, d))
    pa = axis_offset(a, component(s, a))
    pb = axis_offset(b, component(s, b))
    p10 = p00 - pa
    p01 = p00 - pb
    p11 = p10 - pb
    w00 = (1.0 - fa) * (1.0 - fb)
    w10 = fa * (1.0 - fb)
    w01 = (1.0 - fa) * fb
    w11 = fa * fb
    tq = (w00 * T[p00[0], p00[1], p00[2]] + w10 * T[p10[0], p10[1], p10[2]]
          + w01 * T[p01[0], p01[1], p01[2]] + w11 * T[p11[0], p11[1], p11[2]])
    sq = (w00 * sigma[p00[0], p00[1], p00[2]] + w10 * sigma[p10[0], p10[1], p10[2]]
          + w01 * sigma[p01[0], p01[1], p01[2]] + w11 * sigma[p11[0], p11[1], p11[2]])
    depth = 0.5 * (sigma[idx[0], idx[1], idx[2]] + sq) * t
    return tq * wp.exp(-wp.min(depth, MAX_STEP_DEPTH))


@wp.func
def upwind_point(sigma: wp.array3d(dtype=wp.float32), T: wp.array3d(dtype=wp.float32),
                 idx: wp.vec3i, lo: wp.vec3i, hi: wp.vec3i, inflow: wp.vec3i, kind: int,
                 vec: wp.vec3, h: wp.vec3, source_radius: float, scheme: int, dominant: int):
    """Solve the steady upwind equation at one point from its (final) upwind neighbours
    (``dominant``: see :func:`characteristic_value`).

    A point without upwind neighbours (only the point light's own cell, when the
    source radius is smaller than the cell) is treated as a source point, T = 1.
    """
    x = wp.vec3(float(idx[0]) * h[0], float(idx[1]) * h[1], float(idx[2]) * h[2])
    u, dist = light_direction_at(kind, vec, x)
    s = sigma[idx[0], idx[1], idx[2]]
    value = boundary_value(idx, inflow, kind, dist, source_radius, s)
    if value < 0.0 and scheme == CHARACTERISTICS:
        value = characteristic_value(sigma, T, idx, u, h, lo, hi, dominant)
    elif value < 0.0:
        value = 1.0
        num, den = upwind_sums(T, idx, u, h, lo, hi)
        if den > 0.0:
            if scheme == EXPONENTIAL:
                value = num / den * wp.exp(-wp.min(s / den, MAX_STEP_DEPTH))
            else:
                value = num / (den + s)
    T[idx[0], idx[1], idx[2]] = value


# --- kernels -------------------------------------------------------------------------------------
@wp.func
def sweep_point(sigma: wp.array3d(dtype=wp.float32), T: wp.array3d(dtype=wp.float32), m: int,
                primary: int, layers: int, lo: wp.vec3i, hi: wp.vec3i, inflow: wp.vec3i,
                kind: int, vec: wp.vec3, h: wp.vec3, source_radius: float, scheme: int,
                side: int, a: int, b: int):
    """The point of line ``(a, b)`` (the non-primary axes in increasing order) in
    wavefront ``m`` on the light's ``side`` 0 (beyond ``hi``) or 1 (before ``lo``) along
    the primary axis, or side 0 the ``[lo, hi]`` range when ``m`` is reached there; with
    ``layers`` the points of layer ``m`` along the primary axis."""
    dominant = -1
    r_other = 0
    if layers != 0:
        dominant = primary
    else:
        base = grid_index(primary, 0, a, b)
        r_other = (wavefront_distance(base[0], lo[0], hi[0])
                   + wavefront_distance(base[1], lo[1], hi[1])
                   + wavefront_distance(base[2], lo[2], hi[2])
                   - wavefront_distance(0, component(lo, primary), component(hi, primary)))
    rp = m - r_other
    if rp < 0:
        return
    lp = component(lo, primary)
    hp = component(hi, primary)
    if rp == 0:
        if side == 0:
            for p in range(lp, hp + 1):
                upwind_point(sigma, T, grid_index(primary, p, a, b), lo, hi, inflow, kind, vec,
                             h, source_radius, scheme, dominant)
        return
    p = hp + rp
    if side == 1:
        p = lp - rp
    if p >= 0 and p < component(wp.vec3i(T.shape[0], T.shape[1], T.shape[2]), primary):
        upwind_point(sigma, T, grid_index(primary, p, a, b), lo, hi, inflow, kind, vec, h,
                     source_radius, scheme, dominant)


@capped_kernel(SWEEP_REGISTERS)
def batched_sweep_kernel(sigma: wp.array3d(dtype=wp.float32), T: wp.array4d(dtype=wp.float32),
                         m: int, slots: wp.array(dtype=int), primaries: wp.array(dtype=int),
                         layers: wp.array(dtype=int), los: wp.array(dtype=wp.vec3i),
                         his: wp.array(dtype=wp.vec3i), inflows: wp.array(dtype=wp.vec3i),
                         kinds: wp.array(dtype=int), vecs: wp.array(dtype=wp.vec3), h: wp.vec3,
                         source_radius: float, scheme: int, sigma2: wp.array3d(dtype=wp.float32),
                         T2: wp.array4d(dtype=wp.float32)):
    """Wavefront (or layer) ``m`` of several lights at once: ``wp.tid() = (job, part, a,
    b)``, light ``job`` writes ``T[slots[job]]`` (``part`` 0, 1: the two sides of the
    light) and ``T2[slots[job]]`` through ``sigma2`` (``part`` 2, 3), one point of line
    ``(a, b)`` each (:func:`sweep_point`; lines beyond the light's own grid face are
    skipped, and so are the wavefronts past its last)."""
    job, part, a, b = wp.tid()
    primary = primaries[job]
    first = 0
    if primary == 0:
        first = 1
    second = 2
    if primary == 2:
        second = 1
    shape = wp.vec3i(sigma.shape[0], sigma.shape[1], sigma.shape[2])
    if a >= component(shape, first) or b >= component(shape, second):
        return
    slot = slots[job]
    if part < 2:
        sweep_point(sigma, T[slot], m, primary, layers[job], los[job], his[job], inflows[job],
                    kinds[job], vecs[job], h, source_radius, scheme, part, a, b)
    else:
        sweep_point(sigma2, T2[slot], m, primary, layers[job], los[job], his[job],
                    inflows[job], kinds[job], vecs[job], h, source_radius, scheme, part - 2, a,
                    b)


@wp.kernel
def upwind_step_kernel(sigma: wp.array3d(dtype=wp.float32), T: wp.array3d(dtype=wp.float32),
                       T_next: wp.array3d(dtype=wp.float32), lo: wp.vec3i, hi: wp.vec3i,
                       inflow: wp.vec3i, kind: int, vec: wp.vec3, h: wp.vec3,
                       source_radius: float, scheme: int, dt: float,
                       change: wp.array(dtype=wp.float32)):
    """One explicit time step (eq. 16) at point ``wp.tid() = (i, j, k)``.

    ``dt`` is ``c * Δt`` in world units; ``change[0]`` receives the largest
    ``|T_next - T|`` (atomic max).
    """
    i, j, k = wp.tid()
    idx = wp.vec3i(i, j, k)
    x = grid_point(i, j, k, h)
    u, dist = light_direction_at(kind, vec, x)
    old = T[i, j, k]
    s = sigma[i, j, k]
    value = boundary_value(idx, inflow, kind, dist, source_radius, s)
    if value < 0.0 and scheme == CHARACTERISTICS:
        value = characteristic_value(sigma, T, idx, u, h, lo, hi, -1)  # explicit: Jacobi sweeps
    elif value < 0.0:
        value = 1.0
        num, den = upwind_sums(T, idx, u, h, lo, hi)
        if den > 0.0:
            value = (old + dt * (num - den * old)) / (1.0 + dt * effective_sigma(s, den, scheme))
    T_next[i, j, k] = value
    wp.atomic_max(change, 0, wp.abs(value - old))
