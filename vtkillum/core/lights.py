"""Directional and point lights shared by every method.

A directional light has a *travel* direction (the way photons move) and an RGB
irradiance ``E`` per unit area perpendicular to it. A point light has a position,
an RGB intensity ``I`` and a source radius ``r``; its irradiance at distance ``d``
is ``I / max(d, r)**2``: a small sphere rather than a mathematical point, so that a
light on or next to a sample gives a bounded contribution in every method (the ray
caster, the light volumes, the path tracer and ambient scattering all evaluate it
through :func:`vtkillum.core.warp_common.light_incidence`). ``r = 0`` (the default)
means half the smallest voxel spacing of the volume it lights
(:func:`resolved_radius`).

Values are limited to what the float32 kernels can carry without overflow
(:data:`MAX_VALUE` for intensities and irradiances, :data:`MAX_COORDINATE` for
positions): a light beyond them is refused with a clear error instead of
producing infinite or NaN pixels. Point lights are checked in the units the kernels
work in (:mod:`vtkillum.core.units`: about one voxel; positions relative to the
volume), when they are packed for a kernel: a world in any length unit renders, so a
point light's world position, radius and intensity (which scales as length²) only
need to be finite in float64 (:data:`WORLD_LIMIT`, :data:`WORLD_MAX_INTENSITY`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DIRECTIONAL = 0
POINT = 1

#: Largest irradiance / intensity component: squares and sums stay finite in float32
#: (point-light intensities: in the kernels' units, see the module docstring).
MAX_VALUE = 1.0e30
#: Largest |coordinate| of a point light in the kernels' units, relative to the volume:
#: d**2 stays finite in float32.
MAX_COORDINATE = 1.0e15
#: Largest world position and radius of a point light: squares stay finite in float64
#: whatever the length unit ...
WORLD_LIMIT = 1.0e150
#: ... and its largest intensity (it scales as length², so a world of unit 1e150 needs 1e300).
WORLD_MAX_INTENSITY = 1.0e300


def _vec3(value, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be three finite numbers, got {value!r}")
    return v


def _rgb(value, name: str, limit: float = MAX_VALUE,
         why: str = "float32 rendering would overflow") -> np.ndarray:
    v = _vec3(value, name)
    if np.any(v < 0):
        raise ValueError(f"{name} must be non-negative, got {value!r}")
    if np.any(v > limit):
        raise ValueError(f"{name} must not exceed {limit:g} ({why}), got {value!r}; rescale "
                         "the lights and the exposure")
    return v


@dataclass
class DirectionalLight:
    """Distant light.

    Parameters
    ----------
    direction : (3,) float
        Direction in which the light travels (world space); normalised here.
    irradiance : (3,) float
        RGB irradiance on a surface perpendicular to ``direction``.
    """

    direction: np.ndarray
    irradiance: np.ndarray = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        d = _vec3(self.direction, "light.direction")
        n = np.linalg.norm(d)
        if n == 0:
            raise ValueError("light.direction must not be the zero vector")
        self.direction = d / n
        self.irradiance = _rgb(self.irradiance, "light.irradiance")

    kind = DIRECTIONAL

    def to_dict(self) -> dict:
        return {"type": "directional", "direction": self.direction.tolist(),
                "irradiance": self.irradiance.tolist()}


@dataclass
class PointLight:
    """Isotropic point light.

    Parameters
    ----------
    position : (3,) float
        World-space position.
    intensity : (3,) float
        RGB radiant intensity; irradiance at distance d is ``intensity / max(d, r)**2``.
        Per squared world unit: the same scene in a length unit ``s`` times smaller has
        intensities ``s²`` times larger (:mod:`vtkillum.core.units`).
    radius : float
        Source radius ``r`` in world units (>= 0); 0 (default): half the smallest
        voxel spacing of the volume being lit.
    """

    position: np.ndarray
    intensity: np.ndarray = (1.0, 1.0, 1.0)
    radius: float = 0.0

    def __post_init__(self) -> None:
        self.position = _vec3(self.position, "light.position")
        if np.any(np.abs(self.position) > WORLD_LIMIT):
            raise ValueError(
                f"light.position must lie within {WORLD_LIMIT:g} world units of the origin, "
                f"got {self.position.tolist()}; a light that far away is a directional light")
        self.intensity = _rgb(self.intensity, "light.intensity", WORLD_MAX_INTENSITY,
                              "the largest float64 intensity with headroom")
        try:
            radius = float(self.radius)
        except (TypeError, ValueError):
            radius = float("nan")
        if not (np.isfinite(radius) and 0.0 <= radius <= WORLD_LIMIT):
            raise ValueError(f"light.radius must be a non-negative number of world units (0: "
                             f"half a voxel), got {self.radius!r}")
        self.radius = radius

    kind = POINT

    def to_dict(self) -> dict:
        d = {"type": "point", "position": self.position.tolist(),
             "intensity": self.intensity.tolist()}
        if self.radius > 0:
            d["radius"] = self.radius
        return d


Light = DirectionalLight | PointLight


def light_from_dict(d: dict, index: int = 0) -> Light:
    """Build a light from its scene-file object; errors name ``lights[index].field``."""
    where = f"lights[{index}]"
    if not isinstance(d, dict) or "type" not in d:
        raise ValueError(f"{where}: expected an object with a 'type' of 'directional' or 'point'")
    kind = d["type"]
    fields = {"directional": {"direction", "irradiance"},
              "point": {"position", "intensity", "radius"}}
    if kind not in fields:
        raise ValueError(f"{where}.type: {kind!r} is not 'directional' or 'point'")
    unknown = set(d) - fields[kind] - {"type"}
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {sorted(unknown)} for a {kind} light")
    try:
        if kind == "directional":
            if "direction" not in d:
                raise ValueError("direction is missing")
            return DirectionalLight(d["direction"], d.get("irradiance", (1.0, 1.0, 1.0)))
        if "position" not in d:
            raise ValueError("position is missing")
        return PointLight(d["position"], d.get("intensity", (1.0, 1.0, 1.0)),
                          d.get("radius", 0.0))
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from err


def pack_lights(lights, rotation=None, origin=None):
    """Arrays for the kernels: kinds (int32), vectors and RGB (float32, (n, 3)).

    Directional vectors are travel directions, point vectors are positions. When
    ``rotation``/``origin`` are given, vectors are mapped into a volume's local frame
    (``p_local = rotation.T @ (p - origin)``, directions rotated only).
    """
    lights = list(lights)
    kinds = np.array([l.kind for l in lights], dtype=np.int32)
    vecs = np.zeros((len(lights), 3), dtype=np.float64)
    rgb = np.zeros((len(lights), 3), dtype=np.float64)
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    o = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
    for i, l in enumerate(lights):
        if l.kind == DIRECTIONAL:
            vecs[i] = R.T @ l.direction
            rgb[i] = l.irradiance
        else:
            vecs[i] = R.T @ (l.position - o)
            rgb[i] = l.intensity
            _check_packed(i, vecs[i], rgb[i])
    return kinds, vecs.astype(np.float32), rgb.astype(np.float32)


def _check_packed(index: int, position, intensity) -> None:
    """The float32 limits, in the units the kernels get (render() maps worlds of any scale
    into units of about a voxel first, :mod:`vtkillum.core.units`)."""
    if np.max(np.abs(position)) > MAX_COORDINATE:
        raise ValueError(
            f"lights[{index}]: the point light lies {np.max(np.abs(position)):.3g} units from "
            f"the volume; at most {MAX_COORDINATE:g} can be rendered in float32 (a light that "
            "far away is a directional light); render through vtkillum.core.render.render, "
            "which measures lengths in voxels")
    if np.max(intensity) > MAX_VALUE:
        raise ValueError(
            f"lights[{index}]: point-light intensity {np.max(intensity):.3g} exceeds "
            f"{MAX_VALUE:g} (float32 rendering would overflow); render through "
            "vtkillum.core.render.render, which measures lengths in voxels (intensity in "
            "units of voxel²)")


def resolved_radius(light, volume) -> float:
    """Source radius of ``light`` for ``volume`` (world units; 0 for directional lights).

    A point light's own radius, or half the volume's smallest spacing when it is 0.
    """
    if light.kind == DIRECTIONAL:
        return 0.0
    return float(light.radius) if light.radius > 0 else 0.5 * float(np.min(volume.spacing))


def irradiance_on_grid(light, volume, shape) -> np.ndarray:
    """RGB irradiance of one light at the points of a grid covering ``volume``'s box.

    Parameters
    ----------
    light : DirectionalLight or PointLight
    volume : vtkillum.core.volume.Volume
        Gives the box (local frame ``[0, extent]``) and its world placement.
    shape : (3,) int
        Grid points per axis (at least 2 each).

    Returns
    -------
    ndarray (nx, ny, nz, 3) float32
        Constant for a directional light; ``I / max(d, r)**2`` for a point light, with
        ``r`` the larger of its source radius and half a grid spacing (a picture of the
        light for display; renderers evaluate the irradiance per sample).
    """
    shape = tuple(int(n) for n in shape)
    if light.kind == DIRECTIONAL:
        return np.broadcast_to(np.asarray(light.irradiance, np.float32),
                               (*shape, 3)).copy()
    spacing = volume.extent / (np.asarray(shape) - 1)
    p = volume.to_local(light.position)
    axes = [np.arange(n) * h - c for n, h, c in zip(shape, spacing, p)]
    d2 = (axes[0][:, None, None] ** 2 + axes[1][None, :, None] ** 2
          + axes[2][None, None, :] ** 2)
    d2 = np.maximum(d2, max(resolved_radius(light, volume), 0.5 * float(spacing.min())) ** 2)
    return (np.asarray(light.intensity)[None, None, None, :] / d2[..., None]).astype(np.float32)
