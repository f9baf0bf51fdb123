"""The photon-density illumination volume: what :class:`PhotonDensityFilter` hands to the mappers.

In the project's illumination-volume convention (:mod:`vtkillum.core.illumination`):

* ``direct="exact"`` (default): the direct light is the per-light transmittance ``T_l``
  of :func:`vtkillum.core.light_transmittance.light_transmittance` (the ray caster applies
  the phase function to it exactly), and the **scattered** fluence ``φ_s`` is the photon
  density estimate of the photons that have scattered at least once (order >= 2).
* ``direct="photons"`` (the paper's all-photon estimate): ``φ_s`` is the fluence of all
  photons and there is no transmittance. The direct light then carries the photon noise
  and is shaded as isotropic (``σs φ / 4π``), which is wrong for ``g != 0``; it is there to
  compare with the paper.
"""

from __future__ import annotations

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.light_transmittance import light_transmittance


def photon_illumination(mapper, volume, transfer_function, unit_distance: float, albedo: float,
                        anisotropy: float, lights, shape, passes: int = 1,
                        step_size: float | None = None, progress=None,
                        on_device: bool = False) -> IlluminationVolume:
    """Update ``mapper``'s photons and return the illumination volume on a grid of ``shape``.

    Parameters
    ----------
    mapper : vtkillum.core.photon.mapper.PhotonMapper
        Kept between calls: a transfer-function edit updates its photons incrementally.
    volume : vtkillum.core.volume.Volume
    transfer_function, unit_distance, albedo, anisotropy, lights
        The optical model and the lights (world space).
    shape : (3,) int
        Grid points per axis of the output (covering the volume's box).
    passes : int
        Progressive passes averaged into ``φ_s`` (radius shrinking per pass).
    step_size : float, optional
        Shadow-ray step of the transmittance (world units); default half a voxel.
    progress : callable, optional
        ``progress(fraction)``.
    on_device : bool
        Keep the grids on the mapper's device (a renderer there reads them without a copy;
        :class:`IlluminationVolume` downloads them only if its numpy views are read).

    Returns
    -------
    IlluminationVolume
        ``scattered`` = ``φ_s`` and, with exact direct light, ``transmittance`` ``T_l``.
    """
    mapper.update(volume, transfer_function, unit_distance, albedo, anisotropy, lights)
    if progress is not None:
        progress(0.3)
    scattered = mapper.fluence(volume, shape, passes, on_device=on_device)
    if progress is not None:
        progress(0.7)
    transmittance = None
    if mapper.direct == "exact":
        transmittance, _ = light_transmittance(volume, transfer_function, unit_distance, lights,
                                               shape=shape, step_size=step_size,
                                               device=mapper.device, on_device=on_device)
    return IlluminationVolume.for_volume(volume, scattered, transmittance)
