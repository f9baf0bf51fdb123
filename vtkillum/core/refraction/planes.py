"""Plane geometry of the sweep: planes, the sheared light grid, the per-frame record.

Planes parallel to the image plane, ``dz`` apart along the camera's view direction
``f`` (the paper's sample distance times the smallest voxel spacing), cover the
volume's box from its nearest to its farthest point. Positions and directions of
the sweep are in the camera frame (:class:`~vtkillum.core.refraction.ray_equation.Frame`,
the paper's "viewing coordinates").

The light buffer is a regular grid of texels on each plane, sheared along the
light's initial direction: texel ``(a, b)`` of plane ``j`` lies at camera
coordinates ``q0 + h (a, b) + j shift`` with ``shift = dz (ω_x, ω_y) / ω_z``. A
straight light ray therefore goes from texel to texel: with η ≡ 1 every backward
lookup lands on a texel centre and repeated bilinear filtering does not blur the
shadows (the paper's fragment-aligned buffers would). The grid covers the box's
shadow on the plane along the light (anything outside it is unattenuated, straight
light); its texel size ``h`` is the pixel footprint at the volume's centre depth
times ``light_buffer_scale``, so it has about as many texels over the volume as the
paper's viewport-sized buffer.

The light must travel within :data:`MAX_LIGHT_ANGLE` of the view direction (one
distant light in the camera's hemisphere, paper section 7).

Camera inside (or beside) the box: the light comes from the camera's hemisphere, so it
crosses the part of the box behind the camera before it reaches what the camera sees,
and that part casts shadows in front. The planes therefore start at the box's nearest
point even behind the camera; the view rays join the sweep at plane ``view_plane``, the
plane through the camera (parallel projection: the camera plane, where VTK's parallel
rays start; perspective: just in front of the eye), to which the plane grid is aligned.
With the camera in front of the box ``view_plane`` is 0 and plane 0 touches the box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from vtkillum.core.refraction.preintegration import (
    RefractiveMedium,
    data_value,
    segment_extinction,
)
from vtkillum.core.refraction.ray_equation import MIN_COS, Frame, to_local
from vtkillum.core.warp_common import ray_box

#: Largest angle between the light's travel direction and the view direction (paper: artefacts
#: appear beyond 85° with view-aligned planes).
MAX_LIGHT_ANGLE = 85.0


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
    view_plane: int  # the plane the view rays start on (the camera's, when inside the box)
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
    reach: int = 0  # texels a light texel reads around its straight predecessor (a bound)
    corners: np.ndarray | None = None  # the box's 8 corners, camera frame (camera_corners)
    view_plane: int = 0  # first plane of the view rays (> 0: the camera is inside the box)

    @property
    def texels(self) -> int:
        return self.nx * self.ny

#: Corner pairs of the box's 12 edges (corner ``i`` at ``((i >> 2) & 1, (i >> 1) & 1, i & 1)``).
BOX_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8)
                      if bin(a ^ b).count("1") == 1])


def camera_corners(volume, camera):
    """``(R, cam, corners)``: the rotation local → camera frame, the camera's local position
    and the box's eight corners in the camera frame (``corners[i]`` as in :data:`BOX_EDGES`)."""
    r, u, f = (volume.to_local_direction(a) for a in camera.basis())
    R = np.stack([r, u, f])
    cam = volume.to_local(camera.position)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)],
                       np.float64) * volume.extent
    return R, cam, (corners - cam) @ R.T


