"""``OpticalPropertiesFilter``: the optical model of DESIGN.md, evaluated per grid point."""

from __future__ import annotations

import numpy as np

from vtkillum.core.resample import resample_points
from vtkillum.filters.base import IlluminationFilterBase


class OpticalPropertiesFilter(IlluminationFilterBase):
    """Extinction and scattering coefficients of the data under the transfer functions.

    Output arrays, at the input's resolution or the one chosen with ``OutputScale`` /
    ``OutputDimensions`` (the data are then resampled trilinearly and classified
    afterwards, as the kernels sample them):

    ``sigma_t`` (1 component)
        Extinction ``-ln(1 - alpha(s)) / u`` (active scalars).
    ``scattering_color`` (RGB)
        Per-channel single-scattering albedo ``Albedo * color(s)``.
    ``sigma_s`` (RGB)
        Scattering coefficient ``scattering_color * sigma_t``.
    ``sigma_a`` (RGB)
        Absorption coefficient ``sigma_t - sigma_s``.

    Parameters
    ----------
    ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance, Albedo
        The optical model; see :class:`~vtkillum.filters.base.IlluminationFilterBase`.
    OutputScale, OutputDimensions, InputComponent, NaNPolicy, PassInputArrays, CacheSizeMB
        As in the base class. Lights, ``Anisotropy`` and ``Device`` do not affect
        this filter (it runs in numpy).

    Notes
    -----
    ``sigma_t``, ``sigma_s`` and ``sigma_a`` are in 1/world units (the input's
    spacing units); ``scattering_color`` is unitless in [0, 1].
    """

    #: Why this filter runs on the whole volume on every rank under MPI (mode 1).
    distributed_needs = ('per-voxel optical properties need only the whole data range; cheap on the whole volume, not distributed')

    requires_lights = False
    uses_device = False

    def compute(self, volume, params):
        scalars = volume.scalars
        if params.output_shape != volume.dims:
            scalars = resample_points(scalars, params.output_shape)
        tf = params.transfer_function
        # per world unit (compute runs in canonical units)
        sigma_t = params.units.per_world_length(tf.sigma_t(scalars, params.unit_distance))
        params.progress(0.5)
        scattering_color = params.albedo * tf.color(scalars)
        sigma_s = scattering_color * sigma_t[..., None]
        return {
            "sigma_t": sigma_t.astype(np.float32),
            "scattering_color": scattering_color.astype(np.float32),
            "sigma_s": sigma_s.astype(np.float32),
            "sigma_a": (sigma_t[..., None] - sigma_s).astype(np.float32),
        }
