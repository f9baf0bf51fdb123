"""The interleaved plane sweep (paper Algorithm 1): buffers and launches.

Per plane ``j`` one launch of :func:`light_kernel` advances the light buffer
(:mod:`~vtkillum.core.refraction.light_propagation`, section 4.2) to plane ``j``; the
view rays (:mod:`~vtkillum.core.refraction.view_rays`, section 4.3) follow in chunks:
one launch of :func:`view_kernel` moves every ray across up to ``chunk`` segments,
its state in registers, once the light planes of those segments are complete. Plane
geometry in :mod:`~vtkillum.core.refraction.planes`.

Why the view rays go in chunks: a light plane needs the whole previous plane (its
backward lookups, blur and Newton step read texels at data-dependent distances), so
the light cannot advance more than one plane per launch (a grid-wide dependency); a
view ray needs only its own state and two finished light planes, so it can cross many
planes in one launch. The light's ``l`` and ``v`` therefore keep a ring of planes
(plane ``j`` in layer ``j % ring``); ``g``, ``p`` and ``o``, read only by the next light
plane, two.

On CUDA a view chunk runs on a second stream, beside the light planes of the next chunk
(:func:`sweep_launches`): its blocks fill the multiprocessors that each light launch leaves
idle in its last wave and between launches (the sweep 2-4 % faster on an H100). The ring
then holds ``2 chunk + 1`` planes, so that the light can run a whole chunk ahead of the
view rays without overwriting the planes they read; on the CPU, where everything runs in
order, ``chunk + 1``. (The paper's fragment shader reads the previous plane's light for
the current view sample; here a view segment between planes ``k`` and ``k + 1`` uses the
mean of both: the light at the segment's midpoint.)

The per-frame parameters live in a device record, so that on CUDA the launches of a
frame are captured once as a graph and replayed for later frames with the same plane
count (:class:`~vtkillum.core.refraction.render.RefractionRenderer`).
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.refraction.environment import Environment, environment_lookup
from vtkillum.core.refraction.light_propagation import GP_LAYERS, LightBuffers, propagate_light
from vtkillum.core.refraction.planes import SweepParams, world_direction
from vtkillum.core.refraction.preintegration import RefractiveMedium
from vtkillum.core.refraction.ray_equation import (
    camera_sample_and_gradient,
    eta_of_value,
    to_local,
)
from vtkillum.core.refraction.view_rays import ACTIVE, MISSED, advance_view
from vtkillum.core.warp_common import ray_box

#: Segments a view ray crosses per launch (at most; see the module docstring).
VIEW_CHUNK = 16

#: Device memory for the ring of ``l`` and ``v`` light planes (bytes; on CUDA at most an
#: eighth of the device's): the chunk shrinks for light grids so large that the ring of a
#: full chunk would not fit.
RING_BYTES = 4 << 30

#: Threads per block of the light and view kernels, and their register caps (CUDA). The
#: kernels are latency bound (chains of dependent volume and light-buffer gathers): without
#: a cap they take 130-170 registers, one block of 256 threads fits a multiprocessor (8
#: warps), too few to hide the latency; 96 and 128 registers in blocks of 128 threads give
#: 20 and 16 warps for a few spills (H100: light 1.2x, view 1.25x faster).
BLOCK_DIM = 128
LIGHT_MAX_REGISTERS = 96
VIEW_MAX_REGISTERS = 128
#: Compile them with fast division, square root and transcendentals (CUDA ``--use_fast_math``;
#: about 1.2x faster on an H100; changes images by rounding only).
FAST_MATH = True


class SweepBuffers:
    """Device buffers of the sweep: the light ring and the per-pixel view-ray state.

    Light arrays are ``(layers, capacity)``; the capacity only grows (25 % headroom)
    so that buffer addresses, and with them a captured graph, survive small changes
    of the grid.
    """

    def __init__(self, device: str) -> None:
        self.device = device
        self.cuda = wp.get_device(device).is_cuda
        # The view chunks' stream and two events (CUDA): see sweep_launches.
        self.view_stream = wp.Stream(device) if self.cuda else None
        self.view_done = [wp.Event(device) for _ in range(2)] if self.cuda else None
        self.capacity = 0
        self.plane_capacity = 0
        self.pixels = 0
        self.light = None
        self.view = None

    @property
    def chunk(self) -> int:
        """Segments per view launch (the ring holds ``chunk + 1`` light planes, on CUDA
        ``2 chunk + 1``)."""
        return (self.light.ring - 1) // (2 if self.cuda else 1)

    def ensure(self, texels: int, pixels: int, planes: int = 1) -> bool:
        """Allocate for ``texels``, ``pixels`` and ``planes``; returns True when arrays were
        replaced."""
        changed = False
        if texels > self.capacity or planes > self.plane_capacity:
            self.capacity = max(self.capacity, int(texels * 1.25) + 64)
            self.plane_capacity = max(self.plane_capacity, int(planes * 1.25) + 8)
            d = self.device
            # l and v: 24 bytes a texel and layer.
            budget = RING_BYTES
            if self.cuda:
                budget = min(budget, wp.get_device(d).total_memory // 8)
            overlap = 2 if self.cuda else 1
            chunk = max(1, min(VIEW_CHUNK, (budget // (24 * self.capacity) - 1) // overlap))
            ring = overlap * chunk + 1
            self.light = LightBuffers()
            self.light.ring = ring
            for name in ("l", "v"):
                setattr(self.light, name, wp.zeros((ring, self.capacity), dtype=wp.vec3,
                                                   device=d))
            self.light.g = wp.zeros((GP_LAYERS, self.capacity), dtype=wp.vec3, device=d)
            self.light.p = wp.zeros((GP_LAYERS, self.capacity), dtype=wp.vec4, device=d)
            self.light.o = wp.zeros((GP_LAYERS, self.capacity), dtype=wp.vec2, device=d)
            self.light.rect = wp.zeros(self.plane_capacity, dtype=wp.vec4i, device=d)
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
                   device: str, light_dims, after_plane=None) -> int:
    """Issue the whole frame: view-ray set-up, the light planes with the view chunks
    between them, the finish.

    ``light_dims[j]`` is the number of threads of light plane ``j``; they stride over its
    rectangle's texels (``buffers.light.rect[j]``). ``after_plane(j)`` (optional, forces a
    synchronisation) is called after light plane ``j`` was written. Returns the number of
    launches.
    """
    pixels = width * height
    view = buffers.view_arrays()
    cuda = wp.get_device(device).is_cuda
    block = BLOCK_DIM if cuda else 256
    light_k, view_k = sweep_kernels(cuda)
    wp.launch(init_view_kernel, dim=max(pixels, 1), inputs=[medium, params, *view], device=device)
    # CUDA: the view chunks run in order on their own stream, each after the light plane it
    # ends on; the light plane that would overwrite the first plane a chunk reads (plane
    # k0 + ring = the one after the next chunk's end) waits for that chunk. In a captured
    # graph these waits are the graph's edges.
    main = wp.get_stream(device) if cuda else None
    side = buffers.view_stream
    chunks = 0
    launches = 2
    k0 = 0  # first view segment not yet crossed
    for j in range(planes):
        dim = max(int(light_dims[j]), 1)
        wp.launch(light_k, dim=dim, inputs=[medium, params, j, dim, buffers.light],
                  device=device, block_dim=block)
        launches += 1
        if after_plane is not None:
            after_plane(j)
        # Segments k0 .. j-1 need light planes k0 .. j: all in the ring once j - k0 = chunk.
        if pixels > 0 and j > k0 and (j - k0 == buffers.chunk or j == planes - 1):
            inputs = [medium, params, k0, j, buffers.light, *view]
            if cuda:
                side.wait_stream(main)
                wp.launch(view_k, dim=pixels, inputs=inputs, device=device, block_dim=block,
                          stream=side)
                side.record_event(buffers.view_done[chunks % 2])
                if chunks > 0:
                    main.wait_event(buffers.view_done[(chunks - 1) % 2])
            else:
                wp.launch(view_k, dim=pixels, inputs=inputs, device=device, block_dim=block)
            chunks += 1
            launches += 1
            k0 = j
    if cuda:
        main.wait_stream(side)
    wp.launch(finish_kernel, dim=max(pixels, 1),
              inputs=[params, environment, buffers.view["v"], buffers.view["C"],
                      buffers.view["A"], buffers.view["M"], buffers.view["radiance"],
                      buffers.view["alpha"]], device=device)
    return launches

# --- kernels ------------------------------------------------------------------------------------
@wp.kernel
def init_view_kernel(m: RefractiveMedium, params: wp.array(dtype=SweepParams),
                     vp: wp.array(dtype=wp.vec3), vv: wp.array(dtype=wp.vec3),
                     vg: wp.array(dtype=wp.vec3), vs: wp.array(dtype=wp.float32),
                     veta: wp.array(dtype=wp.float32), vc: wp.array(dtype=wp.vec3),
                     va: wp.array(dtype=wp.float32), vm: wp.array(dtype=wp.vec3),
                     state: wp.array(dtype=wp.int32)):
    """Start one view ray per pixel on plane ``view_plane`` (0 unless the camera is inside
    the box: then the plane through the camera).

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
    q = o + d * ((p.z0 + float(p.view_plane) * p.dz - o[2]) / d[2])
    s, g, inside = camera_sample_and_gradient(m, p.frame, q)
    e = m.eta_outside
    if inside != 0:
        e = eta_of_value(m, s)
    vp[i] = q
    vv[i] = d * e
    vg[i] = g
    vs[i] = s
    veta[i] = e
    state[i] = ACTIVE

