"""One entry point for every rendering method, and the result type they share.

Methods register here by name with the import path of their render function, so
that each lives in its own module and is imported only when used::

    result = render(volume, scene, method="single", width=256, height=256)
    result.radiance   # (H, W, 3) float32, linear
    result.alpha      # (H, W) float32, 1 - transmittance along the primary ray

Every render function has the signature
``fn(volume, scene, width, height, device, progress, **options) -> RenderResult``.

World units: :func:`render` hands every method the volume and scene in canonical units
(:mod:`vtkillum.core.units`: lengths in units of about the mean spacing), so that the
same scene described at any length scale gives the same image; point-light intensities
scale with the square of the length unit. Radiance, alpha and fluence have no length in
them and come back as the method computes them.
"""

from __future__ import annotations

import importlib

import numpy as np

from vtkillum.core.device import resolve_device
from vtkillum.core.units import canonical

#: method name -> "module:function"
METHODS: dict[str, str] = {
    "emission": "vtkillum.core.raycast:render_emission",
    "single": "vtkillum.core.raycast:render_single",
    "illumination": "vtkillum.core.raycast:render_illuminated",
    "path": "vtkillum.core.pathtrace:render_path",
    "transmittance": "vtkillum.core.transmittance_render:render_transmittance",
    "ambient-scattering": "vtkillum.core.ambient.render:render_ambient_scattering",
    "convection-diffusion": "vtkillum.core.convection_diffusion.render:render_convection_diffusion",
    "photon": "vtkillum.core.photon.render:render_photon",
    "refraction": "vtkillum.core.refraction.render:render_refraction",
    "many-lights": "vtkillum.core.many_lights.render:render_many_lights",
}


class RenderResult:
    """Linear radiance and alpha of a rendered image.

    Attributes
    ----------
    radiance : ndarray (H, W, 3) float32
        Linear radiance reaching the camera from the volume (background excluded).
    alpha : ndarray (H, W) float32
        ``1 - transmittance`` along each primary ray.
    info : dict
        Method-specific diagnostics (timings, sample counts, ...).
    device : tuple or None
        ``(radiance, alpha)`` as warp arrays (``array2d(vec3)``, ``array2d(float32)``) on
        the device that rendered them, for a renderer that keeps its image there (the
        ray caster): :attr:`radiance` and :attr:`alpha` are then downloaded on first
        access (once), so a consumer on the device (the compute mapper's tone map,
        :func:`vtkillum.core.tonemap.tonemap_device`) moves no float image to the host.
    """

    def __init__(self, radiance=None, alpha=None, info: dict | None = None,
                 device: tuple | None = None) -> None:
        if device is None and (radiance is None or alpha is None):
            raise ValueError("a RenderResult needs radiance and alpha arrays or device arrays")
        self._radiance = radiance
        self._alpha = alpha
        self.info = {} if info is None else info
        self.device = device

    @property
    def radiance(self) -> np.ndarray:
        if self._radiance is None:
            rad = self.device[0]
            self._radiance = rad.numpy().reshape(rad.shape[0], rad.shape[1], 3)
        return self._radiance

    @radiance.setter
    def radiance(self, value) -> None:
        self._radiance = value
        self.device = None  # the host arrays are the result now

    @property
    def alpha(self) -> np.ndarray:
        if self._alpha is None:
            self._alpha = self.device[1].numpy()
        return self._alpha

    @alpha.setter
    def alpha(self, value) -> None:
        self._alpha = value
        self.device = None

    def composite(self, background=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Radiance with ``background`` seen through the volume: ``L + (1 - alpha) * bg``."""
        bg = np.asarray(background, dtype=np.float32)
        return self.radiance + (1.0 - self.alpha)[..., None] * bg

    def __repr__(self) -> str:
        shape = tuple(self.device[1].shape) if self._alpha is None else self._alpha.shape
        return f"RenderResult(shape={shape}, on_device={self._radiance is None}, info={self.info})"


def render(volume, scene, method: str = "emission", width: int = 256, height: int = 256,
           device: str | None = None, progress=None, **options) -> RenderResult:
    """Render ``volume`` as described by ``scene`` with a registered method.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
    method : str
        One of :data:`METHODS`.
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device; default CUDA when present, else CPU (``VTKILLUM_DEVICE`` overrides).
    progress : callable, optional
        Called as ``progress(fraction_done)`` during long renders.
    **options
        Method-specific options (e.g. ``spp`` for ``path``, ``illumination`` for
        ``illumination``). Lengths among them (``step_size`` ...) in world units.

    Notes
    -----
    The scene is rendered in canonical units (:mod:`vtkillum.core.units`): any length
    unit gives the same picture, with point-light intensities in units of (world
    length)², i.e. scaled by ``s²`` when the world is scaled by ``s``. A light the
    kernels cannot represent at the volume's scale is refused before any work starts, and
    so is a render whose device state would not fit in the device's free memory
    (:func:`vtkillum.core.memory.check_fits` raises a ``DeviceMemoryError`` naming the
    largest volume that fits and ``light_volume_scale``).
    """
    fn = method_function(method)
    device = resolve_device(device)
    check_memory(volume, scene, method, int(width), int(height), device, options)
    volume, scene, options, units = canonical(volume, scene, options)
    with units.explained():
        result = fn(volume, scene, int(width), int(height), device, progress, **options)
    units.info(result.info)
    return result


def check_memory(volume, scene, method: str, width: int, height: int, device: str,
                 options: dict) -> None:
    """:func:`vtkillum.core.memory.check_fits` for this render, once per volume, device and
    setting that changes the footprint (a camera move or an edit is not checked again).

    The settings come from ``options`` over the scene's method section; a volume whose
    scalars are already on ``device`` counts them as free (they are reused).
    """
    from vtkillum.core.memory import FOOTPRINTS, check_fits

    if method not in FOOTPRINTS:
        return
    section = {"convection-diffusion": "convection_diffusion",
               "ambient-scattering": "ambient_scattering", "photon": "photon",
               "many-lights": "many_lights"}.get(method)
    merged = dict(scene.options.get(section, {}) if section else {})
    merged.update(options)
    scale = merged.get("light_volume_scale")
    settings = {k: merged[k] for k in ("radiance_cache_scale", "data_textures", "photons",
                                       "segments", "count", "avsm_resolution", "avsm_nodes",
                                       "view_samples") if k in merged}
    n_lights = len(scene.lights)
    key = (method, n_lights, scale, tuple(sorted(settings.items())), width, height)
    try:
        if getattr(volume, "_derived", None) is None:
            check_fits(method, volume.dims, n_lights, scale, settings, (width, height), device)
            return
        held = 4 * int(np.prod(volume.dims)) if f"scalars@{device}" in volume._derived else 0
        volume.derived(f"memory_checked@{device}", key,
                       lambda: check_fits(method, volume.dims, n_lights, scale, settings,
                                          (width, height), device, held_bytes=held))
    except (ValueError, TypeError):
        return  # a bad setting: the method's own check names it in its words


def method_function(method: str):
    """Import and return the render function registered as ``method``."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {sorted(METHODS)}")
    module, name = METHODS[method].split(":")
    return getattr(importlib.import_module(module), name)
