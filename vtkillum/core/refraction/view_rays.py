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
from vtkillum.core.refraction.ray_equation import eta_at, ray_step, to_local
from vtkillum.core.warp_common import hg_phase, inside_box, sample_scalar

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
def advance_view(m: RefractiveMedium, p: SweepParams, k: int, i: int, lb: LightBuffers,
                 vp: wp.array(dtype=wp.vec3), vv: wp.array(dtype=wp.vec3),
                 vg: wp.array(dtype=wp.vec3), vs: wp.array(dtype=wp.float32),
                 veta: wp.array(dtype=wp.float32), vc: wp.array(dtype=wp.vec3),
                 va: wp.array(dtype=wp.float32), vm: wp.array(dtype=wp.vec3),
                 state: wp.array(dtype=wp.int32)):
    """View ray ``i`` from plane ``k`` to ``k + 1`` (Algorithm 1, lines 21–36)."""
    q = vp[i]
    v = vv[i]
    g = vg[i]
    q2, v2, g2, ds, ok = ray_step(m, p.frame, q, v, g, p.dz)
    if ok == 0:
        state[i] = DONE  # turned away from the sweep: keeps its direction for the background
        return
    s = vs[i]
    e = veta[i]
    q2l = to_local(p.frame, q2)
    s2 = float(0.0)
    e2 = m.eta_outside
    if inside_box(q2l, m.extent):
        s2 = sample_scalar(m.scalars, m.inv_spacing, q2l)
        e2 = eta_at(m, q2l)
    ext, inside, sa, sb = segment_transmission(
        m, p.frame, q, q2, ds, s, s2, wp.where(inside_box(to_local(p.frame, q), m.extent), 1, 0), 1)
    if inside > 0.0:
        alpha = 1.0 - wp.exp(-ext[0] * inside)
        la, da = light_at(m, p, lb, q, k)
        lb2, db = light_at(m, p, lb, q2, k + 1)
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
        A = va[i]
        M = vm[i]
        vc[i] = vc[i] + (1.0 - A) * wp.cw_mul(M, src)
        A = A + (1.0 - A) * alpha
        va[i] = A
        if m.medium_white == 0:
            vm[i] = wp.cw_mul(M, wp.vec3(wp.exp(-ext[1] * inside), wp.exp(-ext[2] * inside),
                                         wp.exp(-ext[3] * inside)))
        if A > p.stop_alpha:
            state[i] = DONE
    vp[i] = q2
    vv[i] = v2
    vg[i] = g2
    vs[i] = s2
    veta[i] = e2
