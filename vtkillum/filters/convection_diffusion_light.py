"""``ConvectionDiffusionLightFilter``: the light volume of Zhang & Ma 2013 as a VTK algorithm."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from vtkmodules.vtkCommonCore import vtkOutputWindow
from vtkmodules.vtkCommonDataModel import vtkDataObject
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

from vtkillum.core.convection_diffusion.convection import SCHEMES
from vtkillum.core.convection_diffusion.diffusion import SOLVERS
from vtkillum.core.convection_diffusion.distributed import (
    distributed_light_volume,
    required_data_extent,
)
from vtkillum.core.convection_diffusion.solver import (
    DEFAULT_TOLERANCE,
    MODELS,
    PHYSICAL_SOLVERS,
    ConvectionDiffusionSolver,
    UpdateStats,
)
from vtkillum.core.lights import DIRECTIONAL, resolved_radius
from vtkillum.core.volume import GridGeometry
from vtkillum.filters.base import IlluminationFilterBase, pass_arrays
from vtkillum.io.illumination_arrays import illumination_arrays

__all__ = ["DEFAULT_LIGHT_VOLUME_SCALE", "MODELS", "SCHEMES", "SOLVERS",
           "ConvectionDiffusionLightFilter"]

#: Default light-volume resolution relative to the data (the paper's choice).
DEFAULT_LIGHT_VOLUME_SCALE = 0.5


class ConvectionDiffusionLightFilter(IlluminationFilterBase):
    """Convection–diffusion light volume (Zhang & Ma, I3D 2013) on a grid covering the input.

    Runs :class:`vtkillum.core.convection_diffusion.ConvectionDiffusionSolver`: per light
    the steady transmittance (exact in one ordered sweep), their composition (eq. 22),
    then the diffusion of ``DiffusionModel``. The output grid *is* the light volume; it
    covers the input's box at ``LightVolumeScale`` times its resolution. Output arrays
    (the illumination-volume convention of :mod:`vtkillum.io.illumination_arrays`):

    ``fluence`` (RGB, active scalars)
        All light as an isotropic fluence (for display): ``sum_l T_l E_l + phi_s``
        (physical) or the paper's diffused light volume ``L``.
    ``transmittance`` (one component per light; physical model only)
        ``T_l`` towards each light: the direct light, which the mappers shade with the
        phase function.
    ``scattered_fluence`` (RGB)
        Physical: ``phi_s``, the fluence of light scattered at least once (diffusion
        approximation of radiative transfer). Paper: ``L`` (the direct light included,
        isotropic, as the paper shades it).

    and the lights as field data ``vtkillum_lights``.

    The filter keeps the solver between executions and recomputes only what changed
    (the paper's Algorithm 1): an opacity edit re-sweeps every light, moving one light
    re-sweeps that light, a colour/intensity edit only recomposes, ``Scattering``
    (paper) or ``Anisotropy`` (physical) only re-diffuses. Time steps warm-start the
    diffusion from the previous one.

    Parameters
    ----------
    LightVolumeScale : float
        Light-volume resolution relative to the input, in (0, 1]; default 0.5. The
        same as the base class's ``OutputScale`` (``OutputDimensions`` overrides both).
    DiffusionModel : str
        ``"physical"`` (default): the scattered light from the diffusion approximation of
        radiative transfer, everything derived from the optical model (``Albedo``,
        ``Anisotropy``, the colour and opacity functions); ``Scattering`` is not used.
        ``"paper"``: Zhang & Ma's eq. 23 with ``Scattering``.
    Scattering : (float, float, float)
        Paper model: diffusion coefficient ``sigma_hat_s`` per RGB channel, world units²
        (the square of the distance over which light spreads); default (0, 0, 0): no
        diffusion.
    Iterations : int
        Diffusion iteration budget per execution; 0 (default) iterates until
        ``Tolerance``. With a budget, call :meth:`Refine` and update again to continue.
    Tolerance : float
        Relative residual at which the diffusion has converged; default 3e-4
        (:data:`~vtkillum.core.convection_diffusion.solver.DEFAULT_TOLERANCE`, chosen by
        accuracy).
    Solver : str
        ``"multigrid"`` (default), ``"gauss-seidel"``, and for the paper model ``"cg"`` or
        ``"dct"`` (host).
    SourceRadius : float
        Point lights' source region in world units; 0 (default): two light-grid spacings.
    ConvectionScheme : str
        ``"characteristics"`` (default, short characteristics), ``"exponential"`` or
        ``"upwind"`` (the paper's eqs. 16–20); see
        :mod:`vtkillum.core.convection_diffusion.convection`.
    Albedo, Anisotropy, ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance,
    Lights, Device, OutputDimensions, InputComponent, NaNPolicy, PassInputArrays,
    CacheSizeMB
        As in :class:`~vtkillum.filters.base.IlluminationFilterBase`.

    Notes
    -----
    Units: fluences have the lights' irradiance units (directional: irradiance as given;
    point: intensity / world unit²); extinction is ``-ln(1 - alpha) / u`` in 1/world
    units. Progress is reported after the opacity volume, after each light's
    convection, after the composition and after every diffusion iteration.
    :meth:`GetLastUpdateStats` tells which stages ran, the diffusion iterations and
    residuals, and milliseconds per stage.
    """

    #: Why this filter runs on the whole volume on every rank under MPI (mode 1).
    distributed_needs = ("the paper model's distributed diffusion solves with multigrid "
                         "only (set Solver to multigrid)")
    #: Distributed under MPI by default: the light volume is one rank's within 1e-5 of its
    #: maximum (the diffusion's sums are reduced across ranks in another order).
    distributed_by_default = True
    #: Its pieces are the light grid's, computed from the data points each needs
    #: (:func:`~vtkillum.core.convection_diffusion.distributed.required_data_extent`).
    distributed_on_output_grid = True

    def __init__(self) -> None:
        super().__init__()
        self._output_scale = DEFAULT_LIGHT_VOLUME_SCALE
        self._model = "physical"
        self._scattering = (0.0, 0.0, 0.0)
        self._iterations = 0
        self._tolerance = DEFAULT_TOLERANCE
        self._solver_name = "multigrid"
        self._source_radius = 0.0
        self._scheme = "characteristics"
        self._solver: ConvectionDiffusionSolver | None = None
        self._stats: UpdateStats | None = None

    # --- properties ----------------------------------------------------------------------------
    def SetLightVolumeScale(self, scale: float) -> None:
        try:
            self.SetOutputScale(scale)
        except ValueError:
            raise ValueError(f"LightVolumeScale must lie in (0, 1], got {scale}") from None

    def GetLightVolumeScale(self) -> float:
        return self.GetOutputScale()

    def SetDiffusionModel(self, model: str) -> None:
        if model not in MODELS:
            raise ValueError(f"DiffusionModel must be one of {MODELS}, got {model!r}")
        self.set_parameter("_model", str(model))

    def GetDiffusionModel(self) -> str:
        return self._model

    def SetScattering(self, r, g=None, b=None) -> None:
        """``sigma_hat_s`` per channel: three numbers, or one for all channels."""
        values = np.asarray(r if g is None else (r, g, b), dtype=np.float64).reshape(-1)
        if values.size == 1:
            values = np.repeat(values, 3)
        if values.shape != (3,) or not np.all(np.isfinite(values)) or np.any(values < 0):
            raise ValueError(f"Scattering must be one or three numbers >= 0 (world units²), got "
                             f"{r if g is None else (r, g, b)!r}")
        self.set_parameter("_scattering", tuple(float(v) for v in values))

    def GetScattering(self) -> tuple:
        return self._scattering

    def SetIterations(self, iterations: int) -> None:
        if int(iterations) != iterations or iterations < 0:
            raise ValueError(f"Iterations must be an integer >= 0 (0: until Tolerance), got "
                             f"{iterations!r}")
        self.set_parameter("_iterations", int(iterations))

    def GetIterations(self) -> int:
        return self._iterations

    def SetTolerance(self, tolerance: float) -> None:
        tolerance = float(tolerance)
        if not 0.0 < tolerance < 1.0:
            raise ValueError(f"Tolerance must lie in (0, 1), got {tolerance}")
        self.set_parameter("_tolerance", tolerance)

    def GetTolerance(self) -> float:
        return self._tolerance

    def SetSolver(self, solver: str) -> None:
        if solver not in SOLVERS:
            raise ValueError(f"Solver must be one of {SOLVERS}, got {solver!r} (the physical "
                             f"model takes {PHYSICAL_SOLVERS})")
        self.set_parameter("_solver_name", str(solver))

    def GetSolver(self) -> str:
        return self._solver_name

    def SetSourceRadius(self, radius: float) -> None:
        radius = float(radius)
        if not (np.isfinite(radius) and radius >= 0):
            raise ValueError(f"SourceRadius must be >= 0 world units (0: two light-grid "
                             f"spacings), got {radius}")
        self.set_parameter("_source_radius", radius)

    def GetSourceRadius(self) -> float:
        return self._source_radius

    def SetConvectionScheme(self, scheme: str) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"ConvectionScheme must be one of {sorted(SCHEMES)}, got {scheme!r}")
        self.set_parameter("_scheme", str(scheme))

    def GetConvectionScheme(self) -> str:
        return self._scheme

    # --- progressive refinement and diagnostics --------------------------------------------------
    def GetConverged(self) -> bool:
        """Whether the last execution's diffusion reached ``Tolerance`` (or, physical
        model, stalled above it: further iterations would not lower the residual)."""
        return self._stats is None or self._stats.converged

    def Refine(self) -> bool:
        """Mark the filter modified if the diffusion has not converged yet.

        The next update then runs up to ``Iterations`` more iterations from where the
        last one stopped. Returns whether there was anything left to do.
        """
        if self.GetConverged():
            return False
        self.Modified()
        return True

    def GetLastUpdateStats(self) -> UpdateStats | None:
        """What the last execution recomputed (stages, iterations, residuals, ms)."""
        return self._stats

    def ReleaseSolver(self) -> None:
        """Drop the cached light-volume state (device memory); the next run starts afresh."""
        self._solver = None

    # --- distributed mode (issue 36) ----------------------------------------------------------------
    def distributed_unsupported(self) -> str | None:
        """None (distributed) but for the paper model with a solver other than multigrid,
        and for the baked RGBA output (made from the light grid resampled to the data)."""
        if self._model == "paper" and self._solver_name != "multigrid":
            return self.distributed_needs
        if getattr(self, "_output_rgba", False):
            return ("the baked RGBA output (OutputRGBA) resamples the whole light grid to the "
                    "data; switch OutputRGBA off for the distributed light grid")
        return None

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        """Distributed mode: the input points this rank's light-grid block needs (its
        footprints and one light cell around it), not a piece of the data's split."""
        result = super().RequestUpdateExtent(request, inInfo, outInfo)
        if self._piece_mode[0] == "distributed":
            in_info = inInfo[0].GetInformationObject(0)
            out_info = outInfo.GetInformationObject(0)
            _, piece, pieces, _ = self._piece_mode
            whole = in_info.Get(SDDP.WHOLE_EXTENT())
            lo, hi, dims, shape = self._light_block(whole, out_info, piece, pieces)
            dlo, dhi = required_data_extent(lo, hi, dims, self._input_spacing(in_info), shape)
            start = np.asarray(whole[0::2])
            extent = tuple(int(v) for a in range(3)
                           for v in (start[a] + dlo[a], start[a] + dhi[a] - 1))
            in_info.Set(SDDP.UPDATE_EXTENT(), extent, 6)
        return result

    @staticmethod
    def _input_spacing(in_info):
        return np.asarray(in_info.Get(vtkDataObject.SPACING()) or (1.0, 1.0, 1.0), np.float64)

    def _light_block(self, whole, out_info, piece: int, pieces: int):
        """This rank's light-grid block ``[lo, hi)`` (the points its output piece owns), the
        data's points per axis and the light grid's."""
        from vtkillum.core.convection_diffusion.distributed_layout import extent_block
        from vtkillum.core.parallel import Decomposition

        out_whole = out_info.Get(SDDP.WHOLE_EXTENT())
        dims = tuple(int(whole[2 * a + 1] - whole[2 * a] + 1) for a in range(3))
        shape = tuple(int(out_whole[2 * a + 1] - out_whole[2 * a] + 1) for a in range(3))
        zero = tuple(v for n in shape for v in (0, n - 1))
        lo, hi = extent_block(Decomposition.of(zero, pieces).owner_extent(piece))
        return lo, hi, dims, shape

    def _execute_piece(self, image, in_info, out_info, piece: int, pieces: int):
        """This rank's piece of the light grid from
        :func:`~vtkillum.core.convection_diffusion.distributed.distributed_light_volume`
        (its owned block), widened to VTK's piece extent (the shared planes of the
        neighbours' blocks by a halo exchange); a new vtkImageData on the piece's extent."""
        from vtkmodules.vtkCommonDataModel import vtkImageData

        from vtkillum.core.parallel.comm import rank_device
        from vtkillum.core.parallel.decomposition import split_extent
        from vtkillum.core.units import WorldUnits
        from vtkillum.filters.base import IlluminationParameters, check_image_data
        from vtkillum.io.convert import add_point_array, volume_from_image_data
        from vtkillum.io.illumination_arrays import add_lights_field

        check_image_data(image)
        self.UpdateProgress(0.0)
        whole = tuple(in_info.Get(SDDP.WHOLE_EXTENT()))
        lo, hi, dims, shape = self._light_block(whole, out_info, piece, pieces)
        name, association = self._selected_array(image)
        component = "magnitude" if self._input_component == -1 else self._input_component
        volume = volume_from_image_data(image, name, component, self._nan_policy, association)
        if not self._lights:
            raise ValueError(f"{type(self).__name__} has no lights; add one with "
                             "AddDirectionalLight(direction, irradiance) or AddPointLight(...)")
        units = WorldUnits.for_volume(volume)
        canonical = units.volume(volume)
        data_start = np.asarray(image.GetExtent()[0::2]) - np.asarray(whole[0::2])
        # the whole box in canonical units (its first point; the piece's minus its offset)
        box = _Box(dims, np.asarray(canonical.spacing, np.float64),
                   np.asarray(canonical.origin, np.float64)
                   - np.asarray(canonical.direction) @ (data_start * canonical.spacing),
                   np.asarray(canonical.direction, np.float64))
        lights = units.lights(list(self._lights), volume)
        tf = self._transfer_function(volume)
        unit_distance = units.to_length(self._unit_distance or volume.mean_spacing())
        params = IlluminationParameters(
            transfer_function=tf, unit_distance=unit_distance, albedo=self._albedo,
            anisotropy=self._anisotropy, lights=lights,
            device=rank_device(None, self._device), output_shape=shape, units=units,
            progress=lambda fraction: self.UpdateProgress(float(np.clip(fraction, 0.0, 1.0))))
        with units.explained():
            local = distributed_light_volume(
                canonical.scalars, data_start, dims, box.spacing, tf, unit_distance, lights,
                origin=box.origin, direction=box.direction, light_volume_shape=shape,
                block=(lo, hi), diffusion_model=self._model,
                scattering=units.to_length(self._scattering, 2), solver=self._solver_name,
                tolerance=self._tolerance, iterations=self._iterations,
                source_radius=units.to_length(self._source_radius),
                convection_scheme=self._scheme, albedo=params.albedo,
                anisotropy=params.anisotropy, device=params.device)
        self._stats = UpdateStats(shape=shape, model=self._model, opacity=True,
                                  convected=list(range(len(lights))), composed=True,
                                  diffused=True, diffusion=local.diffusion,
                                  converged=local.diffusion.converged or local.diffusion.stalled,
                                  ms=dict(local.ms))
        arrays = piece_arrays(local, box, lights)
        out_whole = tuple(out_info.Get(SDDP.WHOLE_EXTENT()))
        extent = split_extent(out_whole, piece, pieces)
        first = np.asarray(extent[0::2]) - np.asarray(out_whole[0::2])
        last = np.asarray(extent[1::2]) - np.asarray(out_whole[0::2]) + 1
        arrays = widen_to_piece(arrays, lo, hi, first, last, shape)
        output = vtkImageData()
        output.SetExtent(*extent)
        output.SetOrigin(out_info.Get(vtkDataObject.ORIGIN()))
        output.SetSpacing(out_info.Get(vtkDataObject.SPACING()))
        output.SetDirectionMatrix(out_info.Get(vtkDataObject.DIRECTION()))
        if shape == dims and self._pass_input_arrays:  # the light grid is the data grid
            # The input's arrays on this piece, as the whole-volume run passes them on.
            in_extent = tuple(int(extent[i] - out_whole[i - i % 2] + whole[i - i % 2])
                              for i in range(6))
            piece_image = vtkImageData()
            piece_image.ShallowCopy(image)
            piece_image.Crop(in_extent)
            pass_arrays(piece_image, output)
        for index, (array_name, values) in enumerate(arrays.items()):
            add_point_array(output, array_name, np.asarray(values, np.float32),
                            set_active=index == 0)
        add_lights_field(output, list(self._lights))
        time = self._input_time(image, out_info)
        if time is not None:
            output.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(), time)
        mode = f"{self._label()}: piece {piece + 1} of {pieces}: {local.mode}"
        if mode not in self._notes_given:
            self._notes_given.add(mode)
            vtkOutputWindow.GetInstance().DisplayText(mode + "\n")
        return output

    # --- computation ------------------------------------------------------------------------------
    def compute(self, volume, params):
        if self._solver is None or self._solver.device != params.device:
            self._solver = ConvectionDiffusionSolver(device=params.device)
        solver = self._solver
        solver.light_volume_shape = params.output_shape
        solver.diffusion_model = self._model
        solver.scattering = params.units.to_length(self._scattering, 2)  # world units²
        solver.iterations = self._iterations
        solver.tolerance = self._tolerance
        solver.solver = self._solver_name
        solver.source_radius = params.units.to_length(self._source_radius)
        solver.convection_scheme = self._scheme
        self._stats = solver.update(volume, params.transfer_function, params.unit_distance,
                                    params.lights, volume_key=self._volume_key(volume),
                                    albedo=params.albedo, anisotropy=params.anisotropy,
                                    progress=params.progress)
        return illumination_arrays(solver.illumination_volume(volume), volume, params.lights,
                                   params.output_shape)

    def _volume_key(self, volume):
        """Identity of the converted input without hashing it: data MTime plus selection.

        ``vtkDataSet.GetMTime`` includes its arrays' modification times, so new data (a
        new time step, an edited array) give a new key.
        """
        image = self.GetInputDataObject(0, 0)
        return (id(image), image.GetMTime() if image is not None else 0, volume.dims,
                self._input_component, self._nan_policy, self._selection_key())

    def _selection_key(self) -> tuple:
        info = self.GetInputArrayInformation(0)
        keys = (vtkDataObject.FIELD_NAME(), vtkDataObject.FIELD_ASSOCIATION(),
                vtkDataObject.FIELD_ATTRIBUTE_TYPE())
        return tuple(info.Get(k) if info.Has(k) else None for k in keys)


