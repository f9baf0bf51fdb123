"""The ``transmittance`` method: a cached single-scattering light volume, then ray casting.

The baseline that later illumination methods are compared with: the transmittance
``T_l`` towards every light is computed once on a light grid
(:func:`vtkillum.core.light_transmittance.light_transmittance`, what
``LightTransmittanceFilter`` caches) and the image is ray cast with it
(:func:`vtkillum.core.raycast.render_illuminated`), which applies the phase function
and the irradiance per sample. With the default shading this equals ``single`` up to
the light grid's interpolation, for any anisotropy ``g``.
"""

from __future__ import annotations

import time

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.light_transmittance import light_transmittance
from vtkillum.core.raycast import render_illuminated
from vtkillum.core.resample import scaled_shape


def render_transmittance(volume, scene, width, height, device=None, progress=None,
                         light_volume_scale: float = 1.0, **options):
    """Render with a light-transmittance illumination volume (registry signature).

    Parameters
    ----------
    light_volume_scale : float
        Light-grid resolution relative to the data (0 < scale <= 1; at least 2 points
        per axis).
    **options
        Ray-casting options of :func:`vtkillum.core.raycast.render_illuminated`.
    """
    if not (0.0 < float(light_volume_scale) <= 1.0):
        raise ValueError(f"light_volume_scale must lie in (0, 1], got {light_volume_scale}")
    shape = scaled_shape(volume.dims, light_volume_scale)
    tf = scene.resolved_transfer_function(volume)
    u = scene.resolved_unit_distance(volume)
    # The light volume does not depend on the camera: kept with the volume until an input
    # it depends on changes.
    key = (device, shape, tf.scalars.tobytes(), tf.opacity.tobytes(), float(u),
           repr([light.to_dict() for light in scene.lights]))
    # It stays on the device, checked there once: a camera move moves no volume-sized data.
    t0 = time.perf_counter()
    illumination = volume.derived(
        "light_transmittance", key,
        lambda: IlluminationVolume.for_volume(volume, transmittance=light_transmittance(
            volume, tf, u, scene.lights, shape=shape, device=device, on_device=True)[0]))
    t1 = time.perf_counter()
    result = render_illuminated(volume, scene, width, height, device, progress,
                                illumination=illumination, **options)
    result.info.update(method="transmittance", light_volume_s=t1 - t0,
                       light_volume_shape=shape,
                       transmittance_min=illumination.transmittance_range[0])
    return result
