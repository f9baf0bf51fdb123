"""``PhotonDensityFilter``: the photon-density illumination volume (Jönsson et al. 2012)."""

from __future__ import annotations

import numpy as np

from vtkillum.core.photon.illumination import photon_illumination
from vtkillum.core.photon.mapper import DIRECT_MODES, PhotonMapper, check_config
from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.illumination_arrays import illumination_arrays


class PhotonDensityFilter(IlluminationFilterBase):
    """Volumetric photon mapping with Historygrams, gathered onto a grid as a light volume.

    Traces ``Photons`` photon paths from the lights through the input
    (:mod:`vtkillum.core.photon.tracing`: ray-marched free paths, Russian roulette with
    ``p = σs/σt``, Henyey–Greenstein scattering, at most ``MaxOrder`` interactions), sorts
    them into a spatial hash and estimates the fluence at every output grid point
    (eq. 8 of the paper, :mod:`vtkillum.core.photon.density`). Output arrays, in the
    project's illumination-volume convention (:mod:`vtkillum.io.illumination_arrays`):

    ``fluence`` (RGB, active scalars)
        ``Σ_l T_l E_l + φ_s``, the total light for display.
    ``transmittance`` (one component per light; ``DirectLight`` "exact" only)
        ``T_l`` towards each light: the direct light, shaded with the phase function by
        the mappers (:func:`~vtkillum.core.light_transmittance.light_transmittance`'s
        default grid: chained shadow-ray segments for directional lights, exact rays for
        point lights; Light Transmittance's ``SegmentPlanes`` 16).
    ``scattered_fluence`` (RGB)
        ``φ_s``: the photon estimate of light that has scattered at least once (with
        ``DirectLight`` "photons": of all light).

    and the lights as field data. The filter keeps its photon map between executions:
    with ``Historygrams`` on, a transfer-function edit retraces only the photons whose
    Historygram meets the edit's query mask, from their last valid interaction (section
    4.3.1); any other change traces a new map. ``GetLastUpdateStats`` says what ran.

    Parameters
    ----------
    Photons : int
        Photon paths ``P_n`` per pass; 0 (default): from a pilot trace, enough photons for
        a kernel of 2 voxels (:func:`vtkillum.core.photon.radius.auto_photons`; 200000
        before issue 34).
    Radius : float
        Photon radius in voxels (× mean input spacing) of the first pass; 0 (default):
        chosen from the photon map (:mod:`vtkillum.core.photon.radius`; 2 before issue
        34).
    MaxOrder : int
        ``S_n``: interactions per photon at most; 1 = single scattering, 0 (default) =
        unbounded (Russian roulette only).
    Seed : int
        Seed of the photons (default 0).
    Passes : int
        Progressive passes averaged (independent maps, radius shrinking as
        ``r_{i+1}³ = r_i³ (i + 2/3) / (i + 1)``); default 1.
    Historygrams : bool
        Incremental updates after transfer-function edits (default on).
    DirectLight : str
        ``"exact"`` (default): transmittance per light plus scattered photons;
        ``"photons"``: all light from photons (the paper's estimate; isotropic).
    StepSize : float
        Ray-marching step of photon flights and shadow rays, world units; 0 (default):
        half the smallest input spacing.
    ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance, Albedo, Anisotropy,
    Lights, Device, OutputScale, OutputDimensions, InputComponent, NaNPolicy,
    PassInputArrays, CacheSizeMB
        As in :class:`~vtkillum.filters.base.IlluminationFilterBase`.

    Notes
    -----
    Units: fluences in the lights' irradiance units (directional: irradiance as given;
    point: intensity / world unit²). Memory: about 68 bytes per stored photon interaction
    (a few per photon with high albedo); more photons than fit raise an error that says
    how many fit. Cost: the photon trace (``Photons`` × path length × steps per flight)
    plus one 27-cell gather per output point.
    """

    #: Why this filter runs on the whole volume on every rank under MPI (mode 1).
    distributed_needs = ('a distributed version hands each photon to the rank that owns the cell it enters and gathers the density with a ghost radius; not built yet')

    def __init__(self) -> None:
        super().__init__()
        self._photons = 0
        self._radius = 0.0
        self._max_order = 0
        self._seed = 0
        self._passes = 1
        self._historygrams = True
        self._direct = "exact"
        self._step_size = 0.0
        self._mapper: PhotonMapper | None = None
        self._mapper_key = None
        self._stats: dict | None = None

    # --- properties ----------------------------------------------------------------------------
    def SetPhotons(self, photons: int) -> None:
        check_config(photons, 1.0, 0, 1, "exact", 0.5)
        self.set_parameter("_photons", int(photons))

    def GetPhotons(self) -> int:
        return self._photons

    def SetRadius(self, radius: float) -> None:
        radius = float(radius)
        if not (np.isfinite(radius) and radius >= 0):
            raise ValueError(f"Radius must be >= 0 voxels (0: automatic), got {radius}")
        self.set_parameter("_radius", radius)

    def GetRadius(self) -> float:
        return self._radius

    def SetMaxOrder(self, order: int) -> None:
        check_config(1, 1.0, order, 1, "exact", 0.5)
        self.set_parameter("_max_order", int(order))

    def GetMaxOrder(self) -> int:
        return self._max_order

    def SetSeed(self, seed: int) -> None:
        if int(seed) != seed or not 0 <= int(seed) < 2**31:
            raise ValueError(f"Seed must be an integer in [0, 2**31), got {seed!r}")
        self.set_parameter("_seed", int(seed))

    def GetSeed(self) -> int:
        return self._seed

    def SetPasses(self, passes: int) -> None:
        if int(passes) != passes or int(passes) < 1:
            raise ValueError(f"Passes must be a positive integer, got {passes!r}")
        self.set_parameter("_passes", int(passes))

    def GetPasses(self) -> int:
        return self._passes

    def SetHistorygrams(self, on: bool) -> None:
        self.set_parameter("_historygrams", bool(on))

    def GetHistorygrams(self) -> bool:
        return self._historygrams

    def HistorygramsOn(self) -> None:
        self.SetHistorygrams(True)

    def HistorygramsOff(self) -> None:
        self.SetHistorygrams(False)

    def SetDirectLight(self, mode: str) -> None:
        if mode not in DIRECT_MODES:
            raise ValueError(f"DirectLight must be one of {DIRECT_MODES}, got {mode!r}")
        self.set_parameter("_direct", str(mode))

    def GetDirectLight(self) -> str:
        return self._direct

    def SetStepSize(self, step: float) -> None:
        step = float(step)
        if not (np.isfinite(step) and step >= 0):
            raise ValueError(f"StepSize must be >= 0 (0: half the smallest spacing), got {step}")
        self.set_parameter("_step_size", step)

    def GetStepSize(self) -> float:
        return self._step_size

    def GetLastUpdateStats(self) -> dict | None:
        """What the last execution did to the photon map (``mode``, photons retraced, ms)."""
        return self._stats

    def GetPhotonMapper(self) -> PhotonMapper | None:
        """The core photon mapper kept between executions."""
        return self._mapper

    def ReleasePhotonMap(self) -> None:
        """Drop the photon map (device memory); the next run traces afresh."""
        self._mapper = None

    # --- computation -----------------------------------------------------------------------------
    def compute(self, volume, params):
        step = params.units.to_length(self._step_size) or 0.5 * float(np.min(volume.spacing))
        key = (params.device, self._photons, self._radius, volume.mean_spacing(),
               self._max_order, self._seed, self._historygrams, self._direct, step)
        if self._mapper is None or self._mapper_key != key:
            self._mapper = PhotonMapper(params.device, self._photons,
                                        self._radius * volume.mean_spacing(), self._max_order,
                                        1, self._seed, self._historygrams, False, self._direct,
                                        photon_step=step)
            self._mapper_key = key
        illumination = photon_illumination(
            self._mapper, volume, params.transfer_function, params.unit_distance,
            params.albedo, params.anisotropy, params.lights, params.output_shape,
            self._passes, step, params.progress)
        self._stats = dict(self._mapper.last_update)
        return illumination_arrays(illumination, volume, params.lights, params.output_shape)
