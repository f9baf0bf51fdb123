"""Illumination volumes: what illumination methods hand to the ray caster.

Convention (project-wide)
-------------------------
An :class:`IlluminationVolume` keeps the light at a sample in two parts, on grids
covering a volume's local frame ``[0, extent]`` (trilinearly interpolated,
point-centred like the data):

``transmittance`` — the **direct** (unscattered) light, per light
    ``T_l(x)``, the transmittance from ``x`` towards light ``l`` (same order as the
    scene's lights). Its direction is known (towards the light), so the ray caster
    applies the Henyey–Greenstein phase function to it exactly; the irradiance
    ``E_l(x)`` (constant for directional lights, ``I / d**2`` for point lights) is
    evaluated at the sample, not interpolated, so a point light near the data
    does not smear its ``1/d**2`` peak over a grid cell.
``scattered`` — the **scattered** light as an isotropic RGB fluence
    ``phi_s,c(x) = integral over the sphere of L_s,c(x, w) dw``, counting light
    that has scattered at least once (zero for a method without multiple
    scattering).

The ray caster (:func:`vtkillum.core.raycast.render_illuminated`) turns them into
the source term of the view ray at ``x`` travelling along ``d``, following Zhang
& Ma 2013, eq. 24 (``L_final = L (I_a + I_d + I_s)``) in the project's physical
units::

    J_c(x) = sigma_s,c(x) * [ sum_l p(cos theta_l) T_l(x) E_l,c(x) + phi_s,c(x) / (4 pi) ] * S(x)

    cos theta_l = dot(w_l, d)   (light travel direction -w_l vs. direction to camera -d)

    S(x) = ka + kd * mean_l |n . w_l| + ks * mean_l max(n . h_l, 0) ** shininess

with ``p`` the Henyey–Greenstein phase function of the scene's anisotropy ``g``,
``sigma_s,c = albedo * color_c(s) * sigma_t`` (``DESIGN.md``), ``w_l`` the unit
direction towards light ``l``, ``h_l = normalize(w_l + v)`` the half vector with
``v = -d`` the direction towards the camera, and ``n`` the normalised scalar
gradient (central differences, one voxel apart) flipped to face the camera
(two-sided lighting, as VTK's default ``TwoSidedLighting``). ``ka, kd, ks,
shininess`` are the scene's ``shading`` ``ambient, diffuse, specular, shininess``
(defaults 1, 0, 0, 32). With the defaults ``S = 1`` and the direct part is
exactly single scattering with the phase function, whatever ``g``: the
``transmittance`` method then equals ``single`` up to the light grid's
interpolation.

Why not one isotropic fluence: the first-scattered light is the brightest part
of most images, and treating it as isotropic (``sigma_s phi / 4 pi``) is 1.5–1.9x
off for ``g`` = 0.2–0.4 when the camera looks across the light. The scattered
part has lost most of its directionality after a few events, which is why it is
kept isotropic.

Where the gradient vanishes (homogeneous regions, where no surface and hence no
normal exists) the sample is treated as facing every light without a highlight:
``S = ka + kd`` (diffuse factor 1, specular factor 0). "Vanishes" means that the
data change across one voxel is below ``GRADIENT_EPS`` times the data range.

Simplification vs. the paper: Zhang & Ma multiply their light-volume value by
Phong intensities whose light colours are already part of ``L``; here the light
colour lives only in ``E_l`` and ``phi_s`` and the Phong factor ``S`` is grey.
"""

from __future__ import annotations

import numpy as np

#: Relative data change across one voxel below which a sample has no usable normal.
GRADIENT_EPS = 1.0e-5