@dataclass
class _Box(GridGeometry):
    """The whole data grid's geometry (no data) for a distributed piece."""

    dims: tuple
    spacing: np.ndarray
    origin: np.ndarray
    direction: np.ndarray


def block_irradiance(light, box, shape, lo, hi) -> np.ndarray:
    """:func:`~vtkillum.core.lights.irradiance_on_grid` on block ``[lo, hi)`` of the grid of
    ``shape`` points (the same per-point arithmetic)."""
    size = tuple(int(b - a) for a, b in zip(lo, hi))
    if light.kind == DIRECTIONAL:
        return np.broadcast_to(np.asarray(light.irradiance, np.float32), (*size, 3)).copy()
    spacing = box.extent / (np.asarray(shape) - 1)
    p = box.to_local(light.position)
    axes = [(np.arange(n) * h - c)[a:b] for n, h, c, a, b in zip(shape, spacing, p, lo, hi)]
    d2 = (axes[0][:, None, None] ** 2 + axes[1][None, :, None] ** 2
          + axes[2][None, None, :] ** 2)
    d2 = np.maximum(d2, max(resolved_radius(light, box), 0.5 * float(spacing.min())) ** 2)
    return (np.asarray(light.intensity)[None, None, None, :] / d2[..., None]).astype(np.float32)


