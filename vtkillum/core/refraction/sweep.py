"""The interleaved plane sweep (paper sections 4.2–4.3, Algorithm 1).

Planes parallel to the image plane, ``dz`` apart along the camera's view direction
``f``, cover the volume's box from its nearest to its farthest point. One kernel
launch per plane advances, in the same launch,

* **light propagation** (section 4.2): every texel ``x`` of the light buffer on
  plane ``j`` is integrated *backwards* to plane ``j - 1``: the ray through ``x``
  along the direction stored at ``x`` meets plane ``j - 1`` at ``lp``, where the
  light colour, the (unnormalised) ray direction ``v`` and ``∇η`` are read with
  bilinear lookups (through the elliptical blur below); then

      L_j = L_{j-1}(lp) · I · (1 - α) · m                    (eq. 9)
      v_j = v_{j-1}(lp) + ∇η ds                              (eq. 10, a kick-drift-kick
                                                               step, see ray_equation)

  with ``α`` and ``m`` pre-integrated over the segment ``lp → x`` and ``I`` the
  intensity correction of eqs. 11–13: ``I = S_{j-1} / S_j``, the areas from finite
  differences of neighbouring texels' intersection points (the paper's screen-space
  derivatives; here the neighbours' ``lp`` from their stored directions, central
  differences) times ``cos θ_{j-1} / cos θ_j`` so that ``L`` is the irradiance
  perpendicular to the ray (an addition to the paper: with it the flux through a plane,
  ``Σ L cos θ S``, is conserved exactly by eq. 12). Plane 0 holds the light's
  irradiance and direction.
* **view-ray propagation** (section 4.3): every pixel's ray moves forward one plane
  with the ray equation; the segment is pre-integrated (``α``, medium colour ``m``,
  σt-weighted particle colour ``c``) and shaded with the light buffers at both ends
  (their mean: the light at the segment's midpoint): the diffuse term is the project's
  single-scattering source ``i_d = Λ p(θ) L`` (albedo ``Λ``, Henyey–Greenstein ``p``
  between the local light and view directions), the specular term is Cook–Torrance
  (Beckmann distribution, Cook–Torrance masking) with Schlick's Fresnel factor for the
  relative index between the two planes (symmetric in the two indices: no total internal
  reflection, which would make the inside of glass mirror the concentrated light
  back at full strength) and the normal along ``∇η``
  (which is ``η_tf'(s) ∇s``: the paper's scalar-gradient normal wherever η varies, and
  the Fresnel factor vanishes elsewhere). Compositing is eq. 14:

      C_i = C_{i-1} + (1 - A_{i-1}) M_{i-1} (α c i_d + i_s)
      A_i = A_{i-1} + (1 - A_{i-1}) α,       M_i = M_{i-1} m.

The light buffers are triple-buffered: launch ``j`` writes light plane ``j`` (reading
plane ``j - 1``) while the view rays cross the segment from plane ``j - 2`` to
``j - 1``, whose light buffers are complete. (The paper's fragment shader reads the
previous plane's light for the current view sample; the extra plane of lag here
buys the midpoint light.) View-ray state is per pixel and updated in place.

The light buffer is a regular grid of texels on each plane, sheared along the
light's initial direction: texel ``(a, b)`` of plane ``j`` lies at camera
coordinates ``q0 + h (a, b) + j shift`` with ``shift = dz (ω_x, ω_y) / ω_z``. A
straight light ray therefore goes from texel to texel: with η ≡ 1 every backward
lookup lands on a texel centre and repeated bilinear filtering does not blur the
shadows (the paper's fragment-aligned buffers do). The grid covers the box's shadow
on the plane along the light (anything outside it is unattenuated, straight light);
its texel size is the pixel footprint at the volume's centre depth times
``light_buffer_scale`` (so it has about as many texels over the volume as the paper's
viewport-sized buffer).

Light filtering (Patel et al. 2013, as used by the paper): with ``softness > 0``
the light colour is read as the mean of three bilinear samples on an ellipse around
``lp`` -- the cross-section of a cone of half-angle ``atan(softness)`` around the
ray, cut by the plane -- rotated by a random angle per texel and plane (a
randomised rotational offset); ``direction_blur`` does the same for the ray
directions (the paper filters directions with the light's kernel to reduce the
backward mapping's bias towards refracting boundaries). The kernel's variance grows
with every plane, so penumbrae widen like the square root of the distance from
the occluder (incremental convolution), not linearly as behind a real disc light.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from vtkillum.core.refraction.environment import Environment, environment_lookup
from vtkillum.core.refraction.preintegration import (
    RefractiveMedium,
    segment_extinction,
    segment_source,
)
from vtkillum.core.refraction.ray_equation import (
    MIN_COS,
    Frame,
    camera_eta_gradient,
    eta_at,
    ray_step,
    to_local,
)
from vtkillum.core.warp_common import hg_phase, inside_box, ray_box, sample_scalar

#: Largest angle between the light's travel direction and the view direction (paper: artefacts
#: appear beyond 85° with view-aligned planes).
MAX_LIGHT_ANGLE = 85.0

#: View-ray states.
MISSED = wp.constant(0)
ACTIVE = wp.constant(1)
DONE = wp.constant(2)

#: Light buffers cycle through three layers (see the module docstring).
LAYERS = 3

#: The Newton step of the backward integration is used where |det(I + J)| exceeds this and
#: it moves the lookup by at most this ratio times (the first estimate + one texel).
NEWTON_MIN_DET = wp.constant(0.05)
NEWTON_MAX_RATIO = wp.constant(4.0)


@wp.struct
class SweepParams:
    """Everything per frame that the sweep kernels read, in one device record.

    Kept in a one-element device array (not passed by value) so that a captured
    CUDA graph of the launches can be replayed for a new camera, light or softness.
    """

    frame: Frame  # camera frame in the volume's local frame
    world_right: wp.vec3  # the camera axes in world space (environment lookups)
    world_up: wp.vec3
    world_forward: wp.vec3
    parallel: int
    tan_half: float
    aspect: float
    parallel_scale: float
    width: int
    height: int
    z0: float  # depth of plane 0 along forward, world units
    dz: float  # plane spacing
    planes: int
    light_dir: wp.vec3  # unit travel direction, camera frame
    light_rgb: wp.vec3  # irradiance perpendicular to the light
    grid_origin: wp.vec2  # q0: camera (x, y) of texel (0, 0) on plane 0
    shift: wp.vec2  # per-plane shift of the texel grid
    texel: float  # h, world units
    nx: int
    ny: int
    softness: float  # tan of the light's angular radius
    direction_blur: float  # the same for the direction filter
    intensity_correction: int
    max_concentration: float  # largest intensity gain of the intensity law
    specular: float  # weight of the Cook–Torrance term
    roughness: float  # Beckmann slope RMS
    stop_alpha: float  # view rays stop computing past this opacity
    seed: int
    composite_background: int  # 1: radiance includes the (environment) background
    background: wp.vec3


@dataclass
class SweepGeometry:
    """Host description of one frame's planes and light grid (world units)."""

    z0: float
    dz: float
    planes: int
    light_dir: np.ndarray  # camera frame
    shift: np.ndarray
    grid_origin: np.ndarray
    texel: float
    nx: int
    ny: int

    @property
    def texels(self) -> int:
        return self.nx * self.ny


