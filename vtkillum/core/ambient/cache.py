"""What ambient scattering keeps between frames, and what each edit invalidates.

The paper's Table 1 separates three kinds of interaction; this cache recomputes
exactly the stages each one needs:

==========================  ===============================================
edit                        recomputed
==========================  ===============================================
transfer function (or data) σt grid (and the empty-space blocks),
                            ``σ̃t`` and ``σ̂``, radiance cache
ambient radius ``r``        ``σ̃t`` and the step field ``σ̂`` (from the kept σt), radiance cache
anisotropy ``g``, albedo,   radiance cache only
lights, cache resolution
camera, image size          nothing (only the gather runs)
==========================  ===============================================

Each stage is keyed by everything it depends on; :attr:`AmbientScatteringCache.stats`
counts how often each ran, and :attr:`AmbientState.recomputed` /
:attr:`AmbientState.timings` say what the last update did and how long it took
(milliseconds, device synchronised); the transfer-function stage keeps its name
``"sat"`` from when it built the paper's summed-area table, which ``σ̃t`` no longer needs
(the same cube means by separable passes, :mod:`vtkillum.core.ambient.sat`). The data is recognised by the array's
identity, shape, spacing and a strided sample of its values; a different
array object is compared by a hash of all its values (so a filter's fresh
conversion of unchanged data keeps the caches). After editing a volume's array
in place call :meth:`AmbientScatteringCache.invalidate`.

A ``g`` or light edit runs on the device alone: the whole preintegration table
stays there (:class:`~vtkillum.core.ambient.device_table.DeviceTable` slices it at
the new ``g``), and the radiance cache, light list and table slices are
overwritten in place rather than reallocated. So an :class:`AmbientState` stays
valid until the next :meth:`AmbientScatteringCache.update`, which may overwrite
its arrays.

With ``hardware_filtering=True`` on a CUDA device the cache also keeps the data
scalars, ``σ̃t`` and the (half-precision) radiance cache as ``wp.Texture3D`` objects and
the table slice as a ``wp.Texture2D``
(:mod:`~vtkillum.core.ambient.textures`): the tube march and the gather then sample
them by hardware trilinear filtering (faster; mean differences from the exact values
within 2e-3 of the maximum). Each texture is refreshed by one device copy when its stage is recomputed
(counted in that stage's timing) and reallocated only when its shape changes. On the
CPU the option is ignored: the exact software path runs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from vtkillum.core.ambient.device_table import DeviceTable
from vtkillum.core.ambient.sat import ambient_extinction, sigma_t_grid
from vtkillum.core.ambient.table import PreintegrationTable, load_table
from vtkillum.core.ambient.textures import (
    AmbientTextures,
    data_texture,
    hardware_filtering_available,
    optics_texture,
)
from vtkillum.core.ambient.tube_march import RadianceCache, radiance_cache, step_extinction_field
from vtkillum.core.device import resolve_device
from vtkillum.core.lights import pack_lights, resolved_radius
from vtkillum.core.resample import scaled_shape
from vtkillum.core.volume import array_digest
from vtkillum.core.warp_common import (
    Lights,
    Medium,
    fits_texture,
    make_lights,
    make_medium,
    texture_from,
    to_device,
)

#: Values compared for the data fingerprint (strided over the array). It only backs up the
#: array's identity (in-place edits call for :meth:`AmbientScatteringCache.invalidate`), so it
#: is kept small: 4096 values cost ~6 µs per update on the H200 machine's host (432³ data).
FINGERPRINT_SAMPLES = 1 << 12
#: Ways the tube march measures a step's extinction (:class:`AmbientScatteringCache`).
TUBE_SAMPLING = ("field", "midpoint", "paper")
#: Default samples of the step field per tube step (``step_samples``).
STEP_SAMPLES = 1


@dataclass
class AmbientState:
    """Everything the gather needs, as left by :meth:`AmbientScatteringCache.update`.

    Attributes
    ----------
    medium : Medium
        Data and optical model on the device (albedo and g set).
    sigma_t : wp.array3d(float32)
        σt at the grid points.
    sigma_tilde : wp.array3d(float32)
        Ambient extinction ``σ̃t`` on the data grid.
    radiance : RadianceCache or None
        Tube-marched radiance per light (None after :meth:`~AmbientScatteringCache.update_extinction`).
    lights : Lights or None
        Lights in the local frame, in cache order.
    table : PreintegrationTable or None
        The preintegration table used.
    table_slice : wp.array2d(float32) or None
        ``L̃o(θ, r σ̃t)`` at the scene's ``g`` (the paper's gather).
    scattered_slice : wp.array2d(float32) or None
        Its scattered part ``M(θ, r σ̃t)`` at the scene's ``g`` (the centred gather).
    radius : float
        Sphere radius in world units.
    recomputed : list of str
        Stages the last update ran: ``"sat"``, ``"extinction"``, ``"radiance"``.
    timings : dict
        Milliseconds per stage of the last update (``sat_ms``, ``extinction_ms``,
        ``radiance_ms``; 0 for a stage that was kept).
    occupied : wp.array3d(int32)
        Blocks that may hold matter, for the gather's empty-space skipping (recomputed
        with the σt grid).
    textures : AmbientTextures or None
        With hardware filtering (after :meth:`~AmbientScatteringCache.update`): scalars,
        ``σ̃t`` and radiance cache as textures for the gather; with ``data_textures`` the
        scalars, ``σ̃t`` and the transfer function only (``radiance`` None); else None.
    """

    medium: Medium
    sigma_t: object
    sigma_tilde: object
    radiance: RadianceCache | None
    lights: Lights | None
    table: PreintegrationTable | None
    table_slice: object
    radius: float
    recomputed: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    occupied: object = None
    textures: AmbientTextures | None = None
    scattered_slice: object = None


class AmbientScatteringCache:
    """σt grid, ambient extinction and radiance cache, recomputed only when invalidated.

    Parameters
    ----------
    device : str, optional
        Warp device every array lives on.
    tube_sampling : {"field", "midpoint", "paper"}
        How the tube march measures a step's extinction (see
        :mod:`~vtkillum.core.ambient.tube_march`): ``"field"`` (default) one sample of the
        step field ``σ̂`` (``σ̃t`` box-averaged over ``2r``, kept with ``σ̃t``) at the step's
        middle; ``"midpoint"`` the mean of ``σ̃t`` along the step, a sample per data spacing
        (16× the samples at ``r = 8`` voxels); ``"paper"`` one sample of ``σ̃t`` (thin shells
        slip between the steps: for comparisons only).
    step_samples : int
        With ``"field"``: samples of ``σ̂`` per step of ``2r``, each at the middle of its
        ``2r / step_samples`` (the box then has that side: less lateral blur, more samples).
    field_texture : bool, optional
        With ``"field"``: sample ``σ̂`` through a CUDA texture (hardware trilinear
        filtering, one fetch per step instead of eight loads). Default (None): on CUDA
        devices. ``σ̂`` is a box average over ``2r``, smooth at the grid's scale, so the
        texture units' 8-bit interpolation weights change the radiance cache by ~1e-4 of
        its maximum on average (tested within 1e-3); False keeps the exact software path.
    hardware_filtering : bool
        Sample ``σ̃t``, the radiance cache and the scalars through CUDA textures (hardware
        trilinear filtering, see the module docstring). Ignored on the CPU, which always
        runs the exact software path; also skipped (software path) for a grid larger than
        a texture allows (:data:`~vtkillum.core.warp_common.MAX_TEXTURE_EXTENT` along
        any axis, lights × cache points along x included).
    data_textures : bool, optional
        Let the gather read the scalars, ``σ̃t`` and the transfer function through CUDA
        textures (the loads of its primary and short shadow rays), the radiance cache and
        the table slice from their arrays (no texture copy on a ``g`` or light edit; see
        :mod:`~vtkillum.core.ambient.gather`). Default (None): on CUDA devices; images
        within 2e-3 of the exact software path on average (tested). False keeps the exact
        path. ``hardware_filtering`` includes it.

    Attributes
    ----------
    hardware_filtering : bool
        Whether textures are used (requested and the device is CUDA).
    """

    def __init__(self, device: str | None = None, hardware_filtering: bool = False,
                 tube_sampling: str = "field", step_samples: int = STEP_SAMPLES,
                 field_texture: bool | None = None, data_textures: bool | None = None) -> None:
        if not isinstance(hardware_filtering, (bool, np.bool_)):
            raise ValueError("hardware_filtering must be true or false, got "
                             f"{hardware_filtering!r}")
        if tube_sampling not in TUBE_SAMPLING:
            raise ValueError(f"tube_sampling must be one of {', '.join(TUBE_SAMPLING)}, "
                             f"got {tube_sampling!r}")
        if isinstance(step_samples, bool) or not isinstance(step_samples, (int, np.integer)) \
                or step_samples < 1:
            raise ValueError(f"step_samples must be an integer >= 1, got {step_samples!r}")
        for name, value in (("field_texture", field_texture), ("data_textures", data_textures)):
            if value is not None and not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{name} must be true, false or None, got {value!r}")
        self.tube_sampling = tube_sampling
        self.step_samples = int(step_samples)
        self.device = resolve_device(device)
        cuda = hardware_filtering_available(self.device)
        self.field_texture = cuda if field_texture is None else bool(field_texture) and cuda
        self.data_textures = cuda if data_textures is None else bool(data_textures) and cuda
        self.hardware_filtering = bool(hardware_filtering) and cuda
        self.stats = {"sat": 0, "extinction": 0, "radiance": 0}
        self.invalidate()

    def invalidate(self) -> None:
        """Forget everything (the next update recomputes all stages)."""
        self._data_identity = None
        self._data_sample = None
        self._data_key = None
        self._scalars = None
        self._occupied = None
        self._tf_key = None
        self._medium = None
        self._sigma_t = None
        self._ext_key = None
        self._sigma_tilde = None
        self._step_field = None
        self._step_field_texture = None
        self._rad_key = None
        self._radiance = None
        self._lights = None
        self._light_key = None
        self._light_staging = {}  # pinned host arrays of the light upload (CUDA)
        self._device_table = None
        self._textured = False
        self._data_textured = False
        self._scalars_texture = None  # scalars and σ̃t, two channels (data_texture)
        self._sigma_tilde_texture = None
        self._table_texture = None
        self._scattered_texture = None
        self._table_texture_key = None
        self._optics_texture = None

    def update(self, volume, transfer_function, unit_distance: float, albedo: float,
               anisotropy: float, lights, radius: float, radius_units: str = "voxels",
               cache_scale: float = 0.5, table: PreintegrationTable | None = None,
               cache_shape=None) -> AmbientState:
        """Bring every stage up to date with the given parameters.

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
        transfer_function : vtkillum.core.transfer_function.TransferFunction
        unit_distance : float
            Opacity unit distance (world units).
        albedo, anisotropy : float
            ``Λ`` and HG ``g``.
        lights : list of DirectionalLight / PointLight
        radius : float
            Ambient sphere radius ``r``.
        radius_units : {"voxels", "world"}
            ``"voxels"``: ``r`` times the mean spacing; ``"world"``: world units.
        cache_scale : float
            Radiance-cache resolution relative to the data, in (0, 1].
        table : PreintegrationTable, optional
            Table to use; default :func:`~vtkillum.core.ambient.table.load_table` for ``albedo``.
        cache_shape : (int, int, int), optional
            Explicit radiance-cache grid (overrides ``cache_scale``).
        """
        if table is None:
            table = load_table(albedo, device=self.device)
        state = self.update_extinction(volume, transfer_function, unit_distance, radius,
                                       radius_units)
        device = self.device
        self._medium.albedo = float(albedo)
        self._medium.g = float(anisotropy)

        if self._device_table is None or self._device_table.table is not table:
            self._device_table = DeviceTable(table, device)  # uploaded once per table
        dtable = self._device_table
        g_key = round(float(anisotropy), 9)
        if dtable.g != g_key:
            dtable.set_g(g_key)
        slice_key = (id(table), g_key)

        kinds, vecs, rgb = pack_lights(lights, volume.direction, volume.origin)
        radii = np.array([resolved_radius(light, volume) for light in lights], np.float32)
        light_key = (kinds.tobytes(), vecs.tobytes(), rgb.tobytes(), radii.tobytes())
        rad_key = (self._ext_key, slice_key, light_key,
                   float(cache_scale), None if cache_shape is None else tuple(cache_shape))
        if rad_key != self._rad_key:
            t = time.perf_counter()
            self._lights = _upload_lights(self._lights, lights, volume, kinds, vecs, rgb, radii,
                                          device, light_key, self._light_key,
                                          self._light_staging)
            self._light_key = light_key
            self._radiance = radiance_cache(self._sigma_tilde, volume.spacing, volume.extent,
                                            self._lights, dtable.transmittance_slice,
                                            table.sigma_max, state.radius, cache_scale, device,
                                            cache_shape, out=self._radiance,
                                            sigma_tilde_texture=self._hardware_texture(
                                                len(kinds), cache_scale, cache_shape),
                                            substeps=self._tube_substeps(),
                                            step_field=self._step_field,
                                            step_field_texture=self._step_field_texture)
            wp.synchronize_device(device)
            state.timings["radiance_ms"] = 1e3 * (time.perf_counter() - t)
            self._rad_key = rad_key
            self.stats["radiance"] += 1
            state.recomputed.append("radiance")
        state.radiance = self._radiance
        state.lights = self._lights
        state.table = table
        state.table_slice = dtable.g_slice
        state.scattered_slice = dtable.scattered_slice
        if self._radiance.texture is not None:
            texture_key = (dtable, dtable.g)
            if texture_key != self._table_texture_key:  # the slices changed: small copies
                self._table_texture = texture_from(dtable.g_slice, self._table_texture)
                self._scattered_texture = texture_from(dtable.scattered_slice,
                                                       self._scattered_texture)
                self._table_texture_key = texture_key
            state.textures = AmbientTextures(self._scalars_texture, self._sigma_tilde_texture,
                                             self._radiance.texture, self._table_texture,
                                             self._optics_texture, self._scattered_texture)
        elif self._data_textured:
            state.textures = AmbientTextures(self._scalars_texture, None, None,
                                             optics=self._optics_texture)
        return state

    def _tube_substeps(self) -> int | None:
        """Samples per tube step for :func:`radiance_cache` (None: one per data spacing)."""
        return {"field": self.step_samples, "paper": 1}.get(self.tube_sampling)

    def _hardware_texture(self, n_lights: int, cache_scale: float, cache_shape):
        """``σ̃t``'s texture when hardware filtering applies to this update, else None."""
        if self._sigma_tilde_texture is None or n_lights == 0:
            return None
        shape = (scaled_shape(np.asarray(self._sigma_tilde.shape), float(cache_scale))
                 if cache_shape is None else tuple(int(n) for n in cache_shape))
        if not fits_texture((n_lights * shape[0], shape[1], shape[2])):
            return None
        return self._sigma_tilde_texture

    def update_extinction(self, volume, transfer_function, unit_distance: float, radius: float,
                          radius_units: str = "voxels") -> AmbientState:
        """Bring only the σt grid and ``σ̃t`` up to date (no lights needed).

        The returned state has ``radiance``, ``lights``, ``table`` and ``table_slice``
        set to ``None``; parameters as for :meth:`update`.
        """
        device = self.device
        recomputed = []
        timings = {"sat_ms": 0.0, "extinction_ms": 0.0, "radiance_ms": 0.0}
        radius_world = world_radius(radius, radius_units, volume.spacing)

        identity, sample = _data_identity(volume)
        if identity != self._data_identity or not np.array_equal(sample, self._data_sample):
            # Another array object (e.g. a filter's fresh conversion): compare contents.
            data_key = _data_digest(volume)
            if data_key != self._data_key:
                self.invalidate()
                self._scalars = to_device(volume.scalars, wp.float32, device)
                # hardware filtering of this data (its textures follow with σ̃t)
                self._textured = self.hardware_filtering and fits_texture(self._scalars.shape)
                self._data_textured = self._textured or (
                    self.data_textures and fits_texture(self._scalars.shape))
                self._data_key = data_key
            self._data_identity = identity
            self._data_sample = sample
        data_key = self._data_key

        tf_key = (data_key, _tf_key(transfer_function, unit_distance, volume.value_range))
        if tf_key != self._tf_key:
            t = time.perf_counter()
            # Around the kept scalars: a transfer-function edit uploads the tables only.
            self._medium = make_medium(volume, transfer_function, unit_distance, device=device,
                                       scalars=self._scalars)
            self._sigma_t = sigma_t_grid(self._medium, device)
            self._occupied = self._medium.occupied  # empty blocks (make_medium)
            if self._data_textured:  # the transfer function as one RGBA texture
                self._optics_texture = optics_texture(self._medium, self._optics_texture)
            wp.synchronize_device(device)
            timings["sat_ms"] = 1e3 * (time.perf_counter() - t)
            self._tf_key = tf_key
            self.stats["sat"] += 1
            recomputed.append("sat")

        ext_key = (tf_key, round(radius_world, 12))
        if ext_key != self._ext_key:
            t = time.perf_counter()
            # the cube means by separable passes, no float64 SAT (vtkillum.core.ambient.sat)
            self._sigma_tilde = ambient_extinction(self._sigma_t, volume.spacing, radius_world,
                                                   device)
            wp.synchronize_device(device)
            timings["sigma_tilde_ms"] = 1e3 * (time.perf_counter() - t)
            if self.tube_sampling == "field":
                self._step_field = step_extinction_field(
                    self._sigma_tilde, volume.spacing, radius_world, device,
                    samples=self.step_samples, out=self._step_field)
                if self.field_texture and fits_texture(self._step_field.shape):
                    self._step_field_texture = texture_from(self._step_field,
                                                            self._step_field_texture)
                else:
                    self._step_field_texture = None
            wp.synchronize_device(device)
            t_textures = time.perf_counter()
            timings["step_field_ms"] = 1e3 * (t_textures - t) - timings["sigma_tilde_ms"]
            if self._textured:  # same shape as the scalars
                self._sigma_tilde_texture = texture_from(self._sigma_tilde,
                                                         self._sigma_tilde_texture)
            if self._data_textured:
                self._scalars_texture = data_texture(self._scalars, self._sigma_tilde,
                                                     self._scalars_texture)
            wp.synchronize_device(device)
            timings["extinction_ms"] = 1e3 * (time.perf_counter() - t)
            timings["textures_ms"] = 1e3 * (time.perf_counter() - t_textures)
            self._ext_key = ext_key
            self.stats["extinction"] += 1
            recomputed.append("extinction")

        return AmbientState(self._medium, self._sigma_t, self._sigma_tilde, None, None, None,
                            None, radius_world, recomputed, timings, self._occupied)


