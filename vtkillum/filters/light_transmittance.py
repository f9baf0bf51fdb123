"""``LightTransmittanceFilter``: shadow rays to every light, cached as a light volume."""

from __future__ import annotations

import numpy as np

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.light_transmittance import SEGMENT_PLANES, light_transmittance
from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.illumination_arrays import illumination_arrays


class LightTransmittanceFilter(IlluminationFilterBase):
    """Transmittance towards each light and the unscattered fluence, on a light grid.

    Runs :func:`vtkillum.core.light_transmittance.light_transmittance` on the
    output grid (the input's resolution or the one chosen with ``OutputScale`` /
    ``OutputDimensions``, covering the same box). Output arrays:

    ``fluence`` (RGB, active scalars)
        ``phi(x) = sum_l T_l(x) E_l(x)``, the unscattered light as an isotropic fluence
        (for display).
    ``transmittance`` (one component per light)
        ``T_l(x)`` in [0, 1] towards light ``l``, in the order of the filter's lights:
        the direct light that the mappers shade with the phase function
        (:mod:`vtkillum.core.illumination`).
    ``scattered_fluence`` (RGB)
        Zeros (this filter computes no scattering).

    and the lights as field data ``vtkillum_lights``
    (:mod:`vtkillum.io.illumination_arrays`).

    Parameters
    ----------
    ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance
        The optical model (only the opacity matters here); see
        :class:`~vtkillum.filters.base.IlluminationFilterBase`.
    Lights
        ``AddDirectionalLight(direction, irradiance)``, ``AddPointLight(position,
        intensity)``, ``SetLight``, ``RemoveAllLights``; at least one.
    StepSize : float
        Longest step along shadow rays in world units; 0 (default) means half the
        smallest input spacing.
    SegmentPlanes : int
        Directional lights: chained shadow-ray segments, interpolating ``T`` every ``L``
        output-grid planes (default 16: O(N³ L) instead of O(N⁴); sharp shadow edges blur
        by about ``sqrt(N/L)/2`` cells; see :mod:`vtkillum.core.light_transmittance`).
        0: one exact shadow ray per point. Point lights always get exact rays. Either way
        the distributed mode gives the one-rank arrays (chained: slab by slab across the
        ranks, :mod:`vtkillum.core.parallel.chained`). The grid samples the data from
        arrays, not CUDA textures, so that one rank and N ranks agree on a GPU too.
    Device, OutputScale, OutputDimensions, InputComponent, NaNPolicy, PassInputArrays, CacheSizeMB
        As in the base class.

    Notes
    -----
    ``fluence`` has the lights' irradiance units (directional: irradiance as given;
    point: intensity / world unit²). Cost: point lights (and SegmentPlanes 0): one
    shadow ray per light and output point, each about (box size / StepSize) samples;
    directional lights: at most SegmentPlanes planes' worth of samples per point.
    """

    # Only the opacity shadows: a colour, albedo or anisotropy edit reuses the arrays.
    illumination_depends_on = frozenset()
    reuses_results = True
    #: Under MPI the distributed march gives the one-rank arrays bit for bit: on by default.
    distributed_by_default = True

    def __init__(self) -> None:
        super().__init__()
        self._step_size = 0.0
        self._segment_planes = SEGMENT_PLANES

    def SetStepSize(self, step: float) -> None:
        step = float(step)
        if not (np.isfinite(step) and step >= 0):
            raise ValueError(f"StepSize must be >= 0 (0: half the smallest spacing), got {step}")
        self.set_parameter("_step_size", step)

    def GetStepSize(self) -> float:
        return self._step_size

    def SetSegmentPlanes(self, planes: int) -> None:
        planes = int(planes)
        if planes < 0:
            raise ValueError(f"SegmentPlanes must be >= 0 (0: exact shadow rays), got {planes}")
        self.set_parameter("_segment_planes", planes)

    def GetSegmentPlanes(self) -> int:
        return self._segment_planes

    def compute_piece(self, volume, params, piece):
        """Distributed under MPI: the one-rank shadow rays, marched across the ranks
        (:func:`vtkillum.core.parallel.transmittance.distributed_light_transmittance`), on
        this rank's piece; no ghost levels (neighbouring pieces share their planes). The
        arrays equal the one-rank filter's bit for bit (chained segments too:
        :mod:`vtkillum.core.parallel.chained`)."""
        from vtkillum.core.parallel.transmittance import distributed_light_transmittance

        transmittance, _fluence = distributed_light_transmittance(
            volume, piece.extent, piece.whole, params.transfer_function, params.unit_distance,
            params.lights, step_size=params.units.to_length(self._step_size) or None,
            device=params.device, progress=params.progress, origin=piece.origin,
            segment_planes=self._segment_planes)
        illumination = IlluminationVolume.for_volume(volume, transmittance=transmittance)
        return illumination_arrays(illumination, volume, params.lights, params.output_shape)

    def compute(self, volume, params):
        transmittance, _fluence = light_transmittance(
            volume, params.transfer_function, params.unit_distance, params.lights,
            shape=params.output_shape, step_size=params.units.to_length(self._step_size) or None,
            device=params.device, progress=params.progress,
            segment_planes=self._segment_planes, textures=False)
        illumination = IlluminationVolume.for_volume(volume, transmittance=transmittance)
        return illumination_arrays(illumination, volume, params.lights, params.output_shape)
