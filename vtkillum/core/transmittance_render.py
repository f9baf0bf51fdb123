"""The ``transmittance`` method: a cached single-scattering light volume, then ray casting.

The baseline that later illumination methods are compared with: the transmittance
``T_l`` towards every light is computed once on a light grid
(:func:`vtkillum.core.light_transmittance.light_transmittance`, what
``LightTransmittanceFilter`` caches) and the image is ray cast with it
(:func:`vtkillum.core.raycast.render_illuminated`), which applies the phase function
and the irradiance per sample. With the default shading this equals ``single`` up to
the light grid's interpolation, for any anisotropy ``g``. Directional lights' grids are
chained shadow-ray segments by default (``segment_planes``), so a transfer-function edit
costs O(N³); ``segment_planes=0`` gives the exact per-point rays.
"""

from __future__ import annotations

import time

import numpy as np

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.light_transmittance import SEGMENT_PLANES, light_transmittance
from vtkillum.core.raycast import render_illuminated
from vtkillum.core.resample import scaled_shape


def render_transmittance(volume, scene, width, height, device=None, progress=None,
                         light_volume_scale: float = 1.0, segment_planes: int = SEGMENT_PLANES,
                         **options):
    """Render with a light-transmittance illumination volume (registry signature).

    Parameters
    ----------
    light_volume_scale : float
        Light-grid resolution relative to the data (0 < scale <= 1; at least 2 points
        per axis).
    segment_planes : int
        Directional lights: light-grid planes between the chained shadow-ray segments'
        interpolations (default :data:`~vtkillum.core.light_transmittance.SEGMENT_PLANES`,
        what makes a transfer-function edit O(N³)); 0: one exact shadow ray per grid point
        (O(N⁴)). See :mod:`vtkillum.core.light_transmittance`.
    **options
        Ray-casting options of :func:`vtkillum.core.raycast.render_illuminated`.
    """
    if not (0.0 < float(light_volume_scale) <= 1.0):
        raise ValueError(f"light_volume_scale must lie in (0, 1], got {light_volume_scale}")
    if isinstance(segment_planes, bool) or not isinstance(segment_planes, (int, np.integer)) \
            or segment_planes < 0:
        raise ValueError(f"segment_planes must be a whole number >= 0 (0: exact shadow rays), "
                         f"got {segment_planes!r}")
    shape = scaled_shape(volume.dims, light_volume_scale)
    tf = scene.resolved_transfer_function(volume)
    u = scene.resolved_unit_distance(volume)
    # The light volume does not depend on the camera: kept with the volume until an input
    # it depends on changes.
    key = (device, shape, tf.scalars.tobytes(), tf.opacity.tobytes(), float(u),
           repr([light.to_dict() for light in scene.lights]), int(segment_planes),
           options.get("textures", True) is not False)
    # It stays on the device, checked there once: a camera move moves no volume-sized data.
    t0 = time.perf_counter()
    illumination = volume.derived(
        "light_transmittance", key,
        lambda: IlluminationVolume.for_volume(volume, transmittance=light_transmittance(
            volume, tf, u, scene.lights, shape=shape, device=device, on_device=True,
            segment_planes=int(segment_planes),
            textures=options.get("textures", True) is not False)[0]))
    t1 = time.perf_counter()
    result = render_illuminated(volume, scene, width, height, device, progress,
                                illumination=illumination, **options)
    result.info.update(method="transmittance", light_volume_s=t1 - t0,
                       light_volume_shape=shape, segment_planes=int(segment_planes),
                       transmittance_min=illumination.transmittance_range[0])
    return result
