"""Virtual lights: random walks from the real lights (paper sections 3.1–3.2, Algorithm 1).

A light path starts on a light, samples free-flight distances through the medium and
scatters at every collision until it leaves the volume's box or Russian roulette ends
it. Every collision vertex ``x_k`` becomes a virtual light (VL). The walk stores, per
vertex, its position and the *geometric* part of its sampling density; together with
the distance density (:mod:`~vtkillum.core.many_lights.contribution`) that is the full
density ``p(x_k | x_{k-1})`` in the volume measure, which is what eq. 6 needs to
re-weight a stored vertex after an edit.

Sampling, step by step (local frame, world units)

1. **Light.** Light ``l`` is chosen with probability ``P_l`` proportional to its power
   (directional: mean irradiance x the area of the box's projection onto the plane
   perpendicular to its travel direction; point: ``4 pi`` x mean intensity).
   Directional lights start on a rectangle bounding that projection, outside the box,
   with uniform density ``1 / A_l``; point lights emit uniformly in direction
   (``1 / (4 pi)``). Geometric density of the first vertex: ``P_l / A_l``
   (directional) or ``P_l / (4 pi t^2)`` (point, ``t`` its distance from the light),
   in the volume measure, because a light may move after the walk.
2. **Distance** along the ray, inside the box:

   * ``"ray-marching"`` (Algorithm 1): an optical-depth target ``-ln(1 - u)`` is
     accumulated along the ray on equal steps no longer than ``step`` and the crossing
     is located inside its step; ``sigma_t`` is taken linear between the step ends
     (trapezoid rule, crossing from the quadratic), where the paper adds up
     ``sigma(x) dt`` at the left points — first-order accurate, which puts collisions
     up to a step off in media whose mean free path is below a voxel (10 % less
     multiple scattering than the path tracer on a cloud of optical diameter 20 at 16³);
   * ``"delta-tracking"`` (Woodcock tracking, :func:`vtkillum.core.pathtrace.delta_tracking`):
     exact for the trilinear medium.

   Collisions are distributed as ``sigma_t(x) T(x_{k-1}, x)``; a path that reaches the
   box exit ends. With a *mixture* (eqs. 7–8, the global density scale ``S``) each
   segment is sampled with scale ``S_min`` or ``S_max`` with probability 1/2, so that
   distances follow the mean transmittance ``(T^S_min + T^S_max) / 2`` of eq. 8 exactly.
3. **Russian roulette** from the :data:`RR_START`-th vertex on: the walk goes on with
   probability ``q = clamp(rho, RR_MIN, 1)`` with ``rho`` the path throughput
   (product of ``albedo * max colour`` over the vertices, divided by the earlier
   ``q``). ``q`` never drops to 0 so that an albedo edit from 0 stays unbiased.
4. **Direction**: Henyey–Greenstein importance sampling with the scene's ``g``
   (density ``p_HG``), or uniform (``1 / (4 pi)``; section 5.2's "isotropic as the mean
   phase function" for interactive ``g`` edits). Geometric density of the next
   vertex: ``q * p(w)`` in the measure ``dw dt``. Stored vertices never move, so the
   ``1 / t^2`` of the volume measure cancels between the integrand and the density of
   every later vertex; leaving it out of both keeps a collision a float32 rounding away
   from its predecessor (delta tracking draws arbitrarily short flights) from turning
   into ``0 / 0``. The direction each segment was sampled with is stored too.

Random numbers: path ``p`` of a VL set draws from the PCG stream
``rand_init(seed, p)``, so a path can be traced twice (once to count its vertices,
once to write them) and *regenerated* after an edit with the very numbers a fresh set
would use. Paths are counted first (:func:`count_vertices`); the caller then places
them in a compact vertex array and writes them (:func:`write_vertices`).

Simplifications against the paper: the Russian-roulette weight is the standard
``1 / q`` (the paper's ``1 / (1 - T_path)+`` reads as a typo); a safety cap of
``max_vertices`` per path (:data:`MAX_PATH_VERTICES`) bounds walks in closed media of
albedo 1; capped walks are counted and reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.lights import DIRECTIONAL as HOST_DIRECTIONAL
from vtkillum.core.lights import pack_lights
from vtkillum.core.pathtrace import delta_tracking
from vtkillum.core.warp_common import (
    DIRECTIONAL,
    Lights,
    Medium,
    hg_phase,
    lookup_color,
    lookup_sigma_t,
    ray_box,
    sample_hg,
    sample_scalar,
    uniform,
)

#: Distance sampling by Algorithm 1 (ray marching) or by delta tracking.
SAMPLING = {"ray-marching": 0, "delta-tracking": 1}
MARCHED = wp.constant(0)
DELTA = wp.constant(1)
#: Russian roulette starts after this many vertices of a path.
RR_START = wp.constant(2)
#: Smallest survival probability of the roulette (keeps every continuation possible).
RR_MIN = wp.constant(0.05)
#: Safety cap on the vertices of one light path.
MAX_PATH_VERTICES = 4096
#: Salt of the per-set path seeds.
WALK_SALT = 0x3C6EF372


@wp.struct
class Sources:
    """How light paths start: per light its selection probability and emission geometry.

    ``pmf[l]``/``cdf[l]``: probability of light ``l`` and the cumulative sum up to it.
    Directional lights: origins ``start + a e1 + b e2`` with ``(a, b)`` uniform in
    ``rect = (a0, a1, b0, b1)`` of ``area`` (world units²), outside the box.
    """

    pmf: wp.array(dtype=wp.float32)
    cdf: wp.array(dtype=wp.float32)
    e1: wp.array(dtype=wp.vec3)
    e2: wp.array(dtype=wp.vec3)
    rect: wp.array(dtype=wp.vec4)
    area: wp.array(dtype=wp.float32)
    start: wp.array(dtype=wp.vec3)
    count: int


@wp.struct
class WalkParams:
    """Walk options: distance ``sampling`` (MARCHED or DELTA), ``mixture`` (1: pick the
    first or second medium with probability 1/2 per segment), ``isotropic`` direction
    sampling, HG ``g``, march ``step`` (world units), ``max_vertices`` per path."""

    seed: int
    sampling: int
    mixture: int
    isotropic: int
    g: float
    step: float
    max_vertices: int


@dataclass
class WalkSetup:
    """Everything a walk launch needs, on one device.

    Attributes
    ----------
    medium_a, medium_b : Medium
        The media distances are sampled in (equal unless a mixture is used: then the
        medium scaled by ``S_min`` and by ``S_max``).
    sources : Sources
    lights : Lights
    params : WalkParams
    device : str
    """

    medium_a: Medium
    medium_b: Medium
    sources: Sources
    lights: Lights
    params: WalkParams
    device: str


def count_vertices(setup: WalkSetup, first: int, n: int):
    """Trace paths ``first .. first + n - 1`` and count their vertices.

    Returns
    -------
    counts : ndarray (n,) int32
        Vertices (VLs) of each path.
    lights : ndarray (n,) int32
        Light each path started from.
    capped : int
        Paths that reached ``max_vertices`` while still alive.
    """
    n = int(n)
    if n <= 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int32), 0
    dev = setup.device
    counts = wp.zeros(n, dtype=wp.int32, device=dev)
    path_light = wp.zeros(n, dtype=wp.int32, device=dev)
    capped = wp.zeros(1, dtype=wp.int32, device=dev)
    dummy_pos = wp.zeros(1, dtype=wp.vec3, device=dev)
    dummy_geom = wp.zeros(1, dtype=wp.float32, device=dev)
    wp.launch(walk_kernel, dim=n,
              inputs=[setup.medium_a, setup.medium_b, setup.sources, setup.lights, setup.params,
                      int(first), 0, counts, counts, path_light, dummy_pos, dummy_geom,
                      dummy_pos, capped],
              device=dev)
    return counts.numpy(), path_light.numpy(), int(capped.numpy()[0])


def write_vertices(setup: WalkSetup, paths: np.ndarray, offsets: np.ndarray, total: int):
    """Trace the given paths again and write their vertices at ``offsets``.

    Parameters
    ----------
    paths : ndarray (n,) int
        Path indices (each must have been counted; their streams are deterministic).
    offsets : ndarray (n,) int
        First vertex of each path in the output arrays.
    total : int
        Length of the output arrays.

    Returns
    -------
    positions : wp.array(vec3) (total,)
        Vertex positions (local frame).
    geom : wp.array(float32) (total,)
        Geometric sampling density of each vertex (see the module docstring).
    incident : wp.array(vec3) (total,)
        Unit travel direction of the segment that arrived at each vertex.
    """
    dev = setup.device
    positions = wp.zeros(max(int(total), 1), dtype=wp.vec3, device=dev)
    geom = wp.zeros(max(int(total), 1), dtype=wp.float32, device=dev)
    incident = wp.zeros(max(int(total), 1), dtype=wp.vec3, device=dev)
    n = len(paths)
    if n == 0 or total == 0:
        return positions, geom, incident
    path_ids = wp.array(np.asarray(paths, np.int32), dtype=wp.int32, device=dev)
    offs = wp.array(np.asarray(offsets, np.int32), dtype=wp.int32, device=dev)
    path_light = wp.zeros(n, dtype=wp.int32, device=dev)
    capped = wp.zeros(1, dtype=wp.int32, device=dev)
    wp.launch(walk_kernel, dim=n,
              inputs=[setup.medium_a, setup.medium_b, setup.sources, setup.lights, setup.params,
                      0, 1, path_ids, offs, path_light, positions, geom, incident, capped],
              device=dev)
    return positions, geom, incident


def make_sources(lights, volume, device: str | None = None) -> tuple[Sources, np.ndarray]:
    """Selection probabilities and emission geometry of ``lights`` for ``volume``'s box.

    Returns
    -------
    sources : Sources
    power : ndarray (n_lights,) float64
        Emitted power of each light (mean over RGB; world units of the lights).
    """
    device = resolve_device(device)
    kinds, vecs, rgb = pack_lights(lights, volume.direction, volume.origin)
    extent = np.asarray(volume.extent, np.float64)
    centre = extent / 2
    reach = float(np.linalg.norm(extent)) + 1e-3 * float(extent.max())
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) * extent
    n = len(kinds)
    e1 = np.zeros((n, 3))
    e2 = np.zeros((n, 3))
    rect = np.zeros((n, 4))
    area = np.zeros(n)
    start = np.zeros((n, 3))
    power = np.zeros(n)
    for li in range(n):
        mean = float(np.mean(rgb[li]))
        if kinds[li] == HOST_DIRECTIONAL:
            w = vecs[li].astype(np.float64)
            w /= np.linalg.norm(w)
            a, b = _basis(w)
            pa, pb = (corners - centre) @ a, (corners - centre) @ b
            e1[li], e2[li] = a, b
            rect[li] = (pa.min(), pa.max(), pb.min(), pb.max())
            area[li] = (pa.max() - pa.min()) * (pb.max() - pb.min())
            start[li] = centre - reach * w
            power[li] = mean * area[li]
        else:
            power[li] = 4.0 * np.pi * mean
    total = power.sum()
    pmf = power / total if total > 0 else np.zeros(n)
    cdf = np.cumsum(pmf)
    if total > 0:
        cdf[-1] = 1.0
    s = Sources()
    s.pmf = wp.array(pmf.astype(np.float32), dtype=wp.float32, device=device)
    s.cdf = wp.array(cdf.astype(np.float32), dtype=wp.float32, device=device)
    s.e1 = wp.array(e1.astype(np.float32), dtype=wp.vec3, device=device)
    s.e2 = wp.array(e2.astype(np.float32), dtype=wp.vec3, device=device)
    s.rect = wp.array(rect.astype(np.float32), dtype=wp.vec4, device=device)
    s.area = wp.array(np.maximum(area, 1e-30).astype(np.float32), dtype=wp.float32, device=device)
    s.start = wp.array(start.astype(np.float32), dtype=wp.vec3, device=device)
    s.count = n
    return s, power


def walk_params(seed: int, sampling: str, mixture: bool, isotropic: bool, g: float, step: float,
                max_vertices: int = MAX_PATH_VERTICES) -> WalkParams:
    """A :class:`WalkParams` (``seed`` is the set's stream seed, see the module docstring)."""
    if sampling not in SAMPLING:
        raise ValueError(f"distance_sampling must be one of {sorted(SAMPLING)}, got {sampling!r}")
    p = WalkParams()
    p.seed = int(seed)
    p.sampling = SAMPLING[sampling]
    p.mixture = int(bool(mixture))
    p.isotropic = int(bool(isotropic))
    p.g = float(g)
    p.step = float(step)
    p.max_vertices = int(max_vertices)
    return p


def _basis(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(w, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(w, a)


# --- device functions ---------------------------------------------------------------------------
@wp.func
def march_distance(m: Medium, o: wp.vec3, d: wp.vec3, t_start: float, t_end: float,
                   step: float, target: float):
    """Algorithm 1: the first ``t`` in ``(t_start, t_end)`` where the optical depth from
    ``t_start`` reaches ``target``; returns ``(hit, t)``.

    ``sigma_t`` is sampled at the ends of equal segments no longer than ``step`` and taken
    as linear in between (trapezoid rule), and the crossing is located exactly in that
    piecewise-linear medium (a quadratic in the segment). Second-order accurate: the
    paper's left-point sum puts collisions up to a step away from where a sharp edge is,
    which biases dense media whose mean free path is below a voxel.
    """
    length = t_end - t_start
    if length <= 0.0:
        return False, t_end
    n = int(wp.ceil(length / step))
    h = length / float(n)
    tau = float(0.0)
    s0 = lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing, o + t_start * d))
    for k in range(n):
        s1 = lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing,
                                             o + (t_start + float(k + 1) * h) * d))
        dt = 0.5 * (s0 + s1) * h
        if dt > 0.0 and tau + dt >= target:
            # tau(s) = s0 s + (s1 - s0) s^2 / (2h) = r, solved in its cancellation-free form.
            r = target - tau
            disc = wp.max(s0 * s0 + 2.0 * (s1 - s0) * r / h, 0.0)
            s = wp.min(2.0 * r / wp.max(s0 + wp.sqrt(disc), 1.0e-30), h)
            return True, t_start + float(k) * h + s
        tau += dt
        s0 = s1
    return False, t_end


