"""The light volume of the ``"convection-diffusion"`` method and its partial
recomputation (Zhang & Ma 2013, Fig. 2 and Algorithm 1).

Pipeline
--------
1. **Opacity volume** — extinction ``sigma_t`` and ``color * sigma_t`` on the light
   grid (default half the data's resolution), footprint-averaged
   (:mod:`~vtkillum.core.convection_diffusion.opacity`).
2. **Convection per light** — steady transmittance ``T_l`` (short characteristics
   by default, or the paper's upwind scheme), exact in one wavefront-ordered sweep
   instead of the paper's 4–5 iterations per layer
   (:mod:`~vtkillum.core.convection_diffusion.convection`).
3. **Composition** (eq. 22) — the direct fluence ``phi_d = sum_l T_l E_l``; for the
   physical model also the first-scattered source ``Q = sigma_s <T_l> E_l``
   (:mod:`~vtkillum.core.convection_diffusion.composition`), δ-Eddington scaled for
   forward scattering (``delta_scaling``: ``Q = (1 - g²) sigma_s <T*_l> E_l`` with the
   beam's extinction ``sigma_t - g² sigma_s``, one more sweep per light).
4. **Diffusion**, by ``diffusion_model``:

   ``"physical"`` (default)
       the scattered fluence ``phi_s`` from the diffusion approximation of radiative
       transfer, ``-div(D grad phi_s) + sigma_a phi_s = Q``, flux-limited, vacuum
       (Marshak) boundary, nonlinear multigrid
       (:mod:`~vtkillum.core.convection_diffusion.radiative`). Everything comes from
       the optical model (``sigma_t``, albedo, colour, ``g``); ``scattering`` is not
       used.
   ``"paper"``
       Zhang & Ma's eq. 23 as published: ``(I - sigma_hat_s laplace) L = phi_d`` per
       channel with the user's ``scattering`` ``sigma_hat_s``, pure Neumann
       (:mod:`~vtkillum.core.convection_diffusion.diffusion`).

5. **Rendering** (eq. 24) — :func:`vtkillum.core.raycast.render_illuminated` with
   :meth:`ConvectionDiffusionSolver.illumination_volume`: ``"physical"`` hands over
   the per-light ``T_l`` (direct light, shaded with the phase function per sample)
   and ``phi_s`` (isotropic); ``"paper"`` hands over ``L`` as one isotropic fluence,
   as the paper shades (so its direct light ignores the phase function).

:class:`ConvectionDiffusionSolver` keeps every intermediate result and recomputes
only what an edit invalidates, a finer version of Algorithm 1:

================================  ==================================================
change                            recomputed
================================  ==================================================
data or opacity transfer fn.      opacity, every light, composition, diffusion
colour transfer fn. (physical)    scattering colour, composition, diffusion
one light moved / turned          that light, composition, diffusion
a light's colour or intensity     composition, diffusion (no convection)
albedo (physical)                 composition, diffusion
``g`` (physical)                  composition (source dipole, δ-Eddington beams),
                                  diffusion
``scattering`` (paper), solver,   diffusion only
model
nothing (budget left over)        more diffusion iterations (progressive refinement)
================================  ==================================================

Warm starts: the paper model starts each solve from the previous solution shifted
by the change of the right-hand side, ``x0 = x_prev + (L0 - L0_prev)`` (exact where
the change is smooth on the diffusion length). The physical model starts from the
previous ``phi_s`` scaled per channel by ``||Q|| / ||Q_prev||`` (exact for an
intensity edit: the flux limiter does not depend on the scale of ``phi``). Time
steps and edits converge in fewer iterations than a cold start
(``UpdateStats.diffusion``). The convection needs no warm start, it is exact in
one sweep.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.composition import compose_direct, first_scattered_source
from vtkillum.core.convection_diffusion.convection import SCHEMES, convect_lights
from vtkillum.core.convection_diffusion.diffusion import SOLVERS, DiffusionReport, DiffusionSolver
from vtkillum.core.convection_diffusion.opacity import (
    LightGridOptics,
    light_grid_shape,
    light_grid_spacing,
)
from vtkillum.core.convection_diffusion.radiative import (
    LIMITERS,
    WARM_NESTED_ABOVE,
    RadiativeDiffusion,
)
from vtkillum.core.convection_diffusion.reconstruction import filter_along_surfaces
from vtkillum.core.device import resolve_device
from vtkillum.core.device_arrays import scaled_nonnegative
from vtkillum.core.graphs import LaunchGraphs
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DIRECTIONAL, pack_lights
from vtkillum.core.volume import array_digest
from vtkillum.core.warp_common import MediumTables, device_scalars

#: Diffusion models (see the module docstring).
MODELS = ("physical", "paper")
#: Solvers of the physical model (its operator changes every outer iteration).
PHYSICAL_SOLVERS = ("multigrid", "gauss-seidel")

#: Relative residual at which the diffusion stops by default: the loosest tolerance at
#: which more iterations would change the image by less than a tenth of the method's
#: measured error against ``path``, on a first image and after a transfer-function edit
#: (docs/convection_diffusion_tolerance.md, ``benchmarks/cd_tolerance.py``).
DEFAULT_TOLERANCE = 3e-4

#: Options of the method (scene section ``convection_diffusion``) and their defaults.
OPTIONS = {
    "light_volume_scale": 0.5,
    "diffusion_model": "physical",
    "scattering": [0.0, 0.0, 0.0],
    "iterations": 0,
    "solver": "multigrid",
    "tolerance": DEFAULT_TOLERANCE,
    "source_radius": 0.0,
}

#: Iteration cap of one update when ``iterations`` is 0 ("until the tolerance").
MAX_ITERATIONS = {"multigrid": 100, "cg": 2000, "gauss-seidel": 20000, "dct": 1}

#: Share of an update's progress before the diffusion (opacity, convection, composition).
PROGRESS_BEFORE_DIFFUSION = 0.4


@dataclass
class UpdateStats:
    """What :meth:`ConvectionDiffusionSolver.update` recomputed, and how long it took.

    Attributes
    ----------
    shape : tuple of int
        Light-volume points per axis.
    model : str
        The diffusion model of this update.
    opacity : bool
        The opacity (extinction) volume was recomputed.
    convected : list of int
        Indices of the lights whose transmittance was recomputed.
    composed : bool
        The composition (eq. 22, and the physical model's source) was redone.
    diffused : bool
        Diffusion iterations ran in this update.
    warm_start : bool
        The diffusion started from a previous solution.
    diffusion : DiffusionReport
        Iterations and residual history of this update's diffusion.
    converged : bool
        The light volume is at the tolerance (False: call ``update`` again to refine).
    ms : dict
        Milliseconds per stage (``opacity``, ``convection`` (list, per convected light),
        ``composition``, ``diffusion``), measured after device synchronisation.
    """

    shape: tuple = ()
    model: str = ""
    opacity: bool = False
    convected: list = field(default_factory=list)
    composed: bool = False
    diffused: bool = False
    warm_start: bool = False
    diffusion: DiffusionReport = field(default_factory=DiffusionReport)
    converged: bool = True
    ms: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            "shape": list(self.shape), "model": self.model, "opacity": self.opacity,
            "convected": list(self.convected), "composed": self.composed,
            "diffused": self.diffused, "warm_start": self.warm_start,
            "iterations": self.diffusion.iterations, "residuals": list(self.diffusion.residuals),
            "converged": self.converged, "ms": dict(self.ms),
        }


class ConvectionDiffusionSolver:
    """Light volume of Zhang & Ma 2013 with partial recomputation (Algorithm 1).

    Set the attributes (same names as the constructor's parameters) between calls of
    :meth:`update`; it finds out what changed.

    Parameters
    ----------
    light_volume_scale : float
        Light-volume resolution relative to the data (``round(scale * n)`` points per axis).
    light_volume_shape : (3,) int, optional
        Explicit light-volume shape (overrides the scale).
    diffusion_model : str
        ``"physical"`` (default: diffusion approximation of radiative transfer from the
        optical model) or ``"paper"`` (Zhang & Ma's eq. 23 with ``scattering``).
    scattering : (3,) float
        ``"paper"`` only: ``sigma_hat_s`` per RGB channel in world units²; 0 = no diffusion.
    solver : str
        Diffusion solver, one of
        :data:`~vtkillum.core.convection_diffusion.diffusion.SOLVERS` (``"physical"``:
        ``"multigrid"`` or ``"gauss-seidel"``).
    tolerance : float
        Relative residual at which the diffusion is converged (default
        :data:`DEFAULT_TOLERANCE`, chosen by accuracy).
    iterations : int
        Diffusion iteration budget per update (0: until ``tolerance``, up to
        :data:`MAX_ITERATIONS`). A budget-limited update leaves ``converged`` False and the
        next update continues where it stopped.
    source_radius : float
        Point-light source region in world units; 0 = two light-grid spacings.
    warm_start : bool
        Start each diffusion solve from the previous solution (see the module docstring).
    convection_scheme : str
        ``"characteristics"`` (default: short characteristics), ``"exponential"``
        (exponentially fitted upwind) or ``"upwind"`` (the paper's eqs. 16–20); see
        :mod:`~vtkillum.core.convection_diffusion.convection`.
    flux_limiter : str
        ``"physical"`` only: one of
        :data:`~vtkillum.core.convection_diffusion.radiative.LIMITERS` (default
        ``"levermore-pomraning"``).
    delta_scaling : bool
        ``"physical"`` only: δ-Eddington scaling of the first-scattered source (default on,
        see :func:`delta_fraction`): the fraction ``f = g²`` of each scattering event that
        a Henyey–Greenstein phase sends into its forward peak stays in the light's beam,
        which then has the extinction ``sigma_t - f sigma_s`` and seeds the diffusion with
        ``(1 - f) sigma_s`` and anisotropy ``g / (1 + g)`` (the transport coefficient is
        unchanged). The directly lit single scattering is still rendered with the exact
        transmittance and the full phase function.
    anderson : bool
        ``"physical"`` only: Anderson acceleration of the outer iteration (default on;
        :meth:`~vtkillum.core.convection_diffusion.radiative.RadiativeDiffusion._anderson_iteration`).
    device : str, optional
        Warp device.
    """

    def __init__(self, light_volume_scale: float = 0.5, light_volume_shape=None,
                 diffusion_model: str = "physical", scattering=(0.0, 0.0, 0.0),
                 solver: str = "multigrid", tolerance: float = DEFAULT_TOLERANCE,
                 iterations: int = 0,
                 source_radius: float = 0.0, warm_start: bool = True,
                 convection_scheme: str = "characteristics",
                 flux_limiter: str = "levermore-pomraning", first_moment: bool = True,
                 delta_scaling: bool = True, anderson: bool = True,
                 device: str | None = None):
        self.light_volume_scale = light_volume_scale
        self.light_volume_shape = light_volume_shape
        self.diffusion_model = diffusion_model
        self.scattering = scattering
        self.solver = solver
        self.tolerance = tolerance
        self.iterations = iterations
        self.source_radius = source_radius
        self.warm_start = warm_start
        self.convection_scheme = convection_scheme
        self.flux_limiter = flux_limiter
        self.first_moment = first_moment
        self.delta_scaling = delta_scaling
        self.anderson = anderson
        self.device = resolve_device(device)
        self.reset()

    def reset(self) -> None:
        """Forget every cached result (the next update recomputes everything)."""
        self._grid_key = None
        self._opacity_key = None
        self._opacity_version = 0
        self._color_key = None
        self._color_version = 0
        self._scalars = None  # (volume key, data on the device)
        self._tables = MediumTables(self.device)  # the transfer function's, on the device
        self._optics = LightGridOptics(self.device)  # the opacity stage's launch
        self._sigma = None
        self._color_sigma = None
        self._transmittance = {}  # geometry key -> (opacity version, array)
        self._geometry = []  # geometry keys of the last update's lights, in order
        self._compose_key = None
        self._compose_version = 0
        self._b = None  # composed direct fluence phi_d = L0
        self._q = None  # first-scattered source (physical)
        self._moment = None  # sum_l Q_l u_l per axis (physical, first moment)
        self._b_prev = None  # right-hand side of the last paper diffusion solve
        self._light_scale = 1.0  # light arrays are in units of the brightest light's RGB
        self._q_norm_prev = None  # ||Q|| per channel of the last physical solve
        self._x = None  # diffused light L (paper) or scattered fluence phi_s (physical)
        self._x_model = None  # the model that _x belongs to
        self._x_version = 0  # counts diffusion updates of _x
        self._rendered = None  # (key, phi_s filtered along surfaces)
        self._illumination = None  # (key, IlluminationVolume on the device)
        self._diffusion_key = None
        self._diffusion = None
        self._radiative = None  # (limiter, RadiativeDiffusion)
        self._medium_key = None
        self._converged = True
        self._tolerance_reached = 0.0  # tolerance of the last converged solve
        self._source_radius = 0.0
        self._model = None
        self._graphs = LaunchGraphs(self.device)  # captured convection sweeps
        self._sigma_star = None  # δ-Eddington extinction of the beams (physical)
        self._sigma_star_key = None
        self._T_stack = None  # (slots, *grid): light i's transmittance in slot i
        self._beam_stack = None  # the same through _sigma_star (δ-Eddington beams)
        self._slot_keys = []  # slot -> (geometry key, opacity version) it holds
        self._beam_keys = []  # slot -> (geometry key, sigma_star key) it holds
        self.shape = None
        self.spacing = None

    # --- public ----------------------------------------------------------------------------
    def update(self, volume, transfer_function, unit_distance: float, lights,
               volume_key=None, albedo: float = 0.9, anisotropy: float = 0.0,
               progress=None) -> UpdateStats:
        """Bring the light volume up to date with the inputs, recomputing only what changed.

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
        transfer_function : vtkillum.core.transfer_function.TransferFunction
            Opacity (both models) and colours (the physical model's scattering colour).
        unit_distance : float
            Opacity unit distance (world units).
        lights : sequence of DirectionalLight or PointLight
            World-space lights.
        volume_key : hashable, optional
            Identifies the data (e.g. a pipeline modification time and time step). When
            omitted the scalars are hashed.
        albedo, anisotropy : float
            Single-scattering albedo ``Λ`` and Henyey–Greenstein ``g`` of the scene (the
            physical model's ``sigma_s``, ``sigma_a`` and ``D``).
        progress : callable, optional
            ``progress(fraction)``: after the opacity volume, after the convection (all
            lights in one batch), after the composition and after every diffusion
            iteration.

        Returns
        -------
        UpdateStats
        """
        opts = self._validated(albedo, anisotropy)
        report = progress if progress is not None else (lambda fraction: None)
        stats = UpdateStats(model=self.diffusion_model)
        lights = list(lights)
        if not lights:
            raise ValueError("convection-diffusion needs at least one light")
        shape = light_grid_shape(volume, opts["scale"], self.light_volume_shape)
        spacing = light_grid_spacing(volume.extent, shape)
        grid_key = (volume.dims, tuple(np.round(volume.extent, 9)), shape)
        if grid_key != self._grid_key:
            self.reset()
            self._grid_key = grid_key
            self.shape, self.spacing = shape, spacing
            self._b = wp.zeros(shape, dtype=wp.vec3, device=self.device)
        stats.shape = shape
        r_s = opts["source_radius"] if opts["source_radius"] > 0 else 2.0 * float(spacing.max())
        self._source_radius = r_s

        # 1. opacity volume (and the physical model's scattering colour)
        if volume_key is None:
            volume_key = array_digest(volume.scalars)
        tf_key = (transfer_function.scalars.tobytes(), transfer_function.opacity.tobytes())
        opacity_key = (volume_key, tf_key, float(unit_distance))
        color_key = (opacity_key, transfer_function.colors.tobytes())
        if color_key != self._color_key:
            t = time.perf_counter()
            if self._scalars is None or self._scalars[0] != volume_key:
                self._scalars = (volume_key, device_scalars(volume, self.device))
            # Only the tables are rewritten: a transfer-function edit does not upload the
            # data. No block occupancy: the footprint means below sample every data point.
            medium = self._tables.medium(volume, transfer_function, unit_distance,
                                         self._scalars[1])
            self._sigma, self._color_sigma = self._optics(volume, medium, shape)
            self._color_key = color_key
            self._color_version += 1
            if opacity_key != self._opacity_key:
                self._opacity_key = opacity_key
                self._opacity_version += 1
                stats.opacity = True
            stats.ms["opacity"] = _elapsed_ms(t, self.device)
        report(0.05)

        # 2. convection, per light geometry (with the δ-Eddington beam in the same sweep)
        physical = self.diffusion_model == "physical"
        f = delta_fraction(opts["anisotropy"]) if physical and self.delta_scaling else 0.0
        if f > 0:
            self._update_sigma_star(f, opts["albedo"])
        kinds, vecs, rgbs = pack_lights(lights, volume.direction, volume.origin)
        geometry = [(int(kinds[i]), tuple(vecs[i].tolist()), r_s, self.convection_scheme)
                    for i in range(len(lights))]
        stats.ms["convection"] = []
        self._ensure_slots(len(geometry))
        jobs = [i for i, key in enumerate(geometry)
                if self._slot_keys[i] != (key, self._opacity_version)]
        if jobs:  # all lights that changed in the same launches (one per wavefront)
            t = time.perf_counter()
            second = None
            if f > 0:
                second = (self._sigma_star, self._beam_stack)
            convect_lights(self._sigma, spacing, [(geometry[i][0], vecs[i]) for i in jobs],
                           self._T_stack, jobs, r_s, self.convection_scheme, self._graphs,
                           second)
            for i in jobs:
                self._slot_keys[i] = (geometry[i], self._opacity_version)
                if f > 0:
                    self._beam_keys[i] = (geometry[i], self._sigma_star_key)
            stats.convected.extend(jobs)
            share = _elapsed_ms(t, self.device) / len(jobs)
            stats.ms["convection"].extend([share] * len(jobs))
        report(0.35)
        self._transmittance = {key: (self._opacity_version, self._T_stack[i])
                               for i, key in enumerate(geometry)}
        self._geometry = geometry

        # 3. composition
        light_key = tuple((g, tuple(rgbs[i].tolist())) for i, g in enumerate(geometry))
        compose_key = (self._opacity_version, light_key, self.diffusion_model) + (
            (self._color_version, opts["albedo"], bool(self.first_moment), f,
             opts["anisotropy"] if self.first_moment or f > 0 else None) if physical else ())
        if compose_key != self._compose_key:
            t = time.perf_counter()
            # Light is linear in the lights' RGB (the flux limiter is scale-invariant too):
            # solve in units of the brightest light so that squares in residual norms stay
            # finite in float32 for any accepted light (up to 1e30); outputs scale back.
            scale = float(max(np.max(rgbs), 1e-30))
            if scale != self._light_scale:
                ratio = self._light_scale / scale
                for stale in (self._x, self._b_prev):
                    if stale is not None:
                        wp.launch(scale_kernel, dim=stale.shape, device=self.device,
                                  inputs=[stale, wp.vec3(ratio, ratio, ratio)])
                if self._q_norm_prev is not None:
                    self._q_norm_prev = self._q_norm_prev * ratio
                self._light_scale = scale
            rgbs = (rgbs / scale).astype(np.float32)
            directions = [v / max(float(np.linalg.norm(v)), 1e-30) if k == DIRECTIONAL else v
                          for k, v in zip(kinds, vecs.astype(np.float64))]
            compose_direct(self._T_stack, kinds, directions, rgbs, spacing, r_s, self._b)
            if physical:
                if self._q is None:
                    self._q = wp.zeros(shape, dtype=wp.vec3, device=self.device)
                if self.first_moment and self._moment is None:
                    self._moment = tuple(wp.zeros(shape, dtype=wp.vec3, device=self.device)
                                         for _ in range(3))
                sources, sigma = self._T_stack, self._sigma
                albedo, g = opts["albedo"], opts["anisotropy"]
                if f > 0:  # δ-Eddington: the forward peak stays in the beam
                    sigma, sources = self._delta_beams(geometry, vecs, spacing, r_s)
                    albedo, g = albedo * (1.0 - f), g / (1.0 + g)
                first_scattered_source(sources, kinds, directions, rgbs, spacing, r_s, sigma,
                                       self._color_sigma, albedo, self._q,
                                       self._moment if self.first_moment else None, g)
            self._compose_key = compose_key
            self._compose_version += 1
            stats.composed = True
            stats.ms["composition"] = _elapsed_ms(t, self.device)
        report(PROGRESS_BEFORE_DIFFUSION)

        # 4. diffusion
        if physical:
            self._diffuse_physical(opts, stats, report)
        else:
            self._diffuse_paper(opts, stats, report)
        self._model = self.diffusion_model
        stats.converged = self._converged
        report(1.0)
        return stats

    @property
    def model(self) -> str:
        """The diffusion model of the last update."""
        self._check_updated()
        return self._model

    @property
    def scattered_fluence(self) -> np.ndarray:
        """The isotropic light handed to the ray caster, ``(nx, ny, nz, 3)`` float32, >= 0.

        ``"physical"``: the scattered fluence ``phi_s``; ``"paper"``: the diffused light
        volume ``L`` (direct light included). Iterates of an unfinished diffusion can
        dip a little below zero next to sharp shadows; those values are clamped to 0.
        """
        self._check_updated()
        return np.maximum(self._x.numpy(), 0.0) * np.float32(self._light_scale)

    @property
    def fluence(self) -> np.ndarray:
        """All light as an isotropic fluence ``(nx, ny, nz, 3)``: ``L`` (paper) or
        ``phi_d + phi_s`` (physical), point-light irradiance taken at the grid points."""
        if self.model == "paper":
            return self.scattered_fluence
        return self.composed + self.scattered_fluence

    @property
    def composed(self) -> np.ndarray:
        """The direct fluence ``phi_d = sum_l T_l E_l`` (eq. 22, ``L0``), ``(nx, ny, nz, 3)``."""
        self._check_updated()
        return self._b.numpy() * np.float32(self._light_scale)

    @property
    def source(self) -> np.ndarray:
        """The physical model's first-scattered source ``Q``, ``(nx, ny, nz, 3)``."""
        if self.model != "physical":
            raise RuntimeError("the first-scattered source exists only for the physical model")
        return self._q.numpy() * np.float32(self._light_scale)

    def transmittance(self, index: int, lights=None, volume=None) -> np.ndarray:
        """Transmittance ``T`` of light ``index`` (in the order of the last update's lights).

        ``lights`` and ``volume`` are accepted for compatibility and, when given, must be
        the last update's.
        """
        self._check_updated()
        if lights is not None and volume is not None:
            kinds, vecs, _ = pack_lights(lights, volume.direction, volume.origin)
            key = (int(kinds[index]), tuple(vecs[index].tolist()), self._source_radius,
                   self.convection_scheme)
            if key not in self._transmittance:
                raise KeyError(f"light {index} was not part of the last update")
        else:
            key = self._geometry[index]
        return self._transmittance[key][1].numpy()

    def transmittances(self) -> np.ndarray:
        """``T_l`` of every light of the last update, ``(n_lights, nx, ny, nz)`` float32."""
        self._check_updated()
        return np.stack([self._transmittance[key][1].numpy() for key in self._geometry])

    @property
    def sigma(self) -> np.ndarray:
        """The extinction on the light grid (1/world units) from the last update."""
        if self._sigma is None:
            raise RuntimeError("call update() first")
        return self._sigma.numpy()

    @property
    def converged(self) -> bool:
        return self._converged

    def energy_balance(self) -> dict:
        """Physical model: emitted, absorbed and escaped power of the scattered light per
        channel (see :meth:`RadiativeDiffusion.energy_balance`)."""
        if self.model != "physical":
            raise RuntimeError("the energy balance is defined for the physical model")
        balance = self._radiative[1].energy_balance(self._q, self._x)
        return {name: value * self._light_scale for name, value in balance.items()}

    def illumination_volume(self, volume) -> IlluminationVolume:
        """The light volume as an :class:`IlluminationVolume` covering ``volume``'s box.

        ``"physical"``: per-light transmittance (direct light, phase function applied by
        the ray caster) and the scattered fluence ``phi_s``. ``"paper"``: the diffused
        ``L`` as one isotropic fluence, as the paper shades it (eq. 24).
        """
        # Made on the device (scaled, clamped and checked there) once per update of the
        # light volume and kept: renders with a moved camera move no volume-sized data.
        self._check_updated()
        key = (self._model, self._diffusion_key, self._opacity_version, self._x_version,
               self._compose_version, tuple(self._geometry), self._light_scale,
               tuple(np.round(volume.extent, 9)))
        if self._illumination is not None and self._illumination[0] == key:
            return self._illumination[1]
        source = self._x if self.model == "paper" else self._rendered_device()
        scattered = scaled_nonnegative(source, self._light_scale)
        transmittance = None
        if self.model != "paper":
            transmittance = wp.clone(self._T_stack[0:len(self._geometry)])
        illumination = IlluminationVolume.for_volume(volume, scattered, transmittance)
        self._illumination = (key, illumination)
        return illumination

    def _rendered_device(self):
        """Physical model: the device array of ``phi_s`` filtered along thick surfaces."""
        key = (self._diffusion_key, self._opacity_version, self._x_version)
        if self._rendered is None or self._rendered[0] != key:
            out = self._rendered[1] if self._rendered is not None else None
            self._rendered = (key, filter_along_surfaces(self._x, self._sigma, self.spacing, out))
        return self._rendered[1]

    @property
    def rendered_scattered_fluence(self) -> np.ndarray:
        """Physical model: ``phi_s`` filtered along thick surfaces for the ray caster
        (:mod:`~vtkillum.core.convection_diffusion.reconstruction`), ``(nx, ny, nz, 3)``, >= 0."""
        self._check_updated()
        if self.model != "physical":
            return self.scattered_fluence
        return np.maximum(self._rendered_device().numpy(), 0.0) * np.float32(self._light_scale)

    # --- internals -------------------------------------------------------------------------
    def _update_sigma_star(self, f: float, albedo: float) -> None:
        """δ-Eddington extinction of the beams, ``sigma_t* = sigma_t - f albedo <color
        sigma_t>`` (grey: the channels' mean), when the medium, albedo or ``f`` changed."""
        key = (self._color_version, float(albedo), float(f))
        if self._sigma_star is None or tuple(self._sigma_star.shape) != tuple(self.shape):
            self._sigma_star = wp.empty(self.shape, dtype=wp.float32, device=self.device)
            self._sigma_star_key = None
        if key != self._sigma_star_key:
            wp.launch(delta_sigma_kernel, dim=self.shape, device=self.device,
                      inputs=[self._sigma, self._color_sigma, float(f * albedo),
                              self._sigma_star])
            self._sigma_star_key = key

    def _ensure_slots(self, count: int) -> None:
        """Stacks of per-light transmittance (and δ-Eddington beams) for ``count`` lights;
        light ``i`` lives in slot ``i``. Growing them invalidates every slot."""
        capacity = 0 if self._T_stack is None else self._T_stack.shape[0]
        if count <= capacity and tuple(self._T_stack.shape[1:]) == tuple(self.shape):
            return
        capacity = max(count, 2 * capacity, 1)
        size = (capacity,) + tuple(self.shape)
        self._T_stack = wp.empty(size, dtype=wp.float32, device=self.device)
        self._beam_stack = wp.empty(size, dtype=wp.float32, device=self.device)
        self._slot_keys = [None] * capacity
        self._beam_keys = [None] * capacity

    def _delta_beams(self, geometry, vecs, spacing, r_s):
        """``sigma_t*`` and the lights' transmittances through it (the beam stack, light ``l``
        in slot ``l``): from the paired sweep of the convection step, or swept now (all stale
        lights in the same launches) where only the albedo, colour or ``g`` changed."""
        stale = [i for i, key in enumerate(geometry)
                 if self._beam_keys[i] != (key, self._sigma_star_key)]
        if stale:
            convect_lights(self._sigma_star, spacing, [(geometry[i][0], vecs[i]) for i in stale],
                           self._beam_stack, stale, r_s, self.convection_scheme, self._graphs)
            for i in stale:
                self._beam_keys[i] = (geometry[i], self._sigma_star_key)
        return self._sigma_star, self._beam_stack

    def _check_updated(self) -> None:
        if self._x is None:
            raise RuntimeError("call update() before reading the light volume")

    def _validated(self, albedo, anisotropy) -> dict:
        if self.diffusion_model not in MODELS:
            raise ValueError(f"diffusion_model must be one of {MODELS}, got "
                             f"{self.diffusion_model!r}")
        s = np.asarray(self.scattering, dtype=np.float64).reshape(-1)
        if s.size == 1:
            s = np.repeat(s, 3)
        if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s < 0):
            raise ValueError(
                "scattering (sigma_hat_s) must be one or three non-negative numbers in world "
                f"units², got {self.scattering!r}"
            )
        if self.convection_scheme not in SCHEMES:
            raise ValueError(f"convection_scheme must be one of {sorted(SCHEMES)}, got "
                             f"{self.convection_scheme!r}")
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.diffusion_model == "physical" and self.solver not in PHYSICAL_SOLVERS:
            raise ValueError(f"solver {self.solver!r} serves the paper model only; the physical "
                             f"diffusion model is solved with one of {PHYSICAL_SOLVERS}")
        if self.flux_limiter not in LIMITERS:
            raise ValueError(f"flux_limiter must be one of {sorted(LIMITERS)}, got "
                             f"{self.flux_limiter!r}")
        tol = self.tolerance
        if not (isinstance(tol, (int, float, np.floating)) and np.isfinite(tol) and 0 < tol < 1):
            raise ValueError(f"tolerance must lie in (0, 1), got {tol!r}")
        it = self.iterations
        if not (isinstance(it, (int, np.integer)) and not isinstance(it, bool) and it >= 0):
            raise ValueError(f"iterations must be a non-negative integer (0: converge), got {it!r}")
        r_s = self.source_radius
        if not (isinstance(r_s, (int, float, np.floating)) and np.isfinite(r_s) and r_s >= 0):
            raise ValueError(f"source_radius must be a non-negative number of world units, got {r_s!r}")
        if not (np.isfinite(albedo) and 0.0 <= albedo <= 1.0):
            raise ValueError(f"albedo must lie in [0, 1], got {albedo!r}")
        if not (np.isfinite(anisotropy) and -1.0 < anisotropy < 1.0):
            raise ValueError(f"anisotropy must lie in (-1, 1), got {anisotropy!r}")
        return {"scattering": s, "scale": self.light_volume_scale, "tolerance": float(tol),
                "iterations": int(it), "source_radius": float(r_s), "albedo": float(albedo),
                "anisotropy": float(anisotropy)}

    def _progress_callback(self, report, tolerance: float, budget: int):
        """Map diffusion iterations to [PROGRESS_BEFORE_DIFFUSION, 1]: the share of the
        residual's way (log scale) from its start to ``tolerance``, or of the budget."""
        start = [None]

        def callback(iteration: int, residual: float) -> None:
            if start[0] is None:
                start[0] = max(residual, tolerance * 10.0)
            way = np.log(start[0] / tolerance)
            done = np.log(start[0] / max(residual, tolerance)) / way if way > 0 else 1.0
            frac = max(min(done, 1.0), min(iteration / max(budget, 1), 1.0))
            report(PROGRESS_BEFORE_DIFFUSION + (1.0 - PROGRESS_BEFORE_DIFFUSION) * frac)

        return callback

    def _start_from(self, model: str) -> bool:
        """Whether ``_x`` is a usable warm start for ``model`` (same model, same grid)."""
        return self.warm_start and self._x is not None and self._x_model == model

    def _diffuse_paper(self, opts: dict, stats: UpdateStats, report) -> None:
        s = opts["scattering"]
        key = ("paper", self._compose_version, tuple(s.tolist()), self.solver)
        new_problem = key != self._diffusion_key
        if not new_problem and self._converged and opts["tolerance"] >= self._tolerance_reached:
            return
        t = time.perf_counter()
        if not np.any(s > 0):
            self._x = wp.clone(self._b) if self._x is None else self._x
            wp.copy(self._x, self._b)
            self._x_model = "paper"
            self._b_prev = None  # no diffusion solution to warm-start from
            self._diffusion_key, self._converged = key, True
            self._tolerance_reached = 0.0
            stats.diffused = True
            stats.diffusion = DiffusionReport(0, [0.0], True)
            stats.ms["diffusion"] = _elapsed_ms(t, self.device)
            return
        solver_key = (tuple(s.tolist()), self.solver)
        if self._diffusion is None or self._diffusion[0] != solver_key:
            self._diffusion = (solver_key, DiffusionSolver(self.shape, self.spacing, s,
                                                           self.solver, self.device))
        if new_problem:
            if self._start_from("paper") and self._b_prev is not None:
                # x0 = x_prev + (b - b_prev): exact for changes that are smooth on the
                # diffusion length, and never worse than a cold start for the rest.
                wp.launch(warm_start_kernel, dim=self.shape, device=self.device,
                          inputs=[self._x, self._b, self._b_prev])
                stats.warm_start = True
            else:
                self._x = wp.clone(self._b)
            self._x_model = "paper"
            if self._b_prev is None:
                self._b_prev = wp.clone(self._b)
            else:
                wp.copy(self._b_prev, self._b)
        budget = opts["iterations"] or MAX_ITERATIONS[self.solver]
        result = self._diffusion[1].solve(
            self._b, self._x, budget, opts["tolerance"],
            callback=self._progress_callback(report, opts["tolerance"], budget))
        self._diffusion_key = key
        self._converged = result.converged
        self._tolerance_reached = opts["tolerance"]
        stats.diffused = True
        stats.diffusion = result
        stats.ms["diffusion"] = _elapsed_ms(t, self.device)

    def _diffuse_physical(self, opts: dict, stats: UpdateStats, report) -> None:
        key = ("physical", self._compose_version, self._color_version, opts["albedo"],
               opts["anisotropy"], self.flux_limiter, self.solver, bool(self.first_moment),
               bool(self.anderson))
        new_problem = key != self._diffusion_key
        if not new_problem and self._converged and opts["tolerance"] >= self._tolerance_reached:
            return
        t = time.perf_counter()
        if self._radiative is None or self._radiative[0] != self.flux_limiter:
            self._radiative = (self.flux_limiter, RadiativeDiffusion(
                self.shape, self.spacing, self.flux_limiter, self.device))
            self._medium_key = None
        rd = self._radiative[1]
        rd.anderson = bool(self.anderson)
        medium_key = (self._opacity_version, self._color_version, opts["albedo"],
                      opts["anisotropy"])
        if medium_key != self._medium_key:
            rd.set_medium(self._sigma, self._color_sigma, opts["albedo"], opts["anisotropy"])
            self._medium_key = medium_key
        q_norm = rd._norm(self._q)
        if new_problem:
            if self._start_from("physical") and self._q_norm_prev is not None:
                prev = self._q_norm_prev
                ratio = np.where(prev > 0, q_norm / np.maximum(prev, 1e-300), 0.0)
                wp.launch(scale_kernel, dim=self.shape, device=self.device,
                          inputs=[self._x, wp.vec3(*ratio.astype(np.float32))])
                stats.warm_start = True
            else:
                if self._x is None:
                    self._x = wp.zeros(self.shape, dtype=wp.vec3, device=self.device)
                self._x.zero_()
            self._x_model = "physical"
            self._q_norm_prev = q_norm
        budget = opts["iterations"] or MAX_ITERATIONS[self.solver]
        result = rd.solve(self._q, self._x, budget, opts["tolerance"], method=self.solver,
                          callback=self._progress_callback(report, opts["tolerance"], budget),
                          displacement=self._moment if self.first_moment else None,
                          cold=not stats.warm_start and new_problem,
                          nested_above=WARM_NESTED_ABOVE if stats.warm_start else None)
        self._diffusion_key = key
        self._converged = result.converged or result.stalled  # more iterations gain nothing
        self._tolerance_reached = opts["tolerance"]
        self._x_version += 1
        stats.diffused = True
        stats.diffusion = result
        stats.ms["diffusion"] = _elapsed_ms(t, self.device)


def delta_fraction(g: float) -> float:
    """Forward-peak fraction ``f = g²`` of δ-Eddington scaling (Joseph, Wiscombe &
    Weinman 1976) for ``g > 0``; 0 for isotropic and backward scattering."""
    return float(g) ** 2 if g > 0 else 0.0


def _elapsed_ms(t0: float, device: str) -> float:
    wp.synchronize_device(device)
    return 1000.0 * (time.perf_counter() - t0)


# --- kernels -------------------------------------------------------------------------------------
@wp.kernel
def warm_start_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                      b_prev: wp.array3d(dtype=wp.vec3)):
    """``x += b - b_prev`` at light-grid point ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    x[i, j, k] = x[i, j, k] + b[i, j, k] - b_prev[i, j, k]


@wp.kernel
def scale_kernel(x: wp.array3d(dtype=wp.vec3), ratio: wp.vec3):
    """``x *= ratio`` per channel at light-grid point ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    x[i, j, k] = wp.cw_mul(x[i, j, k], ratio)


@wp.kernel
def delta_sigma_kernel(sigma: wp.array3d(dtype=wp.float32), color_sigma: wp.array3d(dtype=wp.vec3),
                       f_albedo: float, out: wp.array3d(dtype=wp.float32)):
    """``out = sigma_t - f albedo <color sigma_t>`` at point ``wp.tid()`` (>= 0)."""
    i, j, k = wp.tid()
    cs = color_sigma[i, j, k]
    out[i, j, k] = wp.max(sigma[i, j, k] - f_albedo * (cs[0] + cs[1] + cs[2]) / 3.0, 0.0)