def light_angle(light_direction, view_direction) -> float:
    """Angle in degrees between a light's travel direction and the camera's view direction."""
    a = np.asarray(light_direction, np.float64)
    b = np.asarray(view_direction, np.float64)
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def sweep_geometry(volume, camera, width: int, height: int, light_direction, dz: float,
                   light_buffer_scale: float = 1.0, blur: float = 0.0,
                   max_texels: int | None = None) -> SweepGeometry:
    """Planes and light grid of a frame.

    Parameters
    ----------
    volume : Volume
    camera : Camera
    width, height : int
        Image size (sets the light texel size, see the module docstring).
    light_direction : (3,) float
        The light's travel direction (world).
    dz : float
        Plane spacing (world units).
    light_buffer_scale : float
        Texel size relative to the pixel footprint at the volume's centre depth.
    blur : float
        Largest of ``softness`` and ``direction_blur`` (widens the grid's margin).
    max_texels : int, optional
        Cap on the grid size (default ``4 W H``, at least ``256²``): the texels grow
        beyond it.
    """
    r, u, f = (volume.to_local_direction(a) for a in camera.basis())
    R = np.stack([r, u, f])  # local -> camera
    cam = volume.to_local(camera.position)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)],
                       np.float64) * volume.extent
    c = (corners - cam) @ R.T
    zmin, zmax = float(c[:, 2].min()), float(c[:, 2].max())
    near = 0.0 if camera.parallel_projection else 1e-3 * dz
    z0 = max(zmin, near)
    planes = int(np.ceil((zmax - z0) / dz)) + 1 if zmax > z0 else 1
    w = R @ volume.to_local_direction(light_direction)
    w /= np.linalg.norm(w)
    shift = w[:2] * dz / w[2]
    q = c[:, :2] - ((c[:, 2] - z0) / dz)[:, None] * shift
    if camera.parallel_projection:
        footprint = 2.0 * camera.parallel_scale / height
    else:
        depth = max(float((volume.extent / 2 - cam) @ f), dz)
        footprint = 2.0 * depth * np.tan(np.radians(camera.view_angle) / 2) / height
    h = float(light_buffer_scale) * footprint
    span = q.max(0) - q.min(0)
    max_texels = int(max_texels or max(4 * width * height, 256 * 256))
    radius = blur * dz / max(w[2], 0.1) ** 2

    def dims(h):
        margin = 2 + int(np.ceil(radius / h))
        return np.ceil(span / h).astype(int) + 1 + 2 * margin, margin

    n, margin = dims(h)
    while n[0] * n[1] > max_texels:
        h *= 1.1
        n, margin = dims(h)
    origin = q.min(0) - margin * h
    return SweepGeometry(z0, float(dz), planes, w, shift, origin, h, int(n[0]), int(n[1]))


