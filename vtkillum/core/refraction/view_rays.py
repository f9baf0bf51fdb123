"""View-ray propagation (paper section 4.3): forward integration, shading, compositing.

Every pixel's ray moves forward one plane with the ray equation
(:func:`~vtkillum.core.refraction.ray_equation.ray_step`); the segment between the
planes, clipped to the volume's box, is pre-integrated (opacity ``α``, medium colour
``m``, σt-weighted particle colour ``c``) and shaded with the light buffers at both
ends (their mean: the light at the segment's midpoint):

* diffuse: the project's single-scattering source ``i_d = Λ p(θ) L`` (albedo ``Λ``,
  Henyey–Greenstein ``p`` between the local light and view directions, ``L`` the
  light buffer) -- with η ≡ 1 and m ≡ white this is exactly the ``single`` method's
  integrand, which the η ≡ 1 test checks;
* specular: Cook–Torrance (Beckmann distribution, Cook–Torrance masking) with
  Schlick's Fresnel factor for the relative index of the two planes (symmetric in the
  two indices: no total internal reflection, which would make the inside of glass
  mirror the concentrated light back at full strength), the normal along ``∇η``
  (which is ``η_tf'(s) ∇s``: the paper's scalar-gradient normal wherever η varies;
  the Fresnel factor vanishes elsewhere), weighted by ``specular``, and not
  multiplied by the opacity (paper: glass shows highlights).

Compositing is eq. 14 (Oddy–Willis with the light already filtered by the medium):

    C_i = C_{i-1} + (1 - A_{i-1}) M_{i-1} (α c i_d + i_s)
    A_i = A_{i-1} + (1 - A_{i-1}) α,       M_i = M_{i-1} m.

A ray stops computing once ``A`` exceeds ``early_termination``, or when it turns
more than 87° away from the sweep direction (it then keeps its direction for the
background).
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.refraction.light_propagation import LightBuffers, light_at
from vtkillum.core.refraction.planes import SweepParams, segment_transmission
from vtkillum.core.refraction.preintegration import RefractiveMedium, segment_source
from vtkillum.core.refraction.ray_equation import eta_of_value, ray_step, to_local
from vtkillum.core.warp_common import hg_phase, inside_box

#: View-ray states.
MISSED = wp.constant(0)
ACTIVE = wp.constant(1)
DONE = wp.constant(2)


@wp.func
def beckmann(nh: float, roughness: float):
    """Beckmann microfacet distribution (normalised: ∫ D cos θ_h dω = 1)."""
    c2 = nh * nh
    m2 = roughness * roughness
    return wp.exp((c2 - 1.0) / (m2 * c2)) / (wp.pi * m2 * c2 * c2)

@wp.func
def fresnel_schlick(cos_i: float, eta_rel: float):
    """Schlick's Fresnel reflectance for the relative index ``eta_rel`` of two media
    (symmetric: the same for either order, so no total internal reflection)."""
    r = (eta_rel - 1.0) / (eta_rel + 1.0)
    f0 = r * r
    c = 1.0 - wp.clamp(cos_i, 0.0, 1.0)
    c2 = c * c
    return f0 + (1.0 - f0) * c2 * c2 * c

@wp.func
def cook_torrance(n: wp.vec3, to_light: wp.vec3, to_eye: wp.vec3, eta_rel: float,
                  roughness: float):
    """Cook–Torrance ``F D G / (4 n·v)`` (multiply by the irradiance perpendicular to the
    light for the reflected radiance); 0 when the light or the eye is behind the surface."""
    nl = wp.dot(n, to_light)
    nv = wp.dot(n, to_eye)
    if nl <= 0.0 or nv <= 0.0:
        return 0.0
    hv = wp.normalize(to_light + to_eye)
    nh = wp.max(wp.dot(n, hv), 1.0e-4)
    vh = wp.max(wp.dot(to_eye, hv), 1.0e-4)
    geom = wp.min(1.0, wp.min(2.0 * nh * nv / vh, 2.0 * nh * nl / vh))
    return fresnel_schlick(vh, eta_rel) * beckmann(nh, roughness) * geom / (4.0 * nv)

@wp.func
def view_segment(m: RefractiveMedium, p: SweepParams, k: int, lb: LightBuffers, q: wp.vec3,
                 v: wp.vec3, g: wp.vec3, s: float, e: float, C: wp.vec3, A: float, M: wp.vec3,
                 lq: wp.vec3, dq: wp.vec3, have_lq: int):
    """One view ray from plane ``k`` to ``k + 1`` (Algorithm 1, lines 21–36).

    Takes and returns the ray's state: position ``q``, direction ``v``, ``∇η`` ``g``, data
    value ``s`` and index ``e`` at ``q``, and the composited ``C``, ``A``, ``M`` (eq. 14);
    ``lq``, ``dq`` are the light colour and direction of plane ``k`` at ``q`` when
    ``have_lq`` (the previous segment looked them up at its end). Returns the new state,
    the light at the new position (and whether it was looked up) and the ray's state flag
    (ACTIVE or DONE).
    """
    q2, v2, g2, s2, in2, ds, ok = ray_step(m, p.frame, q, v, g, p.dz)
    if ok == 0:
        # Turned away from the sweep: keeps its direction for the background.
        return q, v, g, s, e, C, A, M, lq, dq, 0, DONE
    state = ACTIVE
    e2 = m.eta_outside
    if in2 != 0:
        e2 = eta_of_value(m, s2)
    ext, inside, sa, sb = segment_transmission(
        m, p.frame, q, q2, ds, s, s2, wp.where(inside_box(to_local(p.frame, q), m.extent), 1, 0), 1)
    C2 = C
    A2 = A
    M2 = M
    lb2 = lq
    db = dq
    have = int(0)
    if inside > 0.0:
        alpha = 1.0 - wp.exp(-ext[0] * inside)
        la = lq
        da = dq
        if have_lq == 0:
            la, da = light_at(m, p, lb, q, k)
        lb2, db = light_at(m, p, lb, q2, k + 1)
        have = 1
        light = 0.5 * (la + lb2)
        to_light = -wp.normalize(da + db)
        chord = wp.normalize(q2 - q)
        to_eye = -chord
        src = wp.vec3(0.0)
        if alpha > 0.0:
            colour = segment_source(m, sa, sb) / wp.max(ext[0], 1.0e-30)
            phase = hg_phase(wp.dot(to_light, chord), m.g)
            src = (alpha * m.albedo * phase) * wp.cw_mul(colour, light)
        if p.specular > 0.0 and e2 != e:
            n = g + g2
            if wp.length(n) > 0.0:
                n = wp.normalize(n)
                if wp.dot(n, to_eye) < 0.0:
                    n = -n
                src += (p.specular * cook_torrance(n, to_light, to_eye, e2 / e, p.roughness)) * light
        C2 = C + (1.0 - A) * wp.cw_mul(M, src)
        A2 = A + (1.0 - A) * alpha
        if m.medium_white == 0:
            M2 = wp.cw_mul(M, wp.vec3(wp.exp(-ext[1] * inside), wp.exp(-ext[2] * inside),
                                      wp.exp(-ext[3] * inside)))
        if A2 > p.stop_alpha:
            state = DONE
    return q2, v2, g2, s2, e2, C2, A2, M2, lb2, db, have, state


@wp.func
def advance_view(m: RefractiveMedium, p: SweepParams, k0: int, k1: int, i: int,
                 lb: LightBuffers, vp: wp.array(dtype=wp.vec3), vv: wp.array(dtype=wp.vec3),
                 vg: wp.array(dtype=wp.vec3), vs: wp.array(dtype=wp.float32),
                 veta: wp.array(dtype=wp.float32), vc: wp.array(dtype=wp.vec3),
                 va: wp.array(dtype=wp.float32), vm: wp.array(dtype=wp.vec3),
                 state: wp.array(dtype=wp.int32)):
    """View ray ``i`` from plane ``k0`` to ``k1`` (segments ``k0 … k1 - 1``), its state kept
    in registers in between (the light planes ``k0 … k1`` must be in the ring)."""
    q = vp[i]
    v = vv[i]
    g = vg[i]
    s = vs[i]
    e = veta[i]
    C = vc[i]
    A = va[i]
    M = vm[i]
    st = int(ACTIVE)
    # The light at the end of one segment is the light at the start of the next.
    lq = wp.vec3(0.0)
    dq = wp.vec3(0.0)
    have = int(0)
    for k in range(k0, k1):
        q, v, g, s, e, C, A, M, lq, dq, have, st = view_segment(m, p, k, lb, q, v, g, s, e, C, A,
                                                                 M, lq, dq, have)
        if st != ACTIVE:
            break
    vp[i] = q
    vv[i] = v
    vg[i] = g
    vs[i] = s
    veta[i] = e
    vc[i] = C
    va[i] = A
    vm[i] = M
    state[i] = st
