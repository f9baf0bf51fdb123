"""World units: every method renders in canonical units, so that any length scale works.

The same data and camera described in millimetres, metres or centimetres (astrophysics
in cgs: spacings of 1e18–1e21) must give the same picture. The kernels work in float32
and have budgets (steps per ray, mean free paths per ray, light positions) that are
stated for lengths of the order of a voxel; so the scene is mapped once, at the entry
point (:func:`vtkillum.core.render.render` and the progressive renderers), into
*canonical units* and rendered there.

The mapping
-----------
With ``L`` the canonical length (world units per canonical unit) and ``o`` the
canonical origin (a world point), a world point ``x`` maps to ``(x - o) / L`` and a
length ``l`` to ``l / L``. What changes, and why nothing else has to:

========================================  ============================================
world quantity                            canonical
========================================  ============================================
volume spacing, origin                    ``spacing / L``, ``(origin - o) / L``
opacity unit distance ``u``, step sizes   ``u / L``, ``step / L``
camera position, focal point              ``(x - o) / L`` (view angle unchanged)
camera parallel scale                     ``parallel_scale / L``
point-light position, radius              ``(p - o) / L``, ``r / L``
point-light intensity ``I``               ``I / L²``
directional irradiance ``E``              ``E`` (unchanged)
length options (``source_radius`` ...)    ``/ L``; ``scattering`` (length²) ``/ L²``
========================================  ============================================

* Extinction ``σt = -ln(1 - α) / u`` is per unit length: ``σt_c = σt L``, so every
  optical depth ``∫ σt dl`` (and every transmittance) is unchanged.
* A point light's irradiance ``I / d²`` is unchanged: ``(I / L²) / (d / L)² = I / d²``;
  a directional light's irradiance is unchanged by definition.
* Radiance ``L_o = ∫ T σs p E dl`` is then unchanged (``σs dl`` is dimensionless), and
  so are fluence ``φ = ∫ L dω`` and the per-point quantities that illumination filters
  output (transmittance, fluence). Images and alpha come back as they are: no
  rescaling of the result.

Hence the convention for point lights, the one physically consistent choice: **a scene
scaled by ``s`` shows the same picture when its point-light intensities are scaled by
``s²``** (irradiance ``I / d²`` at every scaled distance stays the same). Directional
irradiances are not scaled.

``L`` is the power of two nearest the volume's mean spacing. Dividing by a power of two
is exact in binary floating point, so a scene whose mean spacing rounds to 1 is rendered
bit for bit as before (the mapping is the identity there and the objects pass through
untouched), and worlds that differ by a power of two give identical bits. ``o`` is the
world origin (0) unless the volume lies more than :data:`FAR_ORIGIN` canonical units
from it; then it is the volume's origin, so that point lights near a far-away volume
stay within the kernels' coordinate range. (Kernels work in the volume's local frame,
computed in float64 on the host, so the offset costs no precision.)

What cannot be represented is refused before any work starts, with the reason: a
mean spacing outside :data:`SPACING_RANGE` (1e-150 to 1e150 world units: squared lengths
stay normal float64 numbers), a point light farther than :data:`vtkillum.core.lights.MAX_COORDINATE` canonical units
from the volume (a directional light then), or brighter than
:data:`~vtkillum.core.lights.MAX_VALUE` in canonical units (float32 overflow). Errors
that the methods raise about lengths speak in canonical units; :func:`render` adds
what one canonical unit is in world units.
"""

from __future__ import annotations

import dataclasses
import math
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

#: Options (keywords and scene-section fields) holding a world length (power 1) or area (2).
LENGTH_OPTIONS = {"step_size": 1, "photon_step": 1, "vl_step": 1, "avsm_step": 1,
                  "source_radius": 1, "scattering": 2}
#: Scene sections with length fields (``ambient_scattering.radius`` only in world units).
SECTION_LENGTHS = {"convection_diffusion": ("source_radius", "scattering")}
#: Mean spacings (world units) that can be represented: squared lengths (distances, camera
#: vectors, point-light intensities which scale as length²) stay normal float64 numbers.
SPACING_RANGE = (1.0e-150, 1.0e150)
#: Where the note on canonical units in error messages points.
_NOTE = "vtkillum.core.units"
#: A volume farther than this many canonical units from the world origin gets its own
#: origin as canonical origin (see the module docstring).
FAR_ORIGIN = float(2**24)


