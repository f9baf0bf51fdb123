"""The interleaved plane sweep (paper Algorithm 1): buffers and one kernel launch per plane.

One kernel launch per plane advances, in the same launch, the light buffer
(:mod:`~vtkillum.core.refraction.light_propagation`, section 4.2) and every view
ray (:mod:`~vtkillum.core.refraction.view_rays`, section 4.3); plane geometry in
:mod:`~vtkillum.core.refraction.planes`.

The light buffers are triple-buffered: launch ``j`` writes light plane ``j``
(reading plane ``j - 1``) while the view rays cross the segment from plane
``j - 2`` to ``j - 1``, whose light buffers are complete. (The paper's fragment
shader reads the previous plane's light for the current view sample; the extra
plane of lag here buys the light at the segment's midpoint.) View-ray state is per
pixel and updated in place (the paper ping-pongs it because a fragment shader cannot
write what it reads; a warp thread can). The per-frame parameters live in a device
record, so that on CUDA the launches of a frame are captured once as a graph and
replayed for later frames with the same plane count
(:class:`~vtkillum.core.refraction.render.RefractionRenderer`).
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.refraction.environment import Environment, environment_lookup
from vtkillum.core.refraction.light_propagation import LAYERS, LightBuffers, propagate_light
from vtkillum.core.refraction.planes import SweepParams, world_direction
from vtkillum.core.refraction.preintegration import RefractiveMedium
from vtkillum.core.refraction.ray_equation import camera_eta_gradient, eta_at, to_local
from vtkillum.core.refraction.view_rays import ACTIVE, MISSED, advance_view
from vtkillum.core.warp_common import inside_box, ray_box, sample_scalar


class SweepBuffers:
    """Device buffers of the sweep: three light layers and the per-pixel view-ray state.

    Light arrays are ``(LAYERS, capacity)``; the capacity only grows (25 % headroom)
    so that buffer addresses, and with them a captured graph, survive small changes
    of the grid.
    """

    def __init__(self, device: str) -> None:
        self.device = device
        self.capacity = 0
        self.pixels = 0
        self.light = None
        self.view = None

    def ensure(self, texels: int, pixels: int) -> bool:
        """Allocate for ``texels`` and ``pixels``; returns True when arrays were replaced."""
        changed = False
        if texels > self.capacity:
            self.capacity = int(texels * 1.25) + 64
            shape = (LAYERS, self.capacity)
            d = self.device
            self.light = LightBuffers()
            for name in ("l", "v", "g"):
                setattr(self.light, name, wp.zeros(shape, dtype=wp.vec3, device=d))
            self.light.p = wp.zeros(shape, dtype=wp.vec4, device=d)
            changed = True
        if pixels != self.pixels:
            self.pixels = pixels
            d = self.device
            n = max(pixels, 1)
            self.view = {
                "p": wp.zeros(n, dtype=wp.vec3, device=d),
                "v": wp.zeros(n, dtype=wp.vec3, device=d),
                "g": wp.zeros(n, dtype=wp.vec3, device=d),
                "s": wp.zeros(n, dtype=wp.float32, device=d),
                "eta": wp.zeros(n, dtype=wp.float32, device=d),
                "C": wp.zeros(n, dtype=wp.vec3, device=d),
                "A": wp.zeros(n, dtype=wp.float32, device=d),
                "M": wp.zeros(n, dtype=wp.vec3, device=d),
                "state": wp.zeros(n, dtype=wp.int32, device=d),
                "radiance": wp.zeros(n, dtype=wp.vec3, device=d),
                "alpha": wp.zeros(n, dtype=wp.float32, device=d),
            }
            changed = True
        return changed

    def view_arrays(self) -> list:
        v = self.view
        return [v["p"], v["v"], v["g"], v["s"], v["eta"], v["C"], v["A"], v["M"], v["state"]]

def sweep_launches(medium: RefractiveMedium, params, buffers: SweepBuffers,
                   environment: Environment, planes: int, width: int, height: int,
                   device: str, after_plane=None) -> int:
    """Issue the whole frame: view-ray set-up, ``planes + 1`` sweep launches, the finish.

    ``after_plane(j)`` (optional, forces a synchronisation) is called after launch
    ``j`` wrote light plane ``j``. Returns the number of launches.
    """
    pixels = width * height
    view = buffers.view_arrays()
    wp.launch(init_view_kernel, dim=max(pixels, 1), inputs=[medium, params, *view], device=device)
    n_light = buffers.capacity
    for j in range(planes + 1):
        wp.launch(sweep_kernel, dim=n_light + pixels,
                  inputs=[medium, params, j, n_light, buffers.light, *view], device=device)
        if after_plane is not None and j < planes:
            after_plane(j)
    wp.launch(finish_kernel, dim=max(pixels, 1),
              inputs=[params, environment, buffers.view["v"], buffers.view["C"],
                      buffers.view["A"], buffers.view["M"], buffers.view["radiance"],
                      buffers.view["alpha"]], device=device)
    return planes + 3

# --- kernels ------------------------------------------------------------------------------------
@wp.kernel
def init_view_kernel(m: RefractiveMedium, params: wp.array(dtype=SweepParams),
                     vp: wp.array(dtype=wp.vec3), vv: wp.array(dtype=wp.vec3),
                     vg: wp.array(dtype=wp.vec3), vs: wp.array(dtype=wp.float32),
                     veta: wp.array(dtype=wp.float32), vc: wp.array(dtype=wp.vec3),
                     va: wp.array(dtype=wp.float32), vm: wp.array(dtype=wp.vec3),
                     state: wp.array(dtype=wp.int32)):
    """Start one view ray per pixel on plane 0.

    ``wp.tid()`` is the pixel ``row * width + col`` (row 0 at the top). Positions and
    directions are camera-frame, world units. Rays that miss the box are MISSED and
    keep their direction (for the background).
    """
    i = wp.tid()
    p = params[0]
    if i >= p.width * p.height:
        return
    row = i / p.width
    col = i - row * p.width
    nx = 2.0 * (float(col) + 0.5) / float(p.width) - 1.0
    ny = 1.0 - 2.0 * (float(row) + 0.5) / float(p.height)
    o = wp.vec3(0.0)
    d = wp.vec3(0.0, 0.0, 1.0)
    if p.parallel != 0:
        o = wp.vec3(nx * p.aspect * p.parallel_scale, ny * p.parallel_scale, 0.0)
    else:
        d = wp.normalize(wp.vec3(nx * p.aspect * p.tan_half, ny * p.tan_half, 1.0))
    vc[i] = wp.vec3(0.0)
    va[i] = 0.0
    vm[i] = wp.vec3(1.0)
    vv[i] = d
    state[i] = MISSED
    lo = to_local(p.frame, o)
    ld = d[0] * p.frame.right + d[1] * p.frame.up + d[2] * p.frame.forward
    tt = ray_box(lo, ld, m.extent)
    if tt[0] >= tt[1] or tt[1] <= 0.0:
        return
    q = o + d * ((p.z0 - o[2]) / d[2])
    ql = to_local(p.frame, q)
    e = eta_at(m, ql)
    vp[i] = q
    vv[i] = d * e
    vg[i] = camera_eta_gradient(m, p.frame, q)
    s = float(0.0)
    if inside_box(ql, m.extent):
        s = sample_scalar(m.scalars, m.inv_spacing, ql)
    vs[i] = s
    veta[i] = e
    state[i] = ACTIVE

@wp.kernel
def sweep_kernel(m: RefractiveMedium, params: wp.array(dtype=SweepParams), j: int,
                 n_light: int, lb: LightBuffers,
                 vp: wp.array(dtype=wp.vec3), vv: wp.array(dtype=wp.vec3),
                 vg: wp.array(dtype=wp.vec3), vs: wp.array(dtype=wp.float32),
                 veta: wp.array(dtype=wp.float32), vc: wp.array(dtype=wp.vec3),
                 va: wp.array(dtype=wp.float32), vm: wp.array(dtype=wp.vec3),
                 state: wp.array(dtype=wp.int32)):
    """Launch ``j`` of the sweep: light plane ``j`` and the view segment ``j - 2 → j - 1``.

    ``wp.tid()`` below ``n_light`` is the light texel ``b * nx + a`` (texels past
    ``nx * ny`` idle); from ``n_light`` on it is the pixel ``row * width + col``.
    Light layer ``j % 3`` is written, layers ``(j - 1) % 3`` and ``(j - 2) % 3`` read.
    Camera-frame positions, world units; light colours in irradiance units.
    """
    tid = wp.tid()
    p = params[0]
    if tid < n_light:
        if j < p.planes and tid < p.nx * p.ny:
            propagate_light(m, p, j, tid, lb)
        return
    k = j - 2
    if k < 0 or k > p.planes - 2:
        return
    i = tid - n_light
    if i >= p.width * p.height:
        return
    if state[i] != ACTIVE:
        return
    advance_view(m, p, k, i, lb, vp, vv, vg, vs, veta, vc, va, vm, state)

@wp.kernel
def finish_kernel(params: wp.array(dtype=SweepParams), env: Environment,
                  vv: wp.array(dtype=wp.vec3), vc: wp.array(dtype=wp.vec3),
                  va: wp.array(dtype=wp.float32), vm: wp.array(dtype=wp.vec3),
                  radiance: wp.array(dtype=wp.vec3), alpha: wp.array(dtype=wp.float32)):
    """Composite eq. 14's result with the background along the final ray directions.

    ``wp.tid()`` is the pixel ``row * width + col``. With ``composite_background`` the
    radiance is ``C + (1 - A) M B(d)`` (``B`` the environment map, mip level from the
    spread of the neighbouring directions, or the background colour) and alpha 1;
    otherwise the radiance is ``C`` and alpha ``1 - (1 - A) mean(M)``.
    """
    i = wp.tid()
    p = params[0]
    if i >= p.width * p.height:
        return
    C = vc[i]
    A = va[i]
    M = vm[i]
    if p.composite_background == 0:
        radiance[i] = C
        alpha[i] = 1.0 - (1.0 - A) * (M[0] + M[1] + M[2]) / 3.0
        return
    background = p.background
    if env.levels > 0:
        row = i / p.width
        col = i - row * p.width
        d = world_direction(p, vv[i])
        nb = i + 1
        if col == p.width - 1:
            nb = i - 1
        nr = i + p.width
        if row == p.height - 1:
            nr = i - p.width
        spread = float(0.0)
        if p.width > 1:
            spread = wp.max(spread, 2.0 * wp.asin(wp.min(0.5 * wp.length(
                d - world_direction(p, vv[nb])), 1.0)))
        if p.height > 1:
            spread = wp.max(spread, 2.0 * wp.asin(wp.min(0.5 * wp.length(
                d - world_direction(p, vv[nr])), 1.0)))
        background = environment_lookup(env, d, spread)
    radiance[i] = C + (1.0 - A) * wp.cw_mul(M, background)
    alpha[i] = 1.0