def plane_rects(geometry: SweepGeometry, margin: int) -> np.ndarray:
    """Per plane, the texel rectangle ``(a0, b0, a1, b1)`` (ends exclusive) that holds the
    box's cross-sections with the planes from the previous to the next one, widened by
    ``margin`` texels and clipped to the grid.

    Outside it the light of that plane is the unobstructed light (straight, not yet in the
    box) or light that has left the box for good (a straight ray leaves a convex box once),
    which no view ray inside the box reads; the light kernel computes only these texels,
    the paper's slice polygon (about a third to a half of the sheared grid). Why the slab
    between the neighbouring planes and not the plane's own cross-section: a view segment
    that enters or leaves the box between planes ``k`` and ``k + 1`` reads the light of
    both planes at its ends, outside the box, where the light is the light that has
    crossed (or will cross) it; the plane beyond the box's far face (or before its near
    face) has no cross-section of its own. ``margin`` covers what a texel inside reads
    around it: its neighbours, the bilinear and blur footprints and the bending of one
    plane.
    """
    planes = geometry.planes
    corners = geometry.corners
    origin = np.asarray(geometry.grid_origin, np.float64)
    shift = np.asarray(geometry.shift, np.float64)
    j = np.arange(planes)
    lo_z = geometry.z0 + (j - 1) * geometry.dz
    hi_z = geometry.z0 + (j + 1) * geometry.dz
    lo = np.full((planes, 2), np.inf)
    hi = np.full((planes, 2), -np.inf)
    # The box cut by the slab is a convex polytope whose vertices are the ends of the edges'
    # parts within it: its bounding rectangle is theirs.
    for e0, e1 in BOX_EDGES:
        a, b = corners[e0], corners[e1]
        if a[2] > b[2]:
            a, b = b, a
        if a[2] == b[2]:  # parallel to the planes: in the slab or not
            inside = (lo_z <= a[2]) & (a[2] <= hi_z)
            ends = [np.broadcast_to(a, (planes, 3)), np.broadcast_to(b, (planes, 3))]
        else:
            z1 = np.maximum(a[2], lo_z)
            z2 = np.minimum(b[2], hi_z)
            inside = z1 <= z2
            ends = [a + ((z - a[2]) / (b[2] - a[2]))[:, None] * (b - a) for z in (z1, z2)]
        for point in ends:
            tex = (point[:, :2] - origin - j[:, None] * shift) / geometry.texel
            lo[inside] = np.minimum(lo[inside], tex[inside])
            hi[inside] = np.maximum(hi[inside], tex[inside])
    n = np.array([geometry.nx, geometry.ny])
    empty = ~np.isfinite(lo[:, :1])
    lo = np.where(empty, 0, np.clip(np.floor(np.where(empty, 0.0, lo)) - margin, 0, n))
    hi = np.where(empty, 0, np.clip(np.ceil(np.where(empty, 0.0, hi)) + margin + 1, 0, n))
    hi = np.maximum(hi, lo)
    return np.concatenate([lo, hi], 1).astype(np.int32)


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
    R, cam, c = camera_corners(volume, camera)
    zmin, zmax = float(c[:, 2].min()), float(c[:, 2].max())
    near = 0.0 if camera.parallel_projection else 1e-3 * dz
    # Light from the box's nearest point, behind the camera too (module docstring); the
    # view rays from the plane through the camera.
    if zmin < near < zmax:  # the camera's plane cuts the box
        view_plane = int(np.ceil((near - zmin) / dz))
        z0 = near - view_plane * dz
    else:
        view_plane = 0
        z0 = max(zmin, near)
    planes = int(np.ceil((zmax - z0) / dz)) + 1 if zmax > z0 else 1
    w = R @ volume.to_local_direction(light_direction)
    w /= np.linalg.norm(w)
    shift = w[:2] * dz / w[2]
    q = c[:, :2] - ((c[:, 2] - z0) / dz)[:, None] * shift
    if camera.parallel_projection:
        footprint = 2.0 * camera.parallel_scale / height
    else:
        depth = max(float((volume.extent / 2 - cam) @ R[2]), dz)
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
    # Newton neighbours and bilinear footprint (2), the blur, one plane's bending (<= 45°).
    reach = 2 + int(np.ceil((radius + dz) / h))
    return SweepGeometry(z0, float(dz), planes, w, shift, origin, h, int(n[0]), int(n[1]),
                         reach, c, view_plane)

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
    p.view_plane = int(geometry.view_plane)
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

# --- device functions ---------------------------------------------------------------------------
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
def world_direction(p: SweepParams, v: wp.vec3):
    """Unit world direction of camera-frame vector ``v``."""
    return wp.normalize(v[0] * p.world_right + v[1] * p.world_up + v[2] * p.world_forward)

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
        sa = data_value(m, a + t0 * d)
    sb = sb_in
    if t1 < 1.0 or have_sb == 0:
        sb = data_value(m, a + t1 * d)
    return segment_extinction(m, sa, sb), (t1 - t0) * length, sa, sb
