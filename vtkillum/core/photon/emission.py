"""Photon emission: where photons leave the lights and what flux each carries.

Each of the ``N`` photons of a photon map picks one light ``l`` with probability
``p_l`` proportional to its power (the sum over RGB of the power that can reach the
volume), then a start point and direction (Jönsson et al. 2012, section 3.2: "importance
sampling is used to select from which light source the photon should be traced, and to
generate a position and direction on the chosen light source"):

* **Directional light** (travel direction ``w``, irradiance ``E``): a start point
  uniform on the rectangle that covers the volume's box projected along ``w``, on a
  plane in front of the box; direction ``w``. Power ``E · A`` with ``A`` the
  rectangle's area.
* **Point light** (intensity ``I``): a direction uniform over the cone from the light
  that holds the box's bounding sphere (solid angle ``Ω = 2π (1 - cos θ_max)``), or
  over the whole sphere (``Ω = 4π``) when the light is inside that sphere. Power
  ``I · Ω``. (Sampling the cone instead of the sphere wastes no photons on directions
  that miss the volume; the flux is the same.) Photons leave the light's centre: the
  source radius ``r`` of :mod:`vtkillum.core.lights` (irradiance ``I / max(d, r)²``)
  only matters within ``r`` of the light, where the photon estimate sees ``I / d²``.

A photon carries the RGB flux ``Φ = P_l / (N p_l)``, so that the ``N`` photons together
carry every light's power in expectation. Units: flux is irradiance × area (directional)
or intensity × steradian (point) in world units.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.lights import DIRECTIONAL, pack_lights
from vtkillum.core.warp_common import orthonormal_basis, uniform, upload_packed

init_warp()


@wp.struct
class Emitters:
    """Light sampling tables on the device (local frame of the volume).

    ``origin[l]``: corner of the start rectangle (directional) or the light's position
    (point); ``edge_u``, ``edge_v``: the rectangle's edges (directional); ``direction``:
    travel direction (directional) or the cone's axis (point); ``cos_max``: cosine of the
    cone's half angle (-1: whole sphere); ``flux``: RGB flux per photon; ``cdf``:
    cumulative selection probability.
    """

    kind: wp.array(dtype=wp.int32)
    origin: wp.array(dtype=wp.vec3)
    edge_u: wp.array(dtype=wp.vec3)
    edge_v: wp.array(dtype=wp.vec3)
    direction: wp.array(dtype=wp.vec3)
    cos_max: wp.array(dtype=wp.float32)
    flux: wp.array(dtype=wp.vec3)
    cdf: wp.array(dtype=wp.float32)
    count: int


def make_emitters(lights, volume, n_photons: int, device: str) -> tuple[Emitters, dict]:
    """Build :class:`Emitters` for ``n_photons`` photons and say how power is split.

    Parameters
    ----------
    lights : sequence of DirectionalLight / PointLight
        World-space lights.
    volume : vtkillum.core.volume.Volume
        Gives the box (local frame) the photons are aimed at.
    n_photons : int
        Photons in the map (the flux per photon is divided by it).
    device : str
        Warp device.

    Returns
    -------
    emitters : Emitters
    info : dict
        ``power`` (n_lights, 3) reaching the box's bounding region per light,
        ``probability`` (n_lights,) of picking each light.
    """
    kinds, vecs, rgb = pack_lights(lights, volume.direction, volume.origin)
    extent = np.asarray(volume.extent, np.float64)
    centre = extent / 2
    radius = float(np.linalg.norm(extent)) / 2
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) * extent
    n = len(kinds)
    origin = np.zeros((n, 3))
    edge_u = np.zeros((n, 3))
    edge_v = np.zeros((n, 3))
    direction = np.zeros((n, 3))
    cos_max = -np.ones(n)
    power = np.zeros((n, 3))
    for li in range(n):
        v = vecs[li].astype(np.float64)
        if kinds[li] == DIRECTIONAL:
            w = v / np.linalg.norm(v)
            t, s = _basis(w)
            u = (corners - centre) @ t
            vv = (corners - centre) @ s
            plane = centre - 1.01 * radius * w
            origin[li] = plane + u.min() * t + vv.min() * s
            edge_u[li] = (u.max() - u.min()) * t
            edge_v[li] = (vv.max() - vv.min()) * s
            direction[li] = w
            power[li] = rgb[li] * (u.max() - u.min()) * (vv.max() - vv.min())
        else:
            origin[li] = v
            to_centre = centre - v
            dist = float(np.linalg.norm(to_centre))
            if dist > radius * 1.0001:
                cos_max[li] = np.sqrt(max(0.0, 1.0 - (radius / dist) ** 2))
                direction[li] = to_centre / dist
            else:
                direction[li] = (0.0, 0.0, 1.0)
            power[li] = rgb[li] * 2.0 * np.pi * (1.0 - cos_max[li])
    weight = power.sum(axis=1)
    total = float(weight.sum())
    prob = weight / total if total > 0 else np.full(n, 1.0 / max(n, 1))
    flux = np.zeros((n, 3))
    for li in range(n):
        if prob[li] > 0:
            flux[li] = power[li] / (n_photons * prob[li])
    cdf = np.cumsum(prob)
    cdf[-1] = 1.0
    em = Emitters()
    (em.kind, em.origin, em.edge_u, em.edge_v, em.direction, em.cos_max, em.flux,
     em.cdf) = upload_packed([(kinds, wp.int32), (origin, wp.vec3), (edge_u, wp.vec3),
                              (edge_v, wp.vec3), (direction, wp.vec3), (cos_max, wp.float32),
                              (flux, wp.vec3), (cdf, wp.float32)], device)
    em.count = n
    return em, {"power": power, "probability": prob}


def _basis(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(w, a)
    t /= np.linalg.norm(t)
    return t, np.cross(w, t)


@wp.func
def emit_photon(em: Emitters, state: wp.uint32):
    """Pick a light and sample a photon's start point, direction and flux.

    Returns ``(origin, unit direction, RGB flux, state)`` in the local frame.
    """
    u, state = uniform(state)
    li = int(0)
    while li < em.count - 1 and u >= em.cdf[li]:
        li += 1
    u1, state = uniform(state)
    u2, state = uniform(state)
    if em.kind[li] == 0:
        o = em.origin[li] + u1 * em.edge_u[li] + u2 * em.edge_v[li]
        return o, em.direction[li], em.flux[li], state
    cos_t = 1.0 - u1 * (1.0 - em.cos_max[li])
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * wp.pi * u2
    axis = em.direction[li]
    t, s = orthonormal_basis(axis)
    d = wp.normalize(sin_t * wp.cos(phi) * t + sin_t * wp.sin(phi) * s + cos_t * axis)
    return em.origin[li], d, em.flux[li], state