def make_params(volume, camera, width: int, height: int, geometry: SweepGeometry, light_rgb,
                opts: dict, background) -> SweepParams:
    """Fill the per-frame record (``opts``: the parsed method options)."""
    r, u, f = camera.basis()
    frame = Frame()
    frame.origin = wp.vec3(*volume.to_local(camera.position).astype(np.float32))
    frame.right, frame.up, frame.forward = (
        wp.vec3(*volume.to_local_direction(a).astype(np.float32)) for a in (r, u, f))
    p = SweepParams()
    p.frame = frame
    p.world_right, p.world_up, p.world_forward = (wp.vec3(*a.astype(np.float32)) for a in (r, u, f))
    p.parallel = int(camera.parallel_projection)
    p.tan_half = float(np.tan(np.radians(camera.view_angle) / 2))
    p.aspect = float(width) / float(height)
    p.parallel_scale = float(camera.parallel_scale)
    p.width, p.height = int(width), int(height)
    p.z0, p.dz, p.planes = float(geometry.z0), float(geometry.dz), int(geometry.planes)
    p.light_dir = wp.vec3(*geometry.light_dir.astype(np.float32))
    p.light_rgb = wp.vec3(*np.asarray(light_rgb, np.float32))
    p.grid_origin = wp.vec2(*geometry.grid_origin.astype(np.float32))
    p.shift = wp.vec2(*geometry.shift.astype(np.float32))
    p.texel = float(geometry.texel)
    p.nx, p.ny = int(geometry.nx), int(geometry.ny)
    p.softness = float(opts["softness"])
    p.direction_blur = float(opts["direction_blur"])
    p.intensity_correction = int(opts["intensity_correction"])
    p.max_concentration = float(opts["max_concentration"])
    p.specular = float(opts["specular"])
    p.roughness = float(opts["roughness"])
    p.stop_alpha = float(opts["early_termination"])
    p.seed = int(opts["seed"])
    p.composite_background = int(opts["composite_background"])
    p.background = wp.vec3(*np.asarray(background, np.float32))
    return p


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


# --- device functions: the light buffer ---------------------------------------------------------
@wp.struct
class LightBuffers:
    """The light buffers, ``(LAYERS, capacity)`` each, texel ``b * nx + a`` (camera frame).

    ``l``: light colour, the irradiance perpendicular to the ray (intensity-corrected);
    ``v``: ray direction ``η dx/ds`` (unnormalised); ``g``: ``∇η`` at the texel;
    ``p``: the ray tube's cross-section ``dX/dX0`` (2x2, columns, in-plane): how a texel
    cell of plane 0 has been mapped onto this plane, for the intensity law.
    """

    l: wp.array2d(dtype=wp.vec3)
    v: wp.array2d(dtype=wp.vec3)
    g: wp.array2d(dtype=wp.vec3)
    p: wp.array2d(dtype=wp.vec4)


