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
values before computing the central differences"): seven trilinear fetches of the
data texture (:func:`~vtkillum.core.refraction.preintegration.data_texture`); outside
the volume's box it is zero and η is the index of the surrounding space
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
    data_coordinate,
    data_fetch,
    data_value,
    make_refractive_medium,
    table_coordinate,
    table_value,
)
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.warp_common import inside_box

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
    return eta_of_value(m, data_value(m, p))


@wp.func
def sample_and_gradient(m: RefractiveMedium, p: wp.vec3):
    """Data value and ``∇η`` (local frame, 1/world units) at local position ``p``:
    ``(s, ∇η, inside)``.

    ``∇η`` is the central difference of ``η_tf`` of the data one voxel either side; the
    seven samples are fetches of the data texture (one grid unit apart in its coordinates;
    clamped to the box's faces). Outside the box ``s = 0`` and ``∇η = 0``; where η is
    constant ``∇η = 0``.
    """
    if not inside_box(p, m.extent):
        return 0.0, wp.vec3(0.0), 0
    c = data_coordinate(m, p)
    s = data_fetch(m, c)
    if m.eta_varies == 0:
        return s, wp.vec3(0.0), 1
    # Texture axes (k, j, i) hold the local axes (z, y, x).
    ex = wp.vec3(0.0, 0.0, 1.0)
    ey = wp.vec3(0.0, 1.0, 0.0)
    ez = wp.vec3(1.0, 0.0, 0.0)
    inv = m.inv_spacing
    g = wp.vec3(
        (eta_of_value(m, data_fetch(m, c + ex)) - eta_of_value(m, data_fetch(m, c - ex)))
        * (0.5 * inv[0]),
        (eta_of_value(m, data_fetch(m, c + ey)) - eta_of_value(m, data_fetch(m, c - ey)))
        * (0.5 * inv[1]),
        (eta_of_value(m, data_fetch(m, c + ez)) - eta_of_value(m, data_fetch(m, c - ez)))
        * (0.5 * inv[2]))
    return s, g, 1


@wp.func
def camera_sample_and_gradient(m: RefractiveMedium, frame: Frame, p: wp.vec3):
    """:func:`sample_and_gradient` at camera-frame point ``p``: ``(s, ∇η in camera-frame
    components, inside)``."""
    s, g, inside = sample_and_gradient(m, to_local(frame, p))
    return s, to_camera(frame, g), inside


@wp.func
def camera_eta_gradient(m: RefractiveMedium, frame: Frame, p: wp.vec3):
    """``∇η`` at camera-frame point ``p``, in camera-frame components."""
    _s, g, _inside = camera_sample_and_gradient(m, frame, p)
    return g


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