@dataclass(frozen=True)
class WorldUnits:
    """The map from world units into canonical units (see the module docstring).

    Attributes
    ----------
    length : float
        World units per canonical unit ``L`` (a power of two).
    origin : tuple of float
        World point ``o`` that becomes the canonical origin.
    """

    length: float = 1.0
    origin: tuple = (0.0, 0.0, 0.0)

    @classmethod
    def for_volume(cls, volume) -> "WorldUnits":
        """Canonical units of ``volume``: ``L`` the power of two nearest its mean spacing."""
        mean = float(np.mean(volume.spacing))
        if not SPACING_RANGE[0] <= mean <= SPACING_RANGE[1]:
            raise ValueError(
                f"volume spacing {np.asarray(volume.spacing).tolist()}: a mean spacing of "
                f"{mean:.3g} world units cannot be represented (squared lengths leave the "
                f"float64 range); the supported mean spacings are {SPACING_RANGE[0]:g} to "
                f"{SPACING_RANGE[1]:g}: describe the data in another length unit")
        # frexp: exact exponent, no log rounding; mean = m 2^e with m in [0.5, 1).
        m, e = math.frexp(mean)
        length = math.ldexp(1.0, e if m >= math.sqrt(0.5) else e - 1)
        origin = np.asarray(volume.origin, dtype=np.float64)
        if np.max(np.abs(origin)) / length <= FAR_ORIGIN:
            origin = np.zeros(3)
        return cls(length, tuple(float(v) for v in origin))

    @property
    def is_identity(self) -> bool:
        return self.length == 1.0 and not any(self.origin)

    # --- scalars, points ---------------------------------------------------------------
    def to_length(self, value, power: int = 1):
        """A world length (``power`` 1) or area (2) in canonical units; other values (None,
        non-numbers, non-positive ones) pass unchanged so that the method's own check
        reports the user's value."""
        if isinstance(value, (bool, np.bool_)) or value is None:
            return value
        if isinstance(value, (list, tuple, np.ndarray)):
            items = [self.to_length(v, power) for v in value]
            return type(value)(items) if not isinstance(value, np.ndarray) else np.array(items)
        if isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value) \
                and value > 0:
            value = float(value)
            for _ in range(power):  # L**power alone may overflow
                value /= self.length
        return value

    def per_world_length(self, value, power: int = 1):
        """A quantity per canonical length (``power`` 1: e.g. σt) per world length."""
        value = np.asarray(value) if not np.isscalar(value) else value
        for _ in range(power):
            value = value / self.length
        return value

    def to_point(self, point) -> np.ndarray:
        return (np.asarray(point, dtype=np.float64) - np.asarray(self.origin)) / self.length

    # --- objects -----------------------------------------------------------------------
    def volume(self, volume):
        """``volume`` in canonical units: the same scalars (not copied), kept with the
        volume so that its own caches (device copies, light volumes) live as long."""
        if self.is_identity:
            return volume
        from vtkillum.core.volume import Volume

        def make():
            canonical = Volume(volume.scalars, spacing=np.asarray(volume.spacing) / self.length,
                               origin=self.to_point(volume.origin), direction=volume.direction,
                               nan_policy=volume.nan_policy)
            for name in ("content_key", "value_range"):  # computed once per data
                if name in volume.__dict__:
                    canonical.__dict__[name] = volume.__dict__[name]
            return canonical

        return volume.derived("world_units.canonical", self, make)

    def camera(self, camera):
        if camera is None or self.is_identity:
            return camera
        return dataclasses.replace(camera, position=self.to_point(camera.position),
                                   focal_point=self.to_point(camera.focal_point),
                                   parallel_scale=camera.parallel_scale / self.length)

    def lights(self, lights, volume=None) -> list:
        """Lights in canonical units; ``ValueError`` for one the kernels cannot carry."""
        from vtkillum.core.lights import MAX_COORDINATE, MAX_VALUE, POINT, PointLight

        out = []
        for i, light in enumerate(lights):
            if light.kind != POINT:
                out.append(light)
                continue
            position = self.to_point(light.position)
            # Two divisions: L² alone overflows for L beyond 1e154 (I / L² does not).
            intensity = np.asarray(light.intensity, dtype=np.float64) / self.length / self.length
            radius = float(light.radius) / self.length
            if volume is not None:  # the world volume: distance from its centre
                centre = np.asarray(volume.bounds).reshape(3, 2).mean(1)
                far = float(np.linalg.norm(position - self.to_point(centre)))
            else:
                far = float(np.max(np.abs(position)))
            if not np.isfinite(far) or max(far, float(np.max(np.abs(position)))) > MAX_COORDINATE:
                raise ValueError(
                    f"lights[{i}]: the point light at {light.position.tolist()} is "
                    f"{far * self.length:.3g} world units from the volume, {far:.3g} times its "
                    f"mean spacing ({self.length:.3g}); at most {MAX_COORDINATE:g} can be "
                    "represented: a light that far away is a directional light")
            if not np.all(np.isfinite(intensity)) or np.any(intensity > MAX_VALUE):
                raise ValueError(
                    f"lights[{i}]: point-light intensity {light.intensity.tolist()} is "
                    f"{np.max(intensity):.3g} per squared mean spacing ({self.length:.3g} world "
                    f"units); at most {MAX_VALUE:g} (float32 rendering would overflow): lower it "
                    "(the picture at another scale s keeps its intensity scaled by s²)")
            if not (np.isfinite(radius) and radius <= MAX_COORDINATE):
                raise ValueError(f"lights[{i}]: radius {light.radius:g} world units is "
                                 f"{radius:.3g} mean spacings; at most {MAX_COORDINATE:g}")
            if self.is_identity:
                out.append(light)
            else:
                out.append(PointLight(position, intensity, radius))
        return out

    def options(self, options: dict, scene=None) -> dict:
        """Keyword options with world lengths in canonical units (``illumination`` volumes
        too); a photon ``mapper`` made for world units is refused."""
        if self.is_identity:
            return options
        out = dict(options)
        for key, power in LENGTH_OPTIONS.items():
            if key in out:
                out[key] = self.to_length(out[key], power)
        if "radius" in out and self._ambient_world_radius(out, scene):
            out["radius"] = self.to_length(out["radius"])
        if out.get("illumination") is not None:
            out["illumination"] = self.illumination(out["illumination"])
        if out.get("mapper") is not None:
            raise ValueError(
                f"mapper: a PhotonMapper keeps its radius in the units it was made for; this "
                f"render works in units of {self.length:g} world units (vtkillum.core.units): "
                "leave mapper out (render keeps one with the volume), or build volume, scene "
                "and mapper in those units")
        return out

    def illumination(self, illumination):
        from vtkillum.core.illumination import IlluminationVolume

        if not isinstance(illumination, IlluminationVolume) or self.is_identity:
            return illumination  # a bare fluence array has no geometry; fluence has no unit
        # The same grids (on the device, if they are there): no copy, no second check.
        return illumination.with_extent(np.asarray(illumination.extent) / self.length)

    def scene(self, scene, volume=None):
        """``scene`` in canonical units (a new Scene; the given one is not changed)."""
        lights = self.lights(scene.lights, volume)
        if self.is_identity:
            return scene
        sections = {name: dict(opts) for name, opts in scene.options.items()}
        for name, keys in SECTION_LENGTHS.items():
            for key in keys:
                if key in sections.get(name, {}):
                    sections[name][key] = self.to_length(sections[name][key],
                                                         LENGTH_OPTIONS[key])
        ambient = sections.get("ambient_scattering", {})
        if ambient.get("radius_units") == "world" and "radius" in ambient:
            ambient["radius"] = self.to_length(ambient["radius"])
        return dataclasses.replace(
            scene, lights=lights, camera=self.camera(scene.camera), options=sections,
            opacity_unit_distance=self.to_length(scene.opacity_unit_distance),
            step_size=self.to_length(scene.step_size))

    def info(self, info: dict) -> dict:
        """A result's ``info`` with its world lengths back in world units."""
        if self.is_identity:
            return info
        for key in ("radius_world", "step_size"):
            if isinstance(info.get(key), (int, float, np.floating)):
                info[key] = float(info[key]) * self.length
        info["world_units"] = {"length": self.length, "origin": list(self.origin)}
        return info

    @contextmanager
    def explained(self):
        """Re-raise a ``ValueError`` from inside with :meth:`explain`'s note."""
        try:
            yield
        except ValueError as err:
            note = self.explain(err)
            if note is err:
                raise
            raise note from err

    def explain(self, err: Exception) -> Exception:
        """``err`` with a note that its lengths are in canonical units (when they differ)."""
        if self.is_identity or not isinstance(err, ValueError) or _NOTE in str(err):
            return err
        return ValueError(f"{err} [lengths in this message are in canonical units of "
                          f"{self.length:.6g} world units, the volume's mean spacing rounded "
                          f"to a power of two: {_NOTE}]")

    @staticmethod
    def _ambient_world_radius(options: dict, scene) -> bool:
        units = options.get("radius_units")
        if units is None and scene is not None:
            units = scene.options.get("ambient_scattering", {}).get("radius_units")
        return units == "world"


def canonical(volume, scene, options: dict | None = None):
    """``(volume, scene, options, units)`` in canonical units (see the module docstring).

    Idempotent: canonical inputs map to themselves (the identity passes the objects
    through).
    """
    units = WorldUnits.for_volume(volume)
    return (units.volume(volume), units.scene(scene, volume), units.options(options or {}, scene),
            units)