@wp.func
def light_fetch(buf: wp.array2d(dtype=Any), layer: int, p: SweepParams, a: int, b: int,
                outside: Any):
    """Texel ``(a, b)`` of ``layer``, or ``outside`` (what the unobstructed light carries)
    beyond the grid."""
    if a < 0 or b < 0 or a >= p.nx or b >= p.ny:
        return outside
    return buf[layer, b * p.nx + a]


@wp.func
def light_bilinear(buf: wp.array2d(dtype=Any), layer: int, p: SweepParams, x: float, y: float,
                   outside: Any):
    """Bilinear lookup at continuous texel coordinates ``(x, y)`` (``outside`` beyond the grid)."""
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    a = int(x0)
    b = int(y0)
    fx = x - x0
    fy = y - y0
    bottom = wp.lerp(light_fetch(buf, layer, p, a, b, outside),
                     light_fetch(buf, layer, p, a + 1, b, outside), fx)
    top = wp.lerp(light_fetch(buf, layer, p, a, b + 1, outside),
                  light_fetch(buf, layer, p, a + 1, b + 1, outside), fx)
    return wp.lerp(bottom, top, fy)


@wp.func
def light_filtered(buf: wp.array2d(dtype=Any), layer: int, p: SweepParams, x: float, y: float,
                   outside: Any, radius: float, major: wp.vec2, stretch: float, phi: float):
    """Three-sample elliptical kernel (Patel et al. 2013) around texel coordinates ``(x, y)``.

    ``radius`` is the cone's radius on the plane (texels), ``major`` the unit direction in
    which the ellipse is stretched by ``stretch = 1/cos θ``, ``phi`` the random rotation.
    Samples sit at ``radius/√2`` (the kernel then has a uniform disc's variance), 120°
    apart. ``radius = 0``: one bilinear lookup.
    """
    if radius <= 0.0:
        return light_bilinear(buf, layer, p, x, y, outside)
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
    c0 = light_bilinear(buf, layer, p, x + s0[0], y + s0[1], outside)
    c1 = light_bilinear(buf, layer, p, x + s1[0], y + s1[1], outside)
    c2 = light_bilinear(buf, layer, p, x + s2[0], y + s2[1], outside)
    # Written so that three equal samples give exactly that value (no drift with η ≡ 1).
    return c0 + ((c1 - c0) + (c2 - c0)) * (1.0 / 3.0)


@wp.func
def plane_offset(v: wp.vec3, dz: float):
    """In-plane displacement ``(x, y)`` of a ray along ``v`` over one plane spacing."""
    c = wp.normalize(v)
    cz = wp.max(c[2], MIN_COS)
    return wp.vec2(c[0], c[1]) * (dz / cz)


@wp.func
def texel_position(p: SweepParams, a: float, b: float, j: int):
    """Camera-frame position of (continuous) texel ``(a, b)`` of plane ``j``."""
    return wp.vec3(p.grid_origin[0] + a * p.texel + float(j) * p.shift[0],
                   p.grid_origin[1] + b * p.texel + float(j) * p.shift[1],
                   p.z0 + float(j) * p.dz)


@wp.func
def texel_coordinates(p: SweepParams, q: wp.vec3, j: int):
    """Continuous texel coordinates of camera-frame point ``q`` on plane ``j``."""
    inv = 1.0 / p.texel
    return wp.vec2((q[0] - p.grid_origin[0] - float(j) * p.shift[0]) * inv,
                   (q[1] - p.grid_origin[1] - float(j) * p.shift[1]) * inv)


@wp.func
def chord_estimate(v: wp.vec3, g: wp.vec3, dz: float):
    """Direction of the chord to the next plane of a ray with direction ``v`` and ``∇η = g``:
    ``v`` plus the first half kick of the Verlet step (``v + ∇η ds/2``)."""
    c = wp.normalize(v)
    return v + g * (0.5 * dz / wp.max(c[2], MIN_COS))