class IlluminationVolume:
    """Direct light per light and isotropic scattered fluence, covering ``[0, extent]``.

    Parameters
    ----------
    scattered : ndarray (nx, ny, nz, 3) or warp array3d(vec3), optional
        Non-negative RGB fluence ``phi_s`` of the scattered light (irradiance units: for
        an isotropic radiance ``L`` it is ``4 pi L``), indexed ``[i, j, k, c]`` along the
        local x, y, z axes; at least 2 points per axis; converted to float32. ``None``:
        no scattered light. A single isotropic fluence from elsewhere (e.g. a solver
        that does not separate the direct light) goes here.
    extent : (3,) float
        Size of the box it covers in the local frame (world units); equal to the
        rendered volume's ``extent``.
    transmittance : ndarray or warp array4d(float32) (n_lights, nx', ny', nz'), optional
        ``T_l`` in [0, 1] towards each light of the scene, in the scene's order; any
        resolution (at least 2 points per axis). ``None``: no direct light (the
        scattered fluence is all there is).

    At least one of ``scattered`` and ``transmittance`` must be given.

    Notes
    -----
    Device residency: grids given as warp arrays (what the light methods compute) stay
    where they are. They are checked there by one reduction each
    (:func:`vtkillum.core.device_arrays.array_stats`), handed to a renderer on the same
    device without a copy (:meth:`device_scattered`, :meth:`device_transmittance`), and
    downloaded only when the numpy attributes :attr:`scattered` / :attr:`transmittance`
    are read (once; kept). numpy grids are checked on the host once and uploaded once per
    device, so a renderer that draws many frames from one IlluminationVolume (a camera
    moving in a window) moves no volume-sized data after the first frame.
    """

    def __init__(self, scattered=None, extent=None, transmittance=None) -> None:
        if scattered is None and transmittance is None:
            raise ValueError("an illumination volume needs scattered fluence, per-light "
                             "transmittance, or both")
        e = np.asarray(extent if extent is not None else [], dtype=np.float64).reshape(-1)
        if e.shape != (3,) or not np.all(np.isfinite(e)) or np.any(e <= 0):
            raise ValueError(f"illumination extent must be three positive numbers, got {extent!r}")
        self.extent = e
        self._host: dict[str, np.ndarray | None] = {"scattered": None, "transmittance": None}
        self._device: dict[tuple[str, str], object] = {}  # (part, device) -> warp array
        self._shapes: dict[str, tuple | None] = {"scattered": None, "transmittance": None}
        self.transmittance_range: tuple[float, float] | None = None
        self.scattered_range: tuple[float, float] | None = None
        self._textures: dict[tuple[str, str], object] = {}  # (part, device) -> texture
        if scattered is not None:
            self._set("scattered", scattered)
        if transmittance is not None:
            self._set("transmittance", transmittance)

    # --- construction ---------------------------------------------------------------------------
    def _set(self, part: str, data) -> None:
        if _is_warp_array(data):
            data, value_range = _checked_device(data, part)
            self._device[(part, str(data.device))] = data
            self._shapes[part] = _logical_shape(data, part)
            setattr(self, f"{part}_range", value_range)
            return
        host = _checked_grid(data, "scattered fluence") if part == "scattered" \
            else _checked_transmittance(data)
        self._host[part] = host
        self._shapes[part] = tuple(int(n) for n in host.shape)
        setattr(self, f"{part}_range", (float(host.min()), float(host.max())))

    def with_extent(self, extent) -> "IlluminationVolume":
        """The same grids (shared, not copied or checked again) covering another ``extent``."""
        out = object.__new__(IlluminationVolume)
        out.__dict__.update(self.__dict__)
        e = np.asarray(extent, dtype=np.float64).reshape(-1)
        if e.shape != (3,) or not np.all(np.isfinite(e)) or np.any(e <= 0):
            raise ValueError(f"illumination extent must be three positive numbers, got {extent!r}")
        out.extent = e
        return out

    # --- numpy views (downloaded once when the grids live on a device) ------------------------
    @property
    def scattered(self) -> np.ndarray | None:
        """Scattered fluence ``(nx, ny, nz, 3)`` float32 on the host, or None."""
        return self._host_part("scattered")

    @property
    def transmittance(self) -> np.ndarray | None:
        """Per-light transmittance ``(n_lights, nx, ny, nz)`` float32 on the host, or None."""
        return self._host_part("transmittance")

    def has(self, part: str) -> bool:
        """Whether ``part`` (``"scattered"`` or ``"transmittance"``) is present."""
        return self._shapes[part] is not None

    def _host_part(self, part: str):
        if self._shapes[part] is None:
            return None
        if self._host[part] is None:
            from vtkillum.core.device_arrays import download

            source = next(a for (p, _d), a in self._device.items() if p == part)
            self._host[part] = np.ascontiguousarray(
                download(source).reshape(self._shapes[part]).astype(np.float32, copy=False))
        return self._host[part]

    def resident_device(self) -> str | None:
        """A warp device on which every present grid already is (a CUDA one first), or
        None: where a consumer can read the grids without a copy."""
        present = [p for p in ("scattered", "transmittance") if self._shapes[p] is not None]
        devices = sorted({d for (_p, d) in self._device},
                         key=lambda d: (not d.startswith("cuda"), d))
        for device in devices:
            if all((part, device) in self._device for part in present):
                return device
        return None

    # --- device views (uploaded once per device when the grids came from numpy) ---------------
    def device_scattered(self, device: str):
        """The scattered fluence as a warp ``array3d(vec3)`` on ``device`` (None if absent)."""
        return self._device_part("scattered", device)

    def device_transmittance(self, device: str):
        """The transmittance as a warp ``array4d(float32)`` on ``device`` (None if absent)."""
        return self._device_part("transmittance", device)

    def _device_part(self, part: str, device: str):
        if self._shapes[part] is None:
            return None
        key = (part, str(device))
        if key not in self._device:
            import warp as wp

            from vtkillum.core.device_arrays import upload

            host = self._host_part(part)
            if part == "scattered":
                self._device[key] = upload(host.reshape(*host.shape[:3], 3), wp.vec3, device)
            else:
                self._device[key] = upload(host, wp.float32, device)
        return self._device[key]

    def device_texture(self, part: str, device: str, make):
        """``make(grid)`` of ``part``'s device grid (a texture, :mod:`vtkillum.core.textures`),
        made once per part and device and kept with this volume (its grids never change);
        None if the part is absent."""
        key = (part, str(device))
        if key not in self._textures:
            grid = self._device_part(part, device)
            self._textures[key] = None if grid is None else make(grid)
        return self._textures[key]

    # --- geometry -------------------------------------------------------------------------------
    @property
    def n_lights(self) -> int:
        """Lights with a direct-light channel (0 without transmittance)."""
        shape = self._shapes["transmittance"]
        return 0 if shape is None else int(shape[0])

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid size ``(nx, ny, nz)`` of the scattered fluence, else of the transmittance."""
        if self._shapes["scattered"] is not None:
            return tuple(self._shapes["scattered"][:3])
        return tuple(self._shapes["transmittance"][1:])

    @property
    def transmittance_shape(self) -> tuple[int, int, int] | None:
        """Grid size ``(nx, ny, nz)`` of the transmittance, or None."""
        shape = self._shapes["transmittance"]
        return None if shape is None else tuple(shape[1:])

    @classmethod
    def for_volume(cls, volume, scattered=None, transmittance=None) -> "IlluminationVolume":
        """An illumination volume covering the same box as ``volume`` (any resolution).

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
        scattered : ndarray (nx, ny, nz, 3) or warp array3d(vec3), optional
        transmittance : ndarray or warp array4d (n_lights, nx, ny, nz), optional
            See the class docstring.
        """
        return cls(scattered, volume.extent, transmittance)

    def check_matches(self, volume, lights=None) -> None:
        """Raise ``ValueError`` unless this covers ``volume``'s box (and has one channel per light).

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
        lights : sequence, optional
            The scene's lights; when given, the transmittance must have one channel each.
        """
        if not np.allclose(self.extent, volume.extent, rtol=1e-5, atol=1e-9):
            raise ValueError(
                f"illumination volume covers extent {self.extent.tolist()} but the volume spans "
                f"{volume.extent.tolist()}; build it with IlluminationVolume.for_volume(volume, "
                "...)"
            )
        if lights is not None and self.has("transmittance") and \
                self.n_lights != len(lights):
            raise ValueError(
                f"the illumination volume has transmittance for {self.n_lights} light(s) but the "
                f"scene has {len(lights)}; compute it with the scene's lights"
            )

    def fluence(self, volume, lights) -> np.ndarray:
        """Total isotropic-equivalent fluence ``sum_l T_l E_l + phi_s`` on the grid (display).

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
            Gives the world frame of the lights.
        lights : sequence of lights
            The scene's lights (one per transmittance channel).

        Returns
        -------
        ndarray (nx, ny, nz, 3) float32
            On the grid of :attr:`shape` (the transmittance is resampled when its grid
            differs). Point-light irradiance is taken at the grid points, so it is only a
            picture of the light, not what the ray caster evaluates per sample.
        """
        from vtkillum.core.lights import irradiance_on_grid
        from vtkillum.core.resample import resample_points

        shape = self.shape
        total = np.zeros((*shape, 3), np.float32)
        if self.scattered is not None:
            total += self.scattered
        if self.transmittance is not None:
            self.check_matches(volume, lights)
            for li, light in enumerate(lights):
                t = self.transmittance[li]
                if t.shape != shape:
                    t = resample_points(t, shape)
                total += t[..., None] * irradiance_on_grid(light, volume, shape)
        return total


def _is_warp_array(data) -> bool:
    return type(data).__module__.startswith("warp") and hasattr(data, "ptr")


def _logical_shape(data, part: str) -> tuple:
    """``(nx, ny, nz, 3)`` / ``(n_lights, nx, ny, nz)`` of a device grid."""
    shape = tuple(int(n) for n in data.shape)
    return shape + (3,) if part == "scattered" else shape


def _checked_device(data, part: str):
    """Shape and value checks of a device grid, as one reduction on its device; returns the
    grid to use (transmittance round-off above 1 clamped in a device copy) and its
    ``(min, max)``."""
    import warp as wp

    from vtkillum.core.device_arrays import array_stats, clamp_max

    if part == "scattered":
        if data.dtype != wp.vec3 or data.ndim != 3 or min(data.shape) < 2:
            raise ValueError(f"a device scattered fluence must be a warp array3d of vec3 with at "
                             f"least 2 points per axis, got {data.ndim}-d {data.dtype} {data.shape}")
    elif data.dtype != wp.float32 or data.ndim != 4 or data.shape[0] < 1 or min(data.shape[1:]) < 2:
        raise ValueError(f"a device transmittance must be a warp array4d of float32 (n_lights, nx, "
                         f"ny, nz), got {data.ndim}-d {data.dtype} {data.shape}")
    bad, lo, hi = array_stats(data)
    if part == "scattered":
        if bad:
            raise ValueError("illumination scattered fluence contains NaN or Inf values; fix the "
                             "solver output")
        if lo < 0:
            raise ValueError(f"illumination scattered fluence must be non-negative (minimum "
                             f"{lo:g}); clamp it at 0 if these are round-off")
        return data, (lo, hi)
    if bad or lo < 0 or hi > 1 + 1e-5:
        raise ValueError("illumination transmittance must lie in [0, 1] (no NaN or Inf)")
    return (clamp_max(data, 1.0) if hi > 1.0 else data), (lo, min(hi, 1.0))


def _checked_grid(fluence, what: str) -> np.ndarray:
    f = np.asarray(fluence)
    if f.dtype.kind not in "biuf":
        raise ValueError(f"illumination {what} must be real numbers, got dtype {f.dtype}")
    if f.ndim != 4 or f.shape[-1] != 3:
        raise ValueError(
            f"illumination {what} must have shape (nx, ny, nz, 3) (RGB per grid point), got "
            f"{f.shape}; for a grey fluence g of shape (nx, ny, nz) pass "
            "np.repeat(g[..., None], 3, axis=-1)"
        )
    if min(f.shape[:3]) < 2:
        raise ValueError(
            f"illumination {what} {f.shape}: at least 2 grid points are needed along each "
            "axis to interpolate it"
        )
    f = f.astype(np.float32, copy=False)
    if not np.all(np.isfinite(f)):
        raise ValueError(f"illumination {what} contains NaN or Inf values; fix the solver output")
    if np.any(f < 0):
        raise ValueError(
            f"illumination {what} must be non-negative (minimum {float(f.min()):g}); clamp "
            "it with np.maximum(fluence, 0) if these are round-off"
        )
    return np.ascontiguousarray(f)


def _checked_transmittance(transmittance) -> np.ndarray:
    t = np.asarray(transmittance)
    if t.dtype.kind not in "biuf":
        raise ValueError(f"illumination transmittance must be real numbers, got dtype {t.dtype}")
    if t.ndim != 4 or t.shape[0] < 1 or min(t.shape[1:]) < 2:
        raise ValueError(
            f"illumination transmittance must have shape (n_lights, nx, ny, nz) with at least "
            f"one light and 2 points per axis, got {t.shape}"
        )
    t = t.astype(np.float32, copy=False)
    if not np.all(np.isfinite(t)) or np.any(t < 0) or np.any(t > 1 + 1e-5):
        raise ValueError("illumination transmittance must lie in [0, 1] (no NaN or Inf)")
    return np.ascontiguousarray(np.minimum(t, 1.0))


def shading_terms(shading: dict) -> tuple[float, float, float, float]:
    """Validated ``(ka, kd, ks, shininess)`` from a scene's ``shading`` section."""
    try:
        ka, kd, ks, n = (float(shading[k]) for k in ("ambient", "diffuse", "specular", "shininess"))
    except KeyError as err:
        raise ValueError(f"shading: missing field {err}") from None
    for name, value in (("ambient", ka), ("diffuse", kd), ("specular", ks)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"shading.{name} must be a non-negative number, got {value}")
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"shading.shininess must be positive, got {n}")
    return ka, kd, ks, n


def gradient_threshold(volume) -> float:
    """:data:`GRADIENT_EPS` as a gradient magnitude for ``volume`` (data units per world unit).

    The data range times ``GRADIENT_EPS`` over one (smallest) voxel: below it a sample has
    no usable normal.
    """
    lo, hi = volume.value_range
    return GRADIENT_EPS * (hi - lo) / float(volume.spacing.min())
