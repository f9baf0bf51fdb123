"""Light propagation (paper section 4.2): backward integration, intensity law, light filtering.

Every texel ``x`` of the light buffer on plane ``j`` is integrated *backwards* to
plane ``j - 1`` (the hybrid Lagrangian–Eulerian scheme of the paper): the ray
arriving at ``x`` left plane ``j - 1`` at ``lp``, where the light colour, the
(unnormalised) ray direction ``v = η dx/ds`` and ``∇η`` are read with bilinear
lookups (through the elliptical blur below); then

    L_j = L_{j-1}(lp) · I · (1 - α) · m                    (eq. 9)
    v_j = v_{j-1}(lp) + ∇η ds                              (eq. 10, as a kick–drift–kick
                                                             step, see ray_equation)

with ``α`` and ``m`` pre-integrated over the segment ``lp → x`` and ``I`` the
intensity correction. Plane 0 holds the light's irradiance and direction.

Finding ``lp``: the paper looks back along the direction stored at ``x`` on the
previous plane (one Picard step of ``lp + off(lp) = x``, ``off`` the in-plane
displacement of a ray over one plane). Here that first estimate is refined by one
Newton step with the Jacobian ``J = ∂off/∂y`` from the four neighbouring texels
(central differences): exact for linear direction fields, and it follows a ray
through a focus (where the arriving ray comes from the other side); the step is
capped where ``det(I + J)`` nearly vanishes.

Intensity law (eqs. 11–13): the paper takes the areas ``S_{j-1}``, ``S_j`` from
screen-space derivatives of the intersection points. Here the same Jacobian maps a
texel cell of plane ``j - 1`` onto ``(I + J)`` times itself on plane ``j``, and
each texel carries its ray tube's cross-section ``P = dX/dX0`` (2x2), advected like
the direction and updated as ``P ← (I + J) P``; the light changes by
``S_{j-1} cos θ_{j-1} / (S_j cos θ_j)`` with ``S = |det P|``, so ``L`` is the
irradiance perpendicular to the ray and the flux through a plane, ``Σ L cos θ h²``,
is conserved (tested to 0.1 % through a lens). Carrying ``P`` instead of multiplying
per-plane area ratios bounds the concentration: ``S`` is clamped at
``1 / max_concentration``. A single-valued direction field cannot hold rays that
crossed at a focus the grid does not resolve; past such a focus (``det P < 0``)
the tube widens at the rate the field still converges instead of collapsing again
(the focus mirrored), and no texel exceeds ``max_concentration`` times the light.

Light filtering (Patel et al. 2013, as used by the paper): with ``softness > 0``
the light colour is read as the mean of three bilinear samples on an ellipse around
``lp`` -- the cross-section of a cone of half-angle ``atan(softness)`` around the
ray, cut by the plane -- rotated by a random angle per texel and plane (a
randomised rotational offset); ``direction_blur`` does the same for the ray
directions (the paper filters directions with the light's kernel to reduce the
backward mapping's bias towards refracting boundaries; it also removes the speckle
behind strongly refracting surfaces). The kernel's variance grows with every plane,
so penumbrae widen like the square root of the distance from the occluder
(incremental convolution), not linearly as behind a real disc light.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from vtkillum.core.refraction.planes import (
    SweepParams,
    plane_offset,
    segment_transmission,
    texel_coordinates,
    texel_position,
)
from vtkillum.core.refraction.preintegration import RefractiveMedium
from vtkillum.core.refraction.ray_equation import MIN_COS, camera_sample_and_gradient

#: Layers of the ``g``, ``p`` and ``o`` light buffers (only the light propagation reads them:
#: the previous plane's); ``l`` and ``v`` keep a ring of planes for the view rays
#: (:class:`~vtkillum.core.refraction.sweep.SweepBuffers`).
GP_LAYERS = wp.constant(2)

#: The Newton step of the backward integration is used where |det(I + J)| exceeds this and
#: it moves the lookup by at most this ratio times (the first estimate + one texel).
NEWTON_MIN_DET = wp.constant(0.05)
NEWTON_MAX_RATIO = wp.constant(4.0)


@wp.struct
class LightBuffers:
    """The light buffers, texel ``b * nx + a`` (camera frame).

    ``l`` and ``v`` are ``(ring, capacity)``: plane ``j`` in layer ``j % ring``; ``g``,
    ``p`` and ``o`` are ``(GP_LAYERS, capacity)``: plane ``j`` in layer ``j % GP_LAYERS``.
    ``l``: light colour, the irradiance perpendicular to the ray (intensity-corrected);
    ``v``: ray direction ``η dx/ds`` (unnormalised); ``g``: ``∇η`` at the texel;
    ``p``: the ray tube's cross-section ``dX/dX0`` (2x2, columns, in-plane): how a texel
    cell of plane 0 has been mapped onto this plane, for the intensity law;
    ``o``: the in-plane displacement of the texel's ray to the next plane
    (:func:`ray_offset` of its ``v`` and ``g``), written with them: the next plane's Newton
    step reads it at five texels, so each texel computes it once instead of five times.
    ``rect[j]``: the texels ``(a0, b0, a1, b1)`` (ends exclusive) computed on plane ``j``
    (:func:`~vtkillum.core.refraction.planes.plane_rects`); any other texel of the plane
    reads as the unobstructed light.
    """

    l: wp.array2d(dtype=wp.vec3)
    v: wp.array2d(dtype=wp.vec3)
    g: wp.array2d(dtype=wp.vec3)
    p: wp.array2d(dtype=wp.vec4)
    o: wp.array2d(dtype=wp.vec2)
    rect: wp.array(dtype=wp.vec4i)
    ring: int

@wp.func
def light_fetch(buf: wp.array2d(dtype=Any), layer: int, p: SweepParams, r: wp.vec4i, a: int,
                b: int, outside: Any):
    """Texel ``(a, b)`` of ``layer``, or ``outside`` (what the unobstructed light carries)
    beyond the plane's computed rectangle ``r``."""
    if a < r[0] or b < r[1] or a >= r[2] or b >= r[3]:
        return outside
    return buf[layer, b * p.nx + a]