@wp.func
def neighbour_offset(lb: LightBuffers, layer: int, p: SweepParams, a: int, b: int, v0: wp.vec3):
    """In-plane displacement to the next plane of the ray leaving texel ``(a, b)``."""
    g = light_fetch(lb.g, layer, p, a, b, wp.vec3(0.0))
    return plane_offset(chord_estimate(light_fetch(lb.v, layer, p, a, b, v0), g, p.dz), p.dz)


@wp.func
def segment_transmission(m: RefractiveMedium, frame: Frame, qa: wp.vec3, qb: wp.vec3,
                         length: float, sa_in: float, sb_in: float, have_sa: int, have_sb: int):
    """Pre-integrated extinction over the part of segment ``qa → qb`` (camera frame) inside the
    box: returns ``(mean (σt, κ), inside length, s at the clipped start, s at the clipped end)``.

    ``sa_in``/``sb_in`` are the data values at the ends when ``have_sa``/``have_sb`` say they
    are known (saves samples).
    """
    a = to_local(frame, qa)
    b = to_local(frame, qb)
    d = b - a
    tt = ray_box(a, d, m.extent)
    t0 = wp.max(tt[0], 0.0)
    t1 = wp.min(tt[1], 1.0)
    if t0 >= t1:
        return wp.vec4(0.0), 0.0, 0.0, 0.0
    sa = sa_in
    if t0 > 0.0 or have_sa == 0:
        sa = sample_scalar(m.scalars, m.inv_spacing, a + t0 * d)
    sb = sb_in
    if t1 < 1.0 or have_sb == 0:
        sb = sample_scalar(m.scalars, m.inv_spacing, a + t1 * d)
    return segment_extinction(m, sa, sb), (t1 - t0) * length, sa, sb


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


@wp.func
def propagate_light(m: RefractiveMedium, p: SweepParams, j: int, t: int, lb: LightBuffers):
    """Light texel ``t`` of plane ``j`` (Algorithm 1, lines 7–18)."""
    b = t / p.nx
    a = t - b * p.nx
    wr = j % 3
    x = texel_position(p, float(a), float(b), j)
    g_x = camera_eta_gradient(m, p.frame, x)
    v0 = p.light_dir * m.eta_outside
    zero = wp.vec3(0.0)
    unit = wp.vec4(1.0, 0.0, 0.0, 1.0)
    if j == 0:
        lb.l[wr, t] = p.light_rgb
        lb.v[wr, t] = v0
        lb.g[wr, t] = g_x
        lb.p[wr, t] = unit
        return
    rd = (j + 2) % 3
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
        oe = neighbour_offset(lb, rd, p, a + 1, b, v0)
        ow = neighbour_offset(lb, rd, p, a - 1, b, v0)
        on = neighbour_offset(lb, rd, p, a, b + 1, v0)
        os = neighbour_offset(lb, rd, p, a, b - 1, v0)
        delta = plane_offset(chord_estimate(lb.v[rd, t], lb.g[rd, t], p.dz), p.dz) - off0
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
    l_in = light_filtered(lb.l, rd, p, la, lb_, p.light_rgb, p.softness * ds * inv_h, major,
                          1.0 / cz, phi)
    v_in = light_filtered(lb.v, rd, p, la, lb_, v0, p.direction_blur * ds * inv_h, major,
                          1.0 / cz, phi)
    g_in = light_bilinear(lb.g, rd, p, la, lb_, zero)
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
        p_in = light_bilinear(lb.p, rd, p, la, lb_, unit)
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
    ext, inside, _sa, _sb = segment_transmission(m, p.frame, lp, x, ds, 0.0, 0.0, 0, 0)
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
    lb.g[wr, t] = g_x
    lb.p[wr, t] = p_new


@wp.func
def light_at(m: RefractiveMedium, p: SweepParams, lb: LightBuffers, q: wp.vec3, j: int):
    """Light colour and direction of plane ``j`` at camera-frame point ``q`` (bilinear)."""
    c = texel_coordinates(p, q, j)
    layer = j % 3
    return (light_bilinear(lb.l, layer, p, c[0], c[1], p.light_rgb),
            light_bilinear(lb.v, layer, p, c[0], c[1], p.light_dir * m.eta_outside))


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


@wp.func
def world_direction(p: SweepParams, v: wp.vec3):
    """Unit world direction of camera-frame vector ``v``."""
    return wp.normalize(v[0] * p.world_right + v[1] * p.world_up + v[2] * p.world_forward)
