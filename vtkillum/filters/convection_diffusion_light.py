"""``ConvectionDiffusionLightFilter``: the light volume of Zhang & Ma 2013 as a VTK algorithm."""

from __future__ import annotations

import numpy as np
from vtkmodules.vtkCommonDataModel import vtkDataObject

from vtkillum.core.convection_diffusion.convection import SCHEMES
from vtkillum.core.convection_diffusion.diffusion import SOLVERS
from vtkillum.core.convection_diffusion.solver import (
    DEFAULT_TOLERANCE,
    MODELS,
    PHYSICAL_SOLVERS,
    ConvectionDiffusionSolver,
    UpdateStats,
)
from vtkillum.filters.base import IlluminationFilterBase
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
    distributed_needs = ('the distributed convection-diffusion core (vtkillum.core.convection_diffusion.distributed: the convection as a sweep across ranks, the diffusion as multigrid with halo exchange) is not wired into this filter yet')

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