def world_radius(radius: float, units: str, spacing) -> float:
    """The ambient radius in world units (``"voxels"`` means times the mean spacing)."""
    if isinstance(radius, bool) or not isinstance(radius, (int, float, np.floating, np.integer)):
        raise ValueError(f"ambient_scattering.radius must be a number, got {radius!r}")
    radius = float(radius)
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"ambient_scattering.radius must be positive, got {radius}")
    if units == "voxels":
        return radius * float(np.mean(spacing))
    if units == "world":
        return radius
    raise ValueError(f"ambient_scattering.radius_units must be 'voxels' or 'world', got {units!r}")


def _data_identity(volume) -> tuple:
    """Cheap identity of the data: (the array object, its address, shape and spacing), and a
    strided sample of its values (compared as is: cheaper than hashing it)."""
    s = volume.scalars
    stride = max(1, s.size // FINGERPRINT_SAMPLES)
    sample = np.array(s.reshape(-1)[::stride])
    return (id(s), s.__array_interface__["data"][0], s.shape,
            tuple(np.asarray(volume.spacing).tolist())), sample


def _upload_lights(current: Lights | None, lights, volume, kinds, vecs, rgb, radii, device,
                   key: tuple, held: tuple | None, staging: dict) -> Lights:
    """The light list on the device, written into ``current``'s arrays when the count matches.

    ``key`` holds the bytes of the four packed arrays, ``held`` those ``current`` holds: only
    the arrays that differ are copied (moving a light copies its positions alone). On CUDA
    each goes through a pinned host array kept in ``staging`` (an asynchronous copy instead
    of a pageable, synchronous one; the cache synchronises before the next edit writes it).
    """
    if current is None or current.count != len(kinds) or len(kinds) == 0 or held is None:
        return make_lights(lights, volume, device)
    targets = (current.kind, current.vec, current.rgb, current.radius)
    for slot, target, values, new, old in zip(range(4), targets, (kinds, vecs, rgb, radii),
                                              key, held):
        if new == old:
            continue
        if not target.device.is_cuda:
            target.assign(values)
            continue
        pinned = staging.get(slot)
        if pinned is None or pinned.shape != target.shape:
            pinned = staging[slot] = wp.empty(target.shape, dtype=target.dtype, device="cpu",
                                              pinned=True)
        pinned.numpy()[...] = np.asarray(values).reshape(pinned.numpy().shape)
        wp.copy(target, pinned)
    return current


def _data_digest(volume) -> tuple:
    """Content key of the data: every value, the shape and the spacing."""
    return (array_digest(volume.scalars), tuple(np.asarray(volume.spacing).tolist()))


def _tf_key(tf, unit_distance: float, value_range) -> tuple:
    """Key of the optical model: the control points' bytes (cheaper than hashing JSON)."""
    return (np.asarray(tf.scalars, dtype=np.float64).tobytes(),
            np.asarray(tf.opacity, dtype=np.float64).tobytes(),
            np.asarray(tf.colors, dtype=np.float64).tobytes(), float(unit_distance),
            tuple(float(v) for v in value_range))