@wp.func
def light_bilinear(buf: wp.array2d(dtype=Any), layer: int, p: SweepParams, r: wp.vec4i,
                   x: float, y: float, outside: Any):
    """Bilinear lookup at continuous texel coordinates ``(x, y)`` (``outside`` beyond the grid)."""
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    a = int(x0)
    b = int(y0)
    fx = x - x0
    fy = y - y0
    bottom = wp.lerp(light_fetch(buf, layer, p, r, a, b, outside),
                     light_fetch(buf, layer, p, r, a + 1, b, outside), fx)
    top = wp.lerp(light_fetch(buf, layer, p, r, a, b + 1, outside),
                  light_fetch(buf, layer, p, r, a + 1, b + 1, outside), fx)
    return wp.lerp(bottom, top, fy)

@wp.func
def light_filtered(buf: wp.array2d(dtype=Any), layer: int, p: SweepParams, r: wp.vec4i,
                   x: float, y: float, outside: Any, radius: float, major: wp.vec2,
                   stretch: float, phi: float):
    """Three-sample elliptical kernel (Patel et al. 2013) around texel coordinates ``(x, y)``.

    ``radius`` is the cone's radius on the plane (texels), ``major`` the unit direction in
    which the ellipse is stretched by ``stretch = 1/cos θ``, ``phi`` the random rotation.
    Samples sit at ``radius/√2`` (the kernel then has a uniform disc's variance), 120°
    apart. ``radius = 0``: one bilinear lookup.
    """
    if radius <= 0.0:
        return light_bilinear(buf, layer, p, r, x, y, outside)
    minor = wp.vec2(-major[1], major[0])
    rs = radius * 0.70710678
    c120 = -0.5
    s120 = 0.8660254
    # Unit offsets 120° apart, rotated by phi, then stretched along the major axis.
    u0 = wp.vec2(wp.cos(phi), wp.sin(phi))
    u1 = wp.vec2(c120 * u0[0] - s120 * u0[1], s120 * u0[0] + c120 * u0[1])
    u2 = wp.vec2(c120 * u1[0] - s120 * u1[1], s120 * u1[0] + c120 * u1[1])
    s0 = major * (rs * stretch * u0[0]) + minor * (rs * u0[1])
    s1 = major * (rs * stretch * u1[0]) + minor * (rs * u1[1])
    s2 = major * (rs * stretch * u2[0]) + minor * (rs * u2[1])
    c0 = light_bilinear(buf, layer, p, r, x + s0[0], y + s0[1], outside)
    c1 = light_bilinear(buf, layer, p, r, x + s1[0], y + s1[1], outside)
    c2 = light_bilinear(buf, layer, p, r, x + s2[0], y + s2[1], outside)
    # Written so that three equal samples give exactly that value (no drift with η ≡ 1).
    return c0 + ((c1 - c0) + (c2 - c0)) * (1.0 / 3.0)