def light_kernel_body(m: RefractiveMedium, params: wp.array(dtype=SweepParams), j: int,
                      stride: int, lb: LightBuffers):
    """Light plane ``j``: thread ``wp.tid()`` computes the texels ``tid``, ``tid + stride``,
    ... of the plane's rectangle ``lb.rect[j]``, counted row by row (``stride`` the launch
    size: a captured graph keeps its launch size while the rectangles change with the
    camera). Writes layer ``j % ring`` of ``l``, ``v`` and ``j % 2`` of ``g``, ``p``; reads
    the previous plane's. Camera-frame positions, world units; light colours in
    irradiance units."""
    t = wp.tid()
    p = params[0]
    r = lb.rect[j]
    w = r[2] - r[0]
    n = w * (r[3] - r[1])
    if j >= p.planes:
        return
    while t < n:
        b = t / w
        propagate_light(m, p, j, r[0] + t - b * w, r[1] + b, lb)
        t += stride


def view_kernel_body(m: RefractiveMedium, params: wp.array(dtype=SweepParams), k0: int,
                     k1: int, lb: LightBuffers, vp: wp.array(dtype=wp.vec3),
                     vv: wp.array(dtype=wp.vec3), vg: wp.array(dtype=wp.vec3),
                     vs: wp.array(dtype=wp.float32), veta: wp.array(dtype=wp.float32),
                     vc: wp.array(dtype=wp.vec3), va: wp.array(dtype=wp.float32),
                     vm: wp.array(dtype=wp.vec3), state: wp.array(dtype=wp.int32)):
    """View segments ``k0 … k1 - 1``: ``wp.tid()`` is the pixel ``row * width + col``."""
    i = wp.tid()
    p = params[0]
    if i >= p.width * p.height:
        return
    if state[i] != ACTIVE:
        return
    # Segments behind the camera (it is inside the box) carry only light.
    k_first = wp.max(k0, p.view_plane)
    k_last = wp.min(k1, p.planes - 1)
    if k_first >= k_last:
        return
    advance_view(m, p, k_first, k_last, i, lb, vp, vv, vg, vs, veta, vc, va, vm, state)


_KERNELS: dict = {}


def sweep_kernels(cuda: bool = True):
    """``(light, view)`` kernels: on CUDA with the register caps and math of the module
    settings above (each setting its own module), on the CPU plain."""
    settings = (LIGHT_MAX_REGISTERS, VIEW_MAX_REGISTERS, bool(FAST_MATH)) if cuda else (0, 0, False)
    kernels = _KERNELS.get(settings)
    if kernels is None:
        kernels = _KERNELS[settings] = tuple(
            _kernel(body, name, cap, settings[2])
            for body, name, cap in ((light_kernel_body, "light_kernel", settings[0]),
                                    (view_kernel_body, "view_kernel", settings[1])))
    return kernels


def _kernel(body, name: str, cap: int, fast: bool):
    options = {"enable_backward": False}
    if cap:
        options.update(cuda_max_registers=cap, module="unique")
    if fast:
        options.update(module_options={"fast_math": True}, module="unique")
    return wp.kernel(body, name=f"{name}_r{cap}{'f' if fast else ''}", **options)


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
