"""Virtual-light contributions along the stored light paths (paper eqs. 3, 6 and 7).

A VL at vertex ``x_k`` of a light path carries the estimate

    beta_k = f(x_1 .. x_k) / p(x_1 .. x_k)

of the light arriving there (the paper's ``L_i^k`` in the volume measure), built up
vertex by vertex:

    k = 1:   beta_1 = E_l(x_1) T(x_1 -> light)                    / p_1
    k > 1:   beta_k = beta_{k-1} sigma_s(x_{k-1}) f_HG(w_{k-1}, w_k) T(x_{k-1}, x_k) / p_k

with ``E_l`` the light's irradiance at ``x_1`` (``I / max(d, r)^2`` for point lights),
``w_k`` the direction of the segment arriving at ``x_k`` and ``p_k`` the density with
which the walk sampled ``x_k`` given ``x_{k-1}``: the walk's geometric density times the
distance density ``sigma_t(x_k) T(x_{k-1}, x_k)``, *frozen* when the vertex was created
(volume measure for the first vertex, whose light may move; for later vertices the
``1 / t_k^2`` of the volume measure is left out of integrand and density alike, as the
vertices never move). The VL then
shines like a point light of intensity

    I_k(w) = beta_k sigma_s(x_k) f_HG(w_k . w)

(``power`` below is ``beta_k sigma_s(x_k) / P`` with ``P`` the number of light paths of
the set, so that the sum over VLs is the set's estimate).

At generation the ratios collapse to the usual collision-estimator weights
(``sigma_s / sigma_t = albedo * colour``). After an edit the same formula with the
*new* transfer function, scale, colours, albedo, ``g`` or lights and the *old* densities
is eq. 6: an importance-sampling re-weighting of the stored paths, unbiased wherever the
old walk could reach (the paper writes ``p_new`` in eq. 6, which would cancel ``T_new``
against the new density and keep VLs behind newly added matter at full power; we divide
by the density the vertices were actually drawn from).

Transmittances are kept as optical depths ``tau`` of the *unscaled* medium, so that a
global density scale ``S`` (eq. 7) enters as ``T = exp(-S tau) = T_old^(S / S_old)``
without marching. ``tau`` is marched (:func:`segment_depths`) at generation, after a
transfer-function edit and, for the first segment only, after a light moved.
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.warp_common import (
    Lights,
    Medium,
    hg_phase,
    light_incidence,
    lookup_color,
    lookup_sigma_t,
    ray_box,
    sample_scalar,
)


def segment_depths(medium: Medium, lights: Lights, positions, vertex, light_of, tau, step: float,
                   device: str, first: int = 0, count: int | None = None,
                   only_first_segment: bool = False) -> None:
    """March the optical depth of the segment arriving at each VL (in place into ``tau``).

    Parameters
    ----------
    medium : Medium
        The unscaled medium.
    lights : Lights
    positions : wp.array(vec3)
        VL positions, grouped by path in vertex order (vertex ``k - 1`` precedes ``k``).
    vertex : wp.array(int32)
        Index of each VL in its path (0: first vertex, whose segment runs to the light).
    light_of : wp.array(int32)
        Light of each VL's path.
    tau : wp.array(float32)
        Output, overwritten for VLs ``first .. first + count - 1``.
    step : float
        Longest marching step (world units); midpoint rule as ``shadow_transmittance``.
    only_first_segment : bool
        Update only the VLs with ``vertex == 0`` (a light moved).
    """
    n = (positions.shape[0] - first) if count is None else int(count)
    if n <= 0:
        return
    wp.launch(segment_depth_kernel, dim=n,
              inputs=[medium, lights, positions, vertex, light_of, int(first), float(step),
                      int(only_first_segment), tau], device=device)


def freeze_densities(medium: Medium, scale_a: float, scale_b: float, positions, geom, tau, pdf,
                     device: str, first: int = 0, count: int | None = None) -> None:
    """Sampling density of new VLs: ``geom * (p_a + p_b) / 2`` with
    ``p_s = s sigma_t(x) exp(-s tau)`` (one scale: the walk's medium; two: the mixture of
    eq. 8). Written to ``pdf`` in place for VLs ``first .. first + count - 1``."""
    n = (positions.shape[0] - first) if count is None else int(count)
    if n <= 0:
        return
    wp.launch(freeze_kernel, dim=n,
              inputs=[medium, float(scale_a), float(scale_b), positions, geom, tau, int(first),
                      pdf], device=device)


def evaluate(medium: Medium, scale: float, lights: Lights, path_offset, path_count, path_light,
             positions, incident, tau, pdf, n_paths: int, power, direction, extinction,
             device: str) -> None:
    """Re-evaluate every VL's ``power`` and incident ``direction`` along its path (eq. 6).

    ``medium`` is unscaled, ``scale`` the global density scale ``S``; ``power`` is divided
    by ``n_paths``, the number of paths (one thread each). ``incident``: the stored
    directions of the walk (all but the first vertex's are used). ``extinction`` receives the
    scaled ``sigma_t`` at each VL (for radii in mean free paths).
    """
    if int(n_paths) <= 0:
        return
    wp.launch(contribution_kernel, dim=int(n_paths),
              inputs=[medium, float(scale), lights, path_offset, path_count, path_light,
                      positions, incident, tau, pdf, 1.0 / max(int(n_paths), 1), power,
                      direction, extinction],
              device=device)


# --- device functions ---------------------------------------------------------------------------
@wp.func
def optical_depth(m: Medium, p: wp.vec3, w: wp.vec3, dist: float, step: float):
    """``integral sigma_t`` from ``p`` along unit ``w`` to the box exit or ``dist``.

    The discretisation of ``shadow_transmittance`` with ``xi = 1/2`` (equal segments no
    longer than ``step``, midpoint rule), returned as an optical depth so that it can be
    scaled and does not underflow.
    """
    tt = ray_box(p, w, m.extent)
    length = wp.min(tt[1], dist)
    if length <= 0.0:
        return 0.0
    n = int(wp.ceil(length / step))
    h = length / float(n)
    tau = float(0.0)
    for k in range(n):
        tau += lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing,
                                               p + ((float(k) + 0.5) * h) * w))
    return tau * h


# --- kernels ------------------------------------------------------------------------------------
@wp.kernel
def segment_depth_kernel(m: Medium, lights: Lights, positions: wp.array(dtype=wp.vec3),
                         vertex: wp.array(dtype=wp.int32), light_of: wp.array(dtype=wp.int32),
                         first: int, step: float, only_first: int,
                         tau: wp.array(dtype=wp.float32)):
    """Optical depth of the segment arriving at VL ``first + tid``.

    ``wp.tid()`` indexes VLs from ``first``. Vertex 0: from the VL towards its light (to
    the box exit for directional lights); others: to the previous vertex of the path,
    which is the previous VL in the arrays. Unitless.
    """
    i = first + wp.tid()
    x = positions[i]
    if vertex[i] == 0:
        wl, dist, _e = light_incidence(lights, light_of[i], x)
        tau[i] = optical_depth(m, x, wl, dist, step)
    elif only_first == 0:
        v = positions[i - 1] - x
        d = wp.length(v)
        if d > 0.0:
            tau[i] = optical_depth(m, x, v / d, d, step)
        else:
            tau[i] = 0.0


@wp.kernel
def freeze_kernel(m: Medium, scale_a: float, scale_b: float, positions: wp.array(dtype=wp.vec3),
                  geom: wp.array(dtype=wp.float32), tau: wp.array(dtype=wp.float32), first: int,
                  pdf: wp.array(dtype=wp.float32)):
    """Sampling density of VL ``first + tid`` (volume measure, 1/world units³)."""
    i = first + wp.tid()
    sig = lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing, positions[i]))
    pa = scale_a * sig * wp.exp(-scale_a * tau[i])
    pb = scale_b * sig * wp.exp(-scale_b * tau[i])
    pdf[i] = geom[i] * 0.5 * (pa + pb)


@wp.kernel
def contribution_kernel(m: Medium, scale: float, lights: Lights,
                        path_offset: wp.array(dtype=wp.int32),
                        path_count: wp.array(dtype=wp.int32),
                        path_light: wp.array(dtype=wp.int32),
                        positions: wp.array(dtype=wp.vec3), incident: wp.array(dtype=wp.vec3),
                        tau: wp.array(dtype=wp.float32),
                        pdf: wp.array(dtype=wp.float32), inv_paths: float,
                        power: wp.array(dtype=wp.vec3), direction: wp.array(dtype=wp.vec3),
                        extinction: wp.array(dtype=wp.float32)):
    """Walk one stored light path and write its VLs' power and incident direction.

    ``wp.tid()`` indexes paths. ``power[i] = beta_i sigma_s(x_i) / P`` (RGB; the VL's
    radiant intensity towards ``w`` is ``power * f_HG(direction . w)``, so ``power`` has
    the units of the lights' power); ``direction[i]`` is the unit travel direction
    of the light arriving at VL ``i``; ``extinction[i]`` its ``S sigma_t`` (1/world units).
    See the module docstring.
    """
    p = wp.tid()
    off = path_offset[p]
    li = path_light[p]
    carry = wp.vec3(0.0)  # beta_{k-1} sigma_s(x_{k-1})
    w_prev = wp.vec3(0.0)
    for k in range(path_count[p]):
        i = off + k
        x = positions[i]
        T = wp.exp(-scale * tau[i])
        f = wp.vec3(0.0)
        w = wp.vec3(0.0)
        if k == 0:
            wl, _dist, e = light_incidence(lights, li, x)
            w = -wl
            f = T * e
        else:
            w = incident[i]
            f = (hg_phase(wp.dot(w_prev, w), m.g) * T) * carry
        beta = wp.vec3(0.0)
        if pdf[i] > 0.0:
            beta = f / pdf[i]
        s = sample_scalar(m.scalars, m.inv_spacing, x)
        sig = scale * lookup_sigma_t(m, s)
        carry = wp.cw_mul(beta, (m.albedo * sig) * lookup_color(m, s))
        power[i] = carry * inv_paths
        direction[i] = w
        extinction[i] = sig
        w_prev = w