@wp.func
def chord_estimate(v: wp.vec3, g: wp.vec3, dz: float):
    """Direction of the chord to the next plane of a ray with direction ``v`` and ``∇η = g``:
    ``v`` plus the first half kick of the Verlet step (``v + ∇η ds/2``)."""
    c = wp.normalize(v)
    return v + g * (0.5 * dz / wp.max(c[2], MIN_COS))

@wp.func
def ray_offset(v: wp.vec3, g: wp.vec3, dz: float):
    """In-plane displacement to the next plane of a ray leaving a texel with direction
    ``v`` and ``∇η = g`` there (its chord estimate)."""
    return plane_offset(chord_estimate(v, g, dz), dz)

@wp.func
def propagate_light(m: RefractiveMedium, p: SweepParams, j: int, a: int, b: int,
                    lb: LightBuffers):
    """Light texel ``(a, b)`` of plane ``j`` (Algorithm 1, lines 7–18)."""
    t = b * p.nx + a
    wr = j % lb.ring
    wg = j % GP_LAYERS
    x = texel_position(p, float(a), float(b), j)
    s_x, g_x, in_x = camera_sample_and_gradient(m, p.frame, x)
    v0 = p.light_dir * m.eta_outside
    zero = wp.vec3(0.0)
    unit = wp.vec4(1.0, 0.0, 0.0, 1.0)
    if j == 0:
        lb.l[wr, t] = p.light_rgb
        lb.v[wr, t] = v0
        lb.g[wg, t] = g_x
        lb.p[wg, t] = unit
        lb.o[wg, t] = ray_offset(v0, g_x, p.dz)
        return
    rd = (j - 1) % lb.ring
    rg = (j - 1) % GP_LAYERS
    r = lb.rect[j - 1]
    inv_h = 1.0 / p.texel
    # Backward integration: find lp on plane j-1 with lp + off(lp) = x, off(y) the in-plane
    # displacement of the ray leaving y (its chord estimate). In deviations from the straight
    # light (off0): one Newton step from texel (a, b), delta(lp) = (I + J)^-1 delta(a, b) with
    # J = d delta / d y from the neighbours (central differences). (The paper's lookup along
    # the stored direction is the first Picard step; the Newton step is exact for linear
    # direction fields.) With η constant every ray is straight and delta = 0.
    off0 = plane_offset(p.light_dir, p.dz)
    delta = wp.vec2(0.0)
    da = wp.vec2(0.0)
    db = wp.vec2(0.0)
    if m.eta_varies != 0:
        # beyond the plane's rectangle: the unobstructed light's ray (v0, no gradient)
        o_out = ray_offset(v0, zero, p.dz)
        oe = light_fetch(lb.o, rg, p, r, a + 1, b, o_out)
        ow = light_fetch(lb.o, rg, p, r, a - 1, b, o_out)
        on = light_fetch(lb.o, rg, p, r, a, b + 1, o_out)
        os = light_fetch(lb.o, rg, p, r, a, b - 1, o_out)
        delta = light_fetch(lb.o, rg, p, r, a, b, o_out) - off0
        da = (oe - ow) * (0.5 * inv_h)
        db = (on - os) * (0.5 * inv_h)
        det = (1.0 + da[0]) * (1.0 + db[1]) - da[1] * db[0]
        newton = wp.vec2((1.0 + db[1]) * delta[0] - db[0] * delta[1],
                         (1.0 + da[0]) * delta[1] - da[1] * delta[0])
        bound = NEWTON_MAX_RATIO * (wp.length(delta) + p.texel) * wp.abs(det)
        if wp.abs(det) > NEWTON_MIN_DET and wp.length(newton) <= bound:
            delta = newton / det
    off = off0 + delta
    la = float(a) - delta[0] * inv_h
    lb_ = float(b) - delta[1] * inv_h
    lp = x - wp.vec3(off[0], off[1], p.dz)
    ds = wp.length(x - lp)
    # Elliptical kernel: a cone of half-angle atan(softness) around the ray, cut by the plane.
    chord = (x - lp) / ds
    cz = wp.max(chord[2], MIN_COS)
    axis = wp.vec2(chord[0], chord[1])
    major = wp.vec2(1.0, 0.0)
    if wp.length(axis) > 1.0e-6:
        major = wp.normalize(axis)
    phi = float(0.0)
    if p.softness > 0.0 or p.direction_blur > 0.0:
        state = wp.rand_init(p.seed + j * 7919, t)
        phi = 2.0 * wp.pi * wp.randf(state)
    l_in = light_filtered(lb.l, rd, p, r, la, lb_, p.light_rgb, p.softness * ds * inv_h, major,
                          1.0 / cz, phi)
    v_in = light_filtered(lb.v, rd, p, r, la, lb_, v0, p.direction_blur * ds * inv_h, major,
                          1.0 / cz, phi)
    g_in = light_bilinear(lb.g, rg, p, r, la, lb_, zero)
    v_half = v_in + g_in * (0.5 * ds)
    v_new = v_half + g_x * (0.5 * ds)
    # Intensity law (eqs. 11-13): a texel cell of plane j-1 maps onto (I + J) times itself on
    # plane j (J = d off / d y from the neighbours, as for the Newton step), so the ray tube's
    # cross-section P = dX/dX0 becomes (I + J) P and the light changes by
    # S_{j-1} cos_{j-1} / (S_j cos_j) with S = |det P|. Carrying P (rather than multiplying
    # per-plane area ratios) bounds the concentration: S is clamped at 1/max_concentration,
    # so a focus the grid cannot resolve brightens the light once, not on every plane.
    gain = float(1.0)
    p_new = unit
    if m.eta_varies != 0:
        p_in = light_bilinear(lb.p, rg, p, r, la, lb_, unit)
        p_new = wp.vec4((1.0 + da[0]) * p_in[0] + db[0] * p_in[1],
                        da[1] * p_in[0] + (1.0 + db[1]) * p_in[1],
                        (1.0 + da[0]) * p_in[2] + db[0] * p_in[3],
                        da[1] * p_in[2] + (1.0 + db[1]) * p_in[3])
        floor = 1.0 / p.max_concentration
        det_in = p_in[0] * p_in[3] - p_in[2] * p_in[1]
        det_step = (1.0 + da[0]) * (1.0 + db[1]) - da[1] * db[0]
        det_new = p_new[0] * p_new[3] - p_new[2] * p_new[1]
        if det_in < 0.0 and wp.abs(det_step) < 1.0:
            # Past a focus (det P < 0) the rays diverge, but a single-valued direction field
            # cannot hold rays that crossed: it keeps converging. Let the tube widen at the
            # rate the field converges (the focus mirrored) instead of collapsing it again.
            p_new = p_in * (1.0 / wp.sqrt(wp.max(wp.abs(det_step), floor)))
        elif det_in > 0.0 and det_new > 0.0 and det_new < floor:
            # The tube collapses in this step: the focus. Mark the ray as past it.
            p_new = wp.vec4(p_new[0], p_new[1], -p_new[2], -p_new[3])
        if p.intensity_correction != 0:
            s_in = wp.max(wp.abs(p_in[0] * p_in[3] - p_in[2] * p_in[1]), floor)
            s_new = wp.max(wp.abs(p_new[0] * p_new[3] - p_new[2] * p_new[1]), floor)
            gain = (s_in * wp.max(wp.normalize(v_in)[2], MIN_COS)) / (
                s_new * wp.max(wp.normalize(v_new)[2], MIN_COS))
    ext, inside, _sa, _sb = segment_transmission(m, p.frame, lp, x, ds, 0.0, s_x, 0, in_x)
    l_out = l_in
    if inside > 0.0:
        l_out = l_in * wp.exp(-ext[0] * inside)
        if m.medium_white == 0:
            l_out = wp.cw_mul(l_out, wp.vec3(wp.exp(-ext[1] * inside), wp.exp(-ext[2] * inside),
                                             wp.exp(-ext[3] * inside)))
    # No texel carries more than max_concentration times the light (bilinear lookups of the
    # light and of P at a focus need not stay consistent).
    lb.l[wr, t] = wp.min(l_out * gain, p.light_rgb * p.max_concentration)
    lb.v[wr, t] = v_new
    lb.g[wg, t] = g_x
    lb.p[wg, t] = p_new
    lb.o[wg, t] = ray_offset(v_new, g_x, p.dz)

@wp.func
def light_at(m: RefractiveMedium, p: SweepParams, lb: LightBuffers, q: wp.vec3, j: int):
    """Light colour and direction of plane ``j`` at camera-frame point ``q`` (bilinear)."""
    c = texel_coordinates(p, q, j)
    layer = j % lb.ring
    r = lb.rect[j]
    return (light_bilinear(lb.l, layer, p, r, c[0], c[1], p.light_rgb),
            light_bilinear(lb.v, layer, p, r, c[0], c[1], p.light_dir * m.eta_outside))