@wp.func
def sample_distance(m: Medium, o: wp.vec3, d: wp.vec3, t_start: float, t_end: float,
                    sampling: int, step: float, state: wp.uint32):
    """A collision on ``o + t d`` distributed as ``sigma_t T`` (or none before ``t_end``).

    Returns ``(hit, t, state)``.
    """
    if sampling == DELTA:
        hit, t, _s, state = delta_tracking(m, o, d, t_start, t_end, state)
        return hit, t, state
    u, state = uniform(state)
    hit, t = march_distance(m, o, d, t_start, t_end, step, -wp.log(1.0 - u))
    return hit, t, state


@wp.func
def uniform_sphere(u1: float, u2: float):
    """A unit vector uniform on the sphere (density ``1 / (4 pi)``)."""
    z = 1.0 - 2.0 * u1
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    phi = 2.0 * wp.pi * u2
    return wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)


@wp.func
def choose_light(src: Sources, u: float):
    """Index of the light whose cumulative probability interval holds ``u``."""
    li = int(0)
    while li < src.count - 1 and u >= src.cdf[li]:
        li += 1
    return li


# --- kernel -------------------------------------------------------------------------------------
@wp.kernel
def walk_kernel(ma: Medium, mb: Medium, src: Sources, lights: Lights, prm: WalkParams,
                first: int, write: int, paths: wp.array(dtype=wp.int32),
                offsets: wp.array(dtype=wp.int32), path_light: wp.array(dtype=wp.int32),
                out_pos: wp.array(dtype=wp.vec3), out_geom: wp.array(dtype=wp.float32),
                out_dir: wp.array(dtype=wp.vec3), capped: wp.array(dtype=wp.int32)):
    """Trace one light path.

    ``wp.tid()`` indexes the launched paths. Counting (``write == 0``): path
    ``first + tid``, its vertex count goes to ``offsets[tid]`` (the ``paths`` argument
    is unused). Writing (``write == 1``): path ``paths[tid]``, its vertices go to
    ``out_pos``/``out_geom``/``out_dir`` from ``offsets[tid]`` on. Positions in the local
    frame (world units); ``out_geom`` is the geometric density (see the module
    docstring); ``out_dir`` the unit direction the vertex was reached along.
    ``path_light[tid]`` gets the light index; ``capped[0]`` counts walks cut by
    ``max_vertices``.
    """
    i = wp.tid()
    p = first + i
    if write != 0:
        p = paths[i]
    state = wp.rand_init(prm.seed, p)
    u, state = uniform(state)
    li = choose_light(src, u)
    path_light[i] = li
    n = int(0)
    pl = float(0.0)
    if src.count > 0:
        pl = src.pmf[li]
    if pl > 0.0:
        u1, state = uniform(state)
        u2, state = uniform(state)
        o = wp.vec3(0.0)
        w = wp.vec3(0.0)
        geom = float(0.0)
        point = int(1)
        if lights.kind[li] == DIRECTIONAL:
            point = 0
            w = lights.vec[li]
            r = src.rect[li]
            o = src.start[li] + (r[0] + u1 * (r[1] - r[0])) * src.e1[li] + (
                r[2] + u2 * (r[3] - r[2])) * src.e2[li]
            geom = pl / src.area[li]
        else:
            o = lights.vec[li]
            w = uniform_sphere(u1, u2)
            geom = pl / (4.0 * wp.pi)
        tt = ray_box(o, w, ma.extent)
        t_start = wp.max(tt[0], 0.0)
        t_end = tt[1]
        rho = float(1.0)
        alive = int(1)
        while alive != 0 and n < prm.max_vertices:
            if t_end <= t_start:
                alive = 0
                break
            use_b = int(0)
            if prm.mixture != 0:
                um, state = uniform(state)
                if um >= 0.5:
                    use_b = 1
            hit = bool(False)
            t = float(0.0)
            if use_b != 0:
                hit, t, state = sample_distance(mb, o, w, t_start, t_end, prm.sampling,
                                                prm.step, state)
            else:
                hit, t, state = sample_distance(ma, o, w, t_start, t_end, prm.sampling,
                                                prm.step, state)
            if not hit:
                alive = 0
                break
            x = o + t * w
            g_v = geom
            if n == 0 and point != 0:
                g_v = geom / wp.max(t * t, 1.0e-30)
            if write != 0:
                out_pos[offsets[i] + n] = x
                out_geom[offsets[i] + n] = g_v
                out_dir[offsets[i] + n] = w
            n += 1
            col = lookup_color(ma, sample_scalar(ma.scalars, ma.inv_spacing, x))
            rho = rho * ma.albedo * wp.max(col[0], wp.max(col[1], col[2]))
            q = float(1.0)
            if n >= RR_START:
                q = wp.clamp(rho, RR_MIN, 1.0)
                ur, state = uniform(state)
                if ur >= q:
                    alive = 0
                    break
                rho = rho / q
            u1, state = uniform(state)
            u2, state = uniform(state)
            wn = wp.vec3(0.0)
            pw = float(0.0)
            if prm.isotropic != 0:
                wn = uniform_sphere(u1, u2)
                pw = 1.0 / (4.0 * wp.pi)
            else:
                wn = sample_hg(w, prm.g, u1, u2)
                pw = hg_phase(wp.dot(w, wn), prm.g)
            geom = q * pw
            o = x
            w = wn
            t_start = 0.0
            t_end = ray_box(o, w, ma.extent)[1]
        if alive != 0 and write == 0:
            wp.atomic_add(capped, 0, 1)
    if write == 0:
        offsets[i] = n
