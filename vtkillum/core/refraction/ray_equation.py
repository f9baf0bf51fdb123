"""The ray equation of geometric optics in a refractive-index field (paper eqs. 6–8).

A ray in a medium of refractive index ``η(x)`` obeys ``d/ds (η dx/ds) = ∇η``
(eq. 6). With ``v = η dx/ds`` this is the first-order system (eq. 7)

    dx/ds = v / η,      dv/ds = ∇η,

which the paper (after Ihrke et al. 2007) discretises with explicit steps
(eq. 8). Here rays advance from one sweep plane to the next (planes perpendicular
to the camera's view direction ``f``, ``dz`` apart), so a step's arc length is
``ds = dz / cos θ`` with ``θ`` the angle between the ray and ``f``, and the step
is a kick–drift–kick (velocity Verlet) version of eq. 8:

    v½ = v + ∇η(x) ds/2,   x' = x + ds v½/|v½|,   v' = v½ + ∇η(x') ds/2.

It is symplectic and second order, and costs one gradient per step as the
paper's Euler step does (the gradient at the new point is kept for the next
step). The position moves along the unit tangent ``v/|v|``, which equals the
paper's ``v/η`` while ``|v| = η``; ``|v|`` starts at η of the ray's starting
medium. A linear-gradient slab bends a ray along the catenary
``y = (η₀/g)(cosh(g x/η₀) - 1) ≈ g x²/(2η₀)`` (tested).

``∇η`` is the central difference of ``η_tf`` applied to the data values one
voxel either side (paper section 5: "by applying η_tf to the neighboring data
values before computing the central differences"); outside the volume's box it
is zero and η is the index of the surrounding space
(:attr:`RefractiveMedium.eta_outside`).

Positions and directions of the sweep live in the camera frame
(:class:`Frame`: right, up, forward); volume samples in the local frame.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.refraction.preintegration import (
    RefractiveMedium,
    make_refractive_medium,
    table_coordinate,
    table_value,
)
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.warp_common import inside_box, sample_scalar

#: Rays that turn more than this from the sweep direction stop (cos of 87°): they no
#: longer reach the next plane in a bounded number of steps.
MIN_COS = wp.constant(0.05)


@wp.struct
class Frame:
    """A camera frame in the volume's local frame: ``origin`` and unit ``right``, ``up``,
    ``forward`` (the sweep direction). Camera coordinates ``(x, y, z)`` are the point
    ``origin + x right + y up + z forward``."""

    origin: wp.vec3
    right: wp.vec3
    up: wp.vec3
    forward: wp.vec3


def trace_rays(volume, optics, origins, directions, forward, dz: float, steps: int,
               device: str | None = None) -> np.ndarray:
    """Trace rays through the refractive-index field, plane to plane (for tests and tools).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    optics : vtkillum.core.refraction.optics.RefractiveOptics
    origins, directions : ndarray (n, 3)
        Start points and directions in the volume's *local* frame (world units). The
        start points lie on the first plane.
    forward : (3,) float
        Normal of the planes (local frame); directions must have a positive component
        along it.
    dz : float
        Plane spacing (world units).
    steps : int
        Number of plane-to-plane steps.

    Returns
    -------
    ndarray (steps + 1, n, 3) float64
        Positions on the planes (local frame); rays that turned away from ``forward``
        by more than 87° repeat their last position.
    """
    device = resolve_device(device)
    if not (np.isfinite(dz) and dz > 0):
        raise ValueError(f"dz must be positive, got {dz}")
    origins = np.atleast_2d(np.asarray(origins, dtype=np.float64))
    directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0] if abs(f[2]) < 0.9 else [1.0, 0.0, 0.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    frame = Frame()
    frame.origin = wp.vec3(0.0, 0.0, 0.0)
    frame.right, frame.up, frame.forward = (wp.vec3(*a.astype(np.float32)) for a in (r, u, f))
    R = np.stack([r, u, f])  # local -> camera coordinates
    tf = TransferFunction([0.0], [0.0])
    medium = make_refractive_medium(volume, tf, optics, volume.mean_spacing(), device=device)
    pos = wp.array((origins @ R.T).astype(np.float32), dtype=wp.vec3, device=device)
    dirs = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    vel = wp.array((dirs @ R.T).astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.zeros((int(steps) + 1, len(origins)), dtype=wp.vec3, device=device)
    wp.launch(trace_kernel, dim=len(origins), inputs=[medium, frame, pos, vel, float(dz),
                                                      int(steps), out], device=device)
    return out.numpy().astype(np.float64) @ R


# --- device functions ---------------------------------------------------------------------------
@wp.func
def to_local(frame: Frame, p: wp.vec3):
    """Local-frame position of camera-frame point ``p``."""
    return frame.origin + p[0] * frame.right + p[1] * frame.up + p[2] * frame.forward


@wp.func
def to_camera(frame: Frame, d: wp.vec3):
    """Camera-frame components of local-frame vector ``d``."""
    return wp.vec3(wp.dot(d, frame.right), wp.dot(d, frame.up), wp.dot(d, frame.forward))


@wp.func
def eta_of_value(m: RefractiveMedium, s: float):
    """``η_tf(s)``."""
    return table_value(m.eta, table_coordinate(m, s))


@wp.func
def eta_at(m: RefractiveMedium, p: wp.vec3):
    """Refractive index at local position ``p`` (the surrounding space's outside the box)."""
    if not inside_box(p, m.extent):
        return m.eta_outside
    return eta_of_value(m, sample_scalar(m.scalars, m.inv_spacing, p))


@wp.func
def eta_gradient(m: RefractiveMedium, p: wp.vec3):
    """``∇η`` at local position ``p`` (1/world units, local frame): central differences of
    ``η_tf`` of the data one voxel either side; zero outside the box or where η is constant."""
    if m.eta_varies == 0:
        return wp.vec3(0.0)
    if not inside_box(p, m.extent):
        return wp.vec3(0.0)
    hx = wp.vec3(m.spacing[0], 0.0, 0.0)
    hy = wp.vec3(0.0, m.spacing[1], 0.0)
    hz = wp.vec3(0.0, 0.0, m.spacing[2])
    a = m.scalars
    inv = m.inv_spacing
    return wp.vec3(
        (eta_of_value(m, sample_scalar(a, inv, p + hx))
         - eta_of_value(m, sample_scalar(a, inv, p - hx))) * (0.5 * inv[0]),
        (eta_of_value(m, sample_scalar(a, inv, p + hy))
         - eta_of_value(m, sample_scalar(a, inv, p - hy))) * (0.5 * inv[1]),
        (eta_of_value(m, sample_scalar(a, inv, p + hz))
         - eta_of_value(m, sample_scalar(a, inv, p - hz))) * (0.5 * inv[2]),
    )


@wp.func
def camera_eta_gradient(m: RefractiveMedium, frame: Frame, p: wp.vec3):
    """``∇η`` at camera-frame point ``p``, in camera-frame components."""
    if m.eta_varies == 0:
        return wp.vec3(0.0)
    return to_camera(frame, eta_gradient(m, to_local(frame, p)))


@wp.func
def lerp_cell(c000: float, c100: float, c010: float, c110: float, c001: float, c101: float,
              c011: float, c111: float, f: wp.vec3):
    """Trilinear interpolation of one cell's corners (``cXYZ``), in the order of
    :func:`~vtkillum.core.warp_common.trilinear` (x, then y, then z)."""
    return wp.lerp(wp.lerp(wp.lerp(c000, c100, f[0]), wp.lerp(c010, c110, f[0]), f[1]),
                   wp.lerp(wp.lerp(c001, c101, f[0]), wp.lerp(c011, c111, f[0]), f[1]), f[2])


@wp.func
def sample_and_gradient(m: RefractiveMedium, p: wp.vec3):
    """Data value and ``∇η`` (local frame) at local position ``p``: ``(s, ∇η, inside)``.

    The value of :func:`sample_scalar` and the gradient of :func:`eta_gradient` from
    one stencil: the seven trilinear samples (``p`` and ``p ± one voxel`` per axis)
    share their cells, so away from the faces they read 32 distinct voxels instead of
    56 (the sweep's cost is these loads). Outside the box ``s = 0`` and ``∇η = 0``;
    within two voxels of a face the samples are taken one by one (clamped cells).
    """
    if not inside_box(p, m.extent):
        return 0.0, wp.vec3(0.0), 0
    a = m.scalars
    inv = m.inv_spacing
    if m.eta_varies == 0:
        return sample_scalar(a, inv, p), wp.vec3(0.0), 1
    u = wp.cw_mul(p, inv)
    i = int(wp.floor(u[0]))
    j = int(wp.floor(u[1]))
    k = int(wp.floor(u[2]))
    if (i < 1 or j < 1 or k < 1 or i > a.shape[0] - 3 or j > a.shape[1] - 3
            or k > a.shape[2] - 3):
        return sample_scalar(a, inv, p), eta_gradient(m, p), 1
    f = wp.vec3(u[0] - float(i), u[1] - float(j), u[2] - float(k))
    # The cell of p ...
    c000 = a[i, j, k]
    c100 = a[i + 1, j, k]
    c010 = a[i, j + 1, k]
    c110 = a[i + 1, j + 1, k]
    c001 = a[i, j, k + 1]
    c101 = a[i + 1, j, k + 1]
    c011 = a[i, j + 1, k + 1]
    c111 = a[i + 1, j + 1, k + 1]
    # ... and the faces one voxel beyond it on either side of each axis.
    xm00 = a[i - 1, j, k]
    xm10 = a[i - 1, j + 1, k]
    xm01 = a[i - 1, j, k + 1]
    xm11 = a[i - 1, j + 1, k + 1]
    xp00 = a[i + 2, j, k]
    xp10 = a[i + 2, j + 1, k]
    xp01 = a[i + 2, j, k + 1]
    xp11 = a[i + 2, j + 1, k + 1]
    ym00 = a[i, j - 1, k]
    ym10 = a[i + 1, j - 1, k]
    ym01 = a[i, j - 1, k + 1]
    ym11 = a[i + 1, j - 1, k + 1]
    yp00 = a[i, j + 2, k]
    yp10 = a[i + 1, j + 2, k]
    yp01 = a[i, j + 2, k + 1]
    yp11 = a[i + 1, j + 2, k + 1]
    zm00 = a[i, j, k - 1]
    zm10 = a[i + 1, j, k - 1]
    zm01 = a[i, j + 1, k - 1]
    zm11 = a[i + 1, j + 1, k - 1]
    zp00 = a[i, j, k + 2]
    zp10 = a[i + 1, j, k + 2]
    zp01 = a[i, j + 1, k + 2]
    zp11 = a[i + 1, j + 1, k + 2]
    s = lerp_cell(c000, c100, c010, c110, c001, c101, c011, c111, f)
    sxp = lerp_cell(c100, xp00, c110, xp10, c101, xp01, c111, xp11, f)
    sxm = lerp_cell(xm00, c000, xm10, c010, xm01, c001, xm11, c011, f)
    syp = lerp_cell(c010, c110, yp00, yp10, c011, c111, yp01, yp11, f)
    sym = lerp_cell(ym00, ym10, c000, c100, ym01, ym11, c001, c101, f)
    szp = lerp_cell(c001, c101, c011, c111, zp00, zp10, zp01, zp11, f)
    szm = lerp_cell(zm00, zm10, zm01, zm11, c000, c100, c010, c110, f)
    g = wp.vec3((eta_of_value(m, sxp) - eta_of_value(m, sxm)) * (0.5 * inv[0]),
                (eta_of_value(m, syp) - eta_of_value(m, sym)) * (0.5 * inv[1]),
                (eta_of_value(m, szp) - eta_of_value(m, szm)) * (0.5 * inv[2]))
    return s, g, 1


@wp.func
def camera_sample_and_gradient(m: RefractiveMedium, frame: Frame, p: wp.vec3):
    """:func:`sample_and_gradient` at camera-frame point ``p``: ``(s, ∇η in camera-frame
    components, inside)``."""
    s, g, inside = sample_and_gradient(m, to_local(frame, p))
    return s, to_camera(frame, g), inside


@wp.func
def ray_step(m: RefractiveMedium, frame: Frame, p: wp.vec3, v: wp.vec3, g: wp.vec3, dz: float):
    """One kick–drift–kick step of the ray equation to the next plane (``dz`` further along
    the camera's forward axis).

    ``p``, ``v`` and ``g = ∇η(p)`` are in camera coordinates. Returns the new
    ``(p, v, ∇η(p), s(p), inside, arc length, ok)`` (``s`` the data value, 0 and
    ``inside = 0`` outside the box); ``ok`` is 0 when the ray turned more than 87° away
    from the sweep direction (it is then left where it was).
    """
    t = wp.normalize(v)
    if t[2] < MIN_COS:
        return p, v, g, 0.0, 0, 0.0, 0
    v_half = v + g * (0.5 * dz / t[2])
    c = wp.normalize(v_half)
    if c[2] < MIN_COS:
        return p, v, g, 0.0, 0, 0.0, 0
    ds = dz / c[2]
    p_new = p + c * ds
    s_new, g_new, inside = camera_sample_and_gradient(m, frame, p_new)
    return p_new, v_half + g_new * (0.5 * ds), g_new, s_new, inside, ds, 1


# --- kernel -------------------------------------------------------------------------------------
@wp.kernel
def trace_kernel(m: RefractiveMedium, frame: Frame, pos: wp.array(dtype=wp.vec3),
                 dirs: wp.array(dtype=wp.vec3), dz: float, steps: int,
                 out: wp.array2d(dtype=wp.vec3)):
    """Trace one ray per thread; ``wp.tid()`` indexes the rays.

    ``pos`` and ``dirs`` are camera-frame start points and unit directions (world
    units); ``out[k, ray]`` receives the position on plane ``k`` (camera frame).
    ``|v|`` starts at η of the start point.
    """
    i = wp.tid()
    p = pos[i]
    v = dirs[i] * eta_at(m, to_local(frame, p))
    g = camera_eta_gradient(m, frame, p)
    out[0, i] = p
    for k in range(steps):
        p2, v2, g2, _s, _inside, _ds, ok = ray_step(m, frame, p, v, g, dz)
        if ok != 0:
            p = p2
            v = v2
            g = g2
        out[k + 1, i] = p
