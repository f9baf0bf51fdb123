"""``AmbientExtinctionFilter``: ambient extinction and the tube-marched radiance cache (Ament 2013)."""

from __future__ import annotations

import numpy as np

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.resample import resample_points
from vtkillum.filters.base import IlluminationFilterBase

RADIUS_UNITS = ("voxels", "world")


class AmbientExtinctionFilter(IlluminationFilterBase):
    """Ambient extinction ``σ̃t`` and the ambient-scattering radiance cache on the output grid.

    Runs the first two steps of ambient volume scattering (Ament, Sadlo & Weiskopf
    2013, section 4.2) through :class:`vtkillum.core.ambient.cache.AmbientScatteringCache`:
    the mean extinction over a cube of the ambient sphere's volume from a summed-area
    table (eqs. 12–13), then light distribution by tube marching with step ``2r``
    (eqs. 14–17). Output arrays, on the output grid (the input's, or the one chosen
    with ``OutputScale`` / ``OutputDimensions``, covering the same box):

    ``ambient_extinction`` (1 component, active scalars)
        ``σ̃t`` in 1/world units, computed at the input's resolution and resampled
        trilinearly when the output grid is coarser.
    ``ambient_radiance`` (RGB)
        ``Σ_l L̃d,l``: the distributed light of all lights (tube-marched at the
        output grid's points); omitted when ``ComputeRadiance`` is off.
    ``ambient_radiance_0`` .. ``ambient_radiance_<n-1>`` (RGB)
        ``L̃d,l`` per light, in the order of the filter's lights; the radiance cache
        the ambient gather samples at ``x' - r ω_l``.

    The filter keeps the cache between executions and recomputes only what an edit
    invalidates (the paper's Table 1): a transfer-function edit recomputes the SAT,
    ``σ̃t`` and the radiance; a ``Radius`` edit ``σ̃t`` (from the kept SAT) and the
    radiance; an ``Anisotropy``, ``Albedo`` or light edit only the radiance. Use
    ``OutputScale`` 0.5 for the paper's half-resolution radiance cache.

    Parameters
    ----------
    Radius : float
        Ambient sphere radius ``r`` (default 4), in ``RadiusUnits``.
    RadiusUnits : str
        ``"voxels"`` (default; ``r`` times the mean spacing) or ``"world"``.
    ComputeRadiance : bool
        Also tube-march the radiance cache (default on); off gives ``σ̃t`` only.
    Albedo, Anisotropy
        ``Λ`` (selects the preintegration table; tables other than Λ = 0.9 are generated
        once on demand) and the Henyey–Greenstein ``g`` of the table look-ups.
    ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance, Lights, Device,
    OutputScale, OutputDimensions, InputComponent, NaNPolicy, PassInputArrays, CacheSizeMB
        As in :class:`~vtkillum.filters.base.IlluminationFilterBase`.

    Notes
    -----
    Under MPI with ``Distributed`` on (the default, see
    :attr:`distributed_by_default`), each rank computes its piece only: ``σ̃t`` from ghost
    layers, the radiance cache by handing each light's tube march from rank to rank with
    its state (:mod:`vtkillum.core.ambient.distributed_radiance`); the arrays are the
    one-rank arrays (equal in ``tests/distributed/test_ambient_filter.py``). The kept cache
    (edit-dependent recomputation) is not used in that mode.

    Units: ``σ̃t`` in 1/world units; the radiance arrays in the lights' irradiance
    units (directional: as given; point: intensity / world unit²), i.e. the light
    front level reaching each point. Cost: one SAT of the input (float64, 8 bytes
    per voxel), one cube mean per voxel, and per light and output point about
    ``box size / 2r`` table look-ups.
    """

    requires_lights = False  # σ̃t alone needs no light; the radiance needs at least one
    #: ``σ̃t`` and the radiance cache in distributed mode are the one-rank result within the
    #: rounding of a piece's summed-area table (equal in the tests, and under pvbatch, where
    #: the ParaView glue resolves the piece's unit distance from the whole image).
    distributed_by_default = True

    def __init__(self) -> None:
        super().__init__()
        self._radius = 4.0
        self._radius_units = "voxels"
        self._compute_radiance = True
        self._ambient = None  # AmbientScatteringCache, per device

    def SetRadius(self, radius: float) -> None:
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"Radius must be positive, got {radius}")
        self.set_parameter("_radius", radius)

    def GetRadius(self) -> float:
        return self._radius

    def SetRadiusUnits(self, units: str) -> None:
        if units not in RADIUS_UNITS:
            raise ValueError(f"RadiusUnits must be one of {RADIUS_UNITS}, got {units!r}")
        self.set_parameter("_radius_units", units)

    def GetRadiusUnits(self) -> str:
        return self._radius_units

    def SetComputeRadiance(self, on: bool) -> None:
        self.set_parameter("_compute_radiance", bool(on))

    def GetComputeRadiance(self) -> bool:
        return self._compute_radiance

    def ComputeRadianceOn(self) -> None:
        self.SetComputeRadiance(True)

    def ComputeRadianceOff(self) -> None:
        self.SetComputeRadiance(False)

    def GetAmbientCache(self) -> AmbientScatteringCache | None:
        """The core cache kept between executions (its ``stats`` count recomputations)."""
        return self._ambient

    def distributed_unsupported(self) -> str | None:
        return None  # σ̃t by ghost layers, the radiance cache by segment forwarding

    def _world_radius(self, spacing) -> float:
        return self._radius * float(np.mean(spacing)) if self._radius_units == "voxels" \
            else self._radius

    def distributed_ghost_levels(self, in_info=None) -> int:
        """Ghost points holding the cube of the ambient sphere around the piece, and with
        ``ComputeRadiance`` the step field's box too
        (:func:`vtkillum.core.ambient.distributed_radiance.radiance_ghost_levels`): the
        pipeline then delivers every ``σt`` the piece needs and no ghost layer is exchanged."""
        from vtkmodules.vtkCommonDataModel import vtkDataObject
        from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

        from vtkillum.core.ambient.distributed import ghost_levels_for
        from vtkillum.core.ambient.distributed_radiance import radiance_ghost_levels

        spacing = (1.0, 1.0, 1.0)
        if in_info is not None and in_info.Has(vtkDataObject.SPACING()):
            spacing = in_info.Get(vtkDataObject.SPACING())
        radius = self._world_radius(spacing)
        if self._compute_radiance and in_info is not None and in_info.Has(SDDP.WHOLE_EXTENT()):
            whole = in_info.Get(SDDP.WHOLE_EXTENT())
            dims = [whole[2 * a + 1] - whole[2 * a] + 1 for a in range(3)]
            return radiance_ghost_levels(dims, spacing, radius)
        return ghost_levels_for(radius, spacing)

    def compute_piece(self, volume, params, piece):
        """Distributed under MPI: ``σ̃t`` of this rank's piece from the ghost layers the input
        delivered (or exchanged with the neighbouring ranks),
        :func:`vtkillum.core.ambient.distributed.distributed_ambient_extinction`; with
        ``ComputeRadiance`` also the radiance cache, each light's tube march handed from rank
        to rank along its path,
        :func:`vtkillum.core.ambient.distributed_radiance.distributed_radiance_cache` (the
        one-rank result; no state is kept between executions in this mode)."""
        from vtkillum.core.ambient.distributed import distributed_ambient_extinction
        from vtkillum.core.ambient.distributed_radiance import distributed_radiance_cache

        radius = params.units.to_length(self._radius) if self._radius_units == "world" \
            else self._radius * float(np.mean(volume.spacing))
        lights = list(params.lights) if self._compute_radiance else []
        if self._compute_radiance and not lights:
            raise ValueError(self._NO_LIGHTS)
        if not lights:
            sigma_tilde = distributed_ambient_extinction(
                volume, piece.extent, piece.whole, params.transfer_function,
                params.unit_distance, radius, device=params.device,
                data_extent=piece.data_extent)
            return {"ambient_extinction": params.units.per_world_length(sigma_tilde)}
        result = distributed_radiance_cache(
            volume, piece.extent, piece.whole, params.transfer_function, params.unit_distance,
            radius, lights, params.albedo, params.anisotropy, device=params.device,
            data_extent=piece.data_extent, whole_origin=getattr(piece, "origin", None))
        params.progress(0.9)
        arrays = {"ambient_extinction": params.units.per_world_length(result.sigma_tilde),
                  "ambient_radiance": result.radiance.sum(axis=0)}
        arrays.update({f"ambient_radiance_{i}": r for i, r in enumerate(result.radiance)})
        return arrays

    _NO_LIGHTS = ("AmbientExtinctionFilter has no lights for the radiance cache; add one with "
                  "AddDirectionalLight(direction, irradiance) or call ComputeRadianceOff() for "
                  "the ambient extinction alone")

    def compute(self, volume, params):
        if self._ambient is None or self._ambient.device != params.device:
            # the filter outputs grids; no gather here, so no gather textures
            self._ambient = AmbientScatteringCache(params.device, data_textures=False)
        lights = list(params.lights) if self._compute_radiance else []
        radius = params.units.to_length(self._radius) if self._radius_units == "world" \
            else self._radius
        if self._compute_radiance and not lights:
            raise ValueError(self._NO_LIGHTS)
        if lights:
            state = self._ambient.update(
                volume, params.transfer_function, params.unit_distance, params.albedo,
                params.anisotropy, lights, radius, self._radius_units,
                cache_shape=params.output_shape)
        else:
            state = self._ambient.update_extinction(
                volume, params.transfer_function, params.unit_distance, radius,
                self._radius_units)
        params.progress(0.9)
        sigma_tilde = params.units.per_world_length(state.sigma_tilde.numpy())
        if sigma_tilde.shape != tuple(params.output_shape):
            sigma_tilde = resample_points(sigma_tilde, params.output_shape)
        arrays = {"ambient_extinction": sigma_tilde}
        if lights:
            per_light = state.radiance.numpy()
            arrays["ambient_radiance"] = per_light.sum(axis=0)
            arrays.update({f"ambient_radiance_{i}": r for i, r in enumerate(per_light)})
        return arrays