def piece_arrays(local, box, lights) -> dict:
    """The output arrays (``illumination_arrays``' names and values) on a rank's block:
    physical: ``fluence = phi_s~ + sum_l T_l E_l``, ``transmittance``, ``scattered_fluence
    = phi_s~`` (filtered along surfaces); paper: ``L`` as fluence and scattered fluence."""
    if local.model == "paper":
        return {"fluence": local.scattered_fluence, "scattered_fluence": local.scattered_fluence}
    scattered = local.rendered_scattered_fluence
    total = scattered.copy()
    for li, light in enumerate(lights):
        total += local.transmittance[li][..., None] * block_irradiance(
            light, box, local.shape, local.lo, local.hi)
    return {"fluence": total,
            "transmittance": np.clip(np.moveaxis(local.transmittance, 0, -1), 0.0, 1.0),
            "scattered_fluence": scattered}


def widen_to_piece(arrays, lo, hi, first, last, shape) -> dict:
    """The arrays of block ``[lo, hi)`` on the piece ``[first, last)`` that covers it (VTK's
    pieces share their boundary planes), the rest from the owners by a halo exchange."""
    import warp as wp

    from vtkillum.core.convection_diffusion.distributed_layout import Halo, Layout, region
    from vtkillum.core.parallel import Parallel

    comm = Parallel.create().comm
    boxes = comm.allgather(((np.asarray(lo), np.asarray(hi)),
                            (np.asarray(first), np.asarray(last))))
    layout = Layout(shape, [b for b, _ in boxes], comm.Get_rank(), [g for _, g in boxes])
    halo = Halo(comm, layout)
    size = tuple(int(b - a) for a, b in zip(first, last))
    out = {}
    for tag, (name, values) in enumerate(arrays.items()):
        values = np.asarray(values, np.float32)
        comps = values.shape[3:]
        wide = np.zeros(size + comps, np.float32)
        wide[region(lo, hi, first)] = values
        channels = [wide] if comps in ((), (3,)) else [np.ascontiguousarray(wide[..., c])
                                                       for c in range(comps[0])]
        done = []
        for c, channel in enumerate(channels):
            arr = wp.array(channel, dtype=wp.vec3 if channel.ndim == 4 else wp.float32,
                           device="cpu")
            halo.exchange(arr, 7000 + 16 * tag + c)
            done.append(arr.numpy())
        out[name] = done[0] if len(done) == 1 and comps in ((), (3,)) else np.stack(done, -1)
    return out
