"""Convection–diffusion light volumes (Zhang & Ma, "Fast Global Illumination for
Interactive Volume Visualization", I3D 2013): the ``"convection-diffusion"`` method.

Pipeline (the paper's Fig. 2 and Algorithm 1)
---------------------------------------------
1. **Opacity volume** — extinction ``sigma_t`` on the light grid (default half the
   data's resolution), footprint-averaged (:mod:`~vtkillum.core.convection_diffusion.opacity`).
2. **Convection per light** — steady transmittance ``T_l`` (short characteristics
   by default, or the paper's upwind scheme), exact in one wavefront-ordered sweep
   instead of the paper's 4–5 iterations per layer (:mod:`~vtkillum.core.convection_diffusion.convection`).
3. **Composition** (eq. 22) — ``L0(x) = sum_l T_l(x) E_l(x)`` with ``E_l`` the light's
   RGB irradiance (``I / max(d, r_s)**2`` for point lights): the single-scattering
   fluence of the project's convention (:mod:`vtkillum.core.illumination`).
4. **Diffusion** (eq. 23) — ``(I - sigma_hat_s laplace) L = L0`` per channel, pure
   Neumann, multigrid by default (:mod:`~vtkillum.core.convection_diffusion.diffusion`).
5. **Rendering** (eq. 24) — :func:`vtkillum.core.raycast.render_illuminated` shades
   with ``L`` and the scene's Phong terms.

:class:`ConvectionDiffusionSolver` keeps every intermediate result and recomputes
only what an edit invalidates, a finer version of Algorithm 1:

==============================  ==================================================
change                          recomputed
==============================  ==================================================
data or opacity transfer fn.    opacity, every light, composition, diffusion
one light moved / turned        that light, composition, diffusion
a light's colour or intensity   composition, diffusion (no convection)
``scattering`` / solver         diffusion only
nothing (budget left over)      more diffusion iterations (progressive refinement)
==============================  ==================================================

Each diffusion solve starts from the previous solution shifted by the change of
the right-hand side, ``x0 = x_prev + (L0 - L0_prev)`` (exact where the change is
smooth on the diffusion length): time steps and edits converge in fewer
iterations than a cold start from ``L0`` (``UpdateStats.diffusion``). The
convection needs no warm start, it is exact in one sweep.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion.convection import POINT_KIND, SCHEMES, convect_light
from vtkillum.core.convection_diffusion.diffusion import SOLVERS, DiffusionReport, DiffusionSolver
from vtkillum.core.convection_diffusion.opacity import (
    light_grid_shape,
    light_grid_sigma,
    light_grid_spacing,
)
from vtkillum.core.device import resolve_device
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import pack_lights
from vtkillum.core.volume import array_digest
from vtkillum.core.warp_common import grid_point, make_medium

#: Options of the method (scene section ``convection_diffusion``) and their defaults.
OPTIONS = {
    "light_volume_scale": 0.5,
    "scattering": [0.0, 0.0, 0.0],
    "iterations": 0,
    "solver": "multigrid",
    "tolerance": 1e-4,
    "source_radius": 0.0,
}

#: Iteration cap of one update when ``iterations`` is 0 ("until the tolerance").
MAX_ITERATIONS = {"multigrid": 100, "cg": 2000, "gauss-seidel": 20000, "dct": 1}


@dataclass
class UpdateStats:
    """What :meth:`ConvectionDiffusionSolver.update` recomputed, and how long it took.

    Attributes
    ----------
    shape : tuple of int
        Light-volume points per axis.
    opacity : bool
        The opacity (extinction) volume was recomputed.
    convected : list of int
        Indices of the lights whose transmittance was recomputed.
    composed : bool
        The composition (eq. 22) was redone.
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
            "shape": list(self.shape), "opacity": self.opacity, "convected": list(self.convected),
            "composed": self.composed, "diffused": self.diffused, "warm_start": self.warm_start,
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
    scattering : (3,) float
        ``sigma_hat_s`` per RGB channel in world units²; 0 = no diffusion.
    solver : str
        Diffusion solver, one of :data:`~vtkillum.core.convection_diffusion.diffusion.SOLVERS`.
    tolerance : float
        Relative residual at which the diffusion is converged.
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
    device : str, optional
        Warp device.
    """

    def __init__(self, light_volume_scale: float = 0.5, light_volume_shape=None,
                 scattering=(0.0, 0.0, 0.0), solver: str = "multigrid", tolerance: float = 1e-4,
                 iterations: int = 0, source_radius: float = 0.0, warm_start: bool = True,
                 convection_scheme: str = "characteristics", device: str | None = None):
        self.light_volume_scale = light_volume_scale
        self.light_volume_shape = light_volume_shape
        self.scattering = scattering
        self.solver = solver
        self.tolerance = tolerance
        self.iterations = iterations
        self.source_radius = source_radius
        self.warm_start = warm_start
        self.convection_scheme = convection_scheme
        self.device = resolve_device(device)
        self.reset()

    def reset(self) -> None:
        """Forget every cached result (the next update recomputes everything)."""
        self._grid_key = None
        self._opacity_key = None
        self._opacity_version = 0
        self._scalars = None  # (volume key, data on the device)
        self._sigma = None
        self._transmittance = {}  # geometry key -> (opacity version, array)
        self._compose_key = None
        self._compose_version = 0
        self._b = None  # composed light L0
        self._b_prev = None  # L0 of the last diffusion solve
        self._x = None  # diffused light L
        self._diffusion_key = None
        self._diffusion = None
        self._converged = True
        self._source_radius = 0.0
        self.shape = None
        self.spacing = None

    # --- public ----------------------------------------------------------------------------
    def update(self, volume, transfer_function, unit_distance: float, lights,
               volume_key=None) -> UpdateStats:
        """Bring the light volume up to date with the inputs, recomputing only what changed.

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
        transfer_function : vtkillum.core.transfer_function.TransferFunction
        unit_distance : float
            Opacity unit distance (world units).
        lights : sequence of DirectionalLight or PointLight
            World-space lights.
        volume_key : hashable, optional
            Identifies the data (e.g. a pipeline modification time and time step). When
            omitted the scalars are hashed.

        Returns
        -------
        UpdateStats
        """
        opts = self._validated()
        stats = UpdateStats()
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

        # 1. opacity volume
        if volume_key is None:
            volume_key = array_digest(volume.scalars)
        tf_key = (transfer_function.scalars.tobytes(), transfer_function.opacity.tobytes())
        opacity_key = (volume_key, tf_key, float(unit_distance))
        if opacity_key != self._opacity_key:
            t = time.perf_counter()
            if self._scalars is None or self._scalars[0] != volume_key:
                self._scalars = (volume_key, None)  # upload once per data set
            # Only the tables are rebuilt: an opacity edit does not upload the data again.
            medium = make_medium(volume, transfer_function, unit_distance, device=self.device,
                                 scalars=self._scalars[1])
            self._scalars = (volume_key, medium.scalars)
            self._sigma = light_grid_sigma(volume, transfer_function, unit_distance, shape,
                                           self.device, medium=medium)
            self._opacity_key = opacity_key
            self._opacity_version += 1
            stats.opacity = True
            stats.ms["opacity"] = _elapsed_ms(t, self.device)

        # 2. convection, per light geometry
        kinds, vecs, rgbs = pack_lights(lights, volume.direction, volume.origin)
        geometry = [(int(kinds[i]), tuple(vecs[i].tolist()), r_s, self.convection_scheme)
                    for i in range(len(lights))]
        fresh = {}
        stats.ms["convection"] = []
        for i, key in enumerate(geometry):
            cached = fresh.get(key) or self._transmittance.get(key)
            if cached is not None and cached[0] == self._opacity_version:
                fresh[key] = cached
                continue
            t = time.perf_counter()
            out = cached[1] if cached is not None else None
            T = convect_light(self._sigma, spacing, key[0], vecs[i], r_s, out=out,
                              scheme=self.convection_scheme)
            fresh[key] = (self._opacity_version, T)
            stats.convected.append(i)
            stats.ms["convection"].append(_elapsed_ms(t, self.device))
        self._transmittance = fresh

        # 3. composition
        compose_key = (self._opacity_version, tuple(
            (g, tuple(rgbs[i].tolist())) for i, g in enumerate(geometry)))
        if compose_key != self._compose_key:
            t = time.perf_counter()
            self._b.zero_()
            h = wp.vec3(*spacing.astype(np.float32))
            for i, key in enumerate(geometry):
                wp.launch(compose_kernel, dim=shape, device=self.device,
                          inputs=[fresh[key][1], self._b, int(kinds[i]), wp.vec3(*vecs[i]),
                                  wp.vec3(*rgbs[i]), h, float(r_s)])
            self._compose_key = compose_key
            self._compose_version += 1
            stats.composed = True
            stats.ms["composition"] = _elapsed_ms(t, self.device)

        # 4. diffusion
        self._diffuse(opts, stats)
        stats.converged = self._converged
        return stats

    @property
    def fluence(self) -> np.ndarray:
        """The light volume ``L`` (RGB fluence), ``(nx, ny, nz, 3)`` float32, non-negative.

        Iterates of an unfinished diffusion can dip a little below zero next to sharp
        shadows; those values are clamped to 0.
        """
        if self._x is None:
            raise RuntimeError("call update() before reading the light volume")
        return np.maximum(self._x.numpy(), 0.0)

    @property
    def composed(self) -> np.ndarray:
        """The composed light ``L0`` before diffusion (eq. 22), ``(nx, ny, nz, 3)``."""
        if self._x is None:
            raise RuntimeError("call update() before reading the light volume")
        return self._b.numpy()

    def transmittance(self, index: int, lights, volume) -> np.ndarray:
        """Transmittance ``T`` of light ``index`` of ``lights`` from the last update."""
        kinds, vecs, _ = pack_lights(lights, volume.direction, volume.origin)
        key = (int(kinds[index]), tuple(vecs[index].tolist()), self._source_radius,
               self.convection_scheme)
        if key not in self._transmittance:
            raise KeyError(f"light {index} was not part of the last update")
        return self._transmittance[key][1].numpy()

    @property
    def sigma(self) -> np.ndarray:
        """The extinction on the light grid (1/world units) from the last update."""
        if self._sigma is None:
            raise RuntimeError("call update() first")
        return self._sigma.numpy()

    @property
    def converged(self) -> bool:
        return self._converged

    def illumination_volume(self, volume) -> IlluminationVolume:
        """The light volume as an :class:`IlluminationVolume` covering ``volume``'s box."""
        return IlluminationVolume.for_volume(volume, self.fluence)

    # --- internals -------------------------------------------------------------------------
    def _validated(self) -> dict:
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
        tol = self.tolerance
        if not (isinstance(tol, (int, float, np.floating)) and np.isfinite(tol) and 0 < tol < 1):
            raise ValueError(f"tolerance must lie in (0, 1), got {tol!r}")
        it = self.iterations
        if not (isinstance(it, (int, np.integer)) and not isinstance(it, bool) and it >= 0):
            raise ValueError(f"iterations must be a non-negative integer (0: converge), got {it!r}")
        r_s = self.source_radius
        if not (isinstance(r_s, (int, float, np.floating)) and np.isfinite(r_s) and r_s >= 0):
            raise ValueError(f"source_radius must be a non-negative number of world units, got {r_s!r}")
        return {"scattering": s, "scale": self.light_volume_scale, "tolerance": float(tol),
                "iterations": int(it), "source_radius": float(r_s)}

    def _diffuse(self, opts: dict, stats: UpdateStats) -> None:
        s = opts["scattering"]
        key = (self._compose_version, tuple(s.tolist()), self.solver)
        new_problem = key != self._diffusion_key
        if not new_problem and self._converged:
            return
        t = time.perf_counter()
        if not np.any(s > 0):
            self._x = wp.clone(self._b) if self._x is None else self._x
            wp.copy(self._x, self._b)
            self._b_prev = None  # no diffusion solution to warm-start from
            self._diffusion_key, self._converged = key, True
            stats.diffused = True
            stats.diffusion = DiffusionReport(0, [0.0], True)
            stats.ms["diffusion"] = _elapsed_ms(t, self.device)
            return
        solver_key = (tuple(s.tolist()), self.solver)
        if self._diffusion is None or self._diffusion[0] != solver_key:
            self._diffusion = (solver_key, DiffusionSolver(self.shape, self.spacing, s,
                                                           self.solver, self.device))
        if new_problem:
            if self.warm_start and self._x is not None and self._b_prev is not None:
                # x0 = x_prev + (b - b_prev): exact for changes that are smooth on the
                # diffusion length, and never worse than a cold start for the rest.
                wp.launch(warm_start_kernel, dim=self.shape, device=self.device,
                          inputs=[self._x, self._b, self._b_prev])
                stats.warm_start = True
            else:
                self._x = wp.clone(self._b)
            if self._b_prev is None:
                self._b_prev = wp.clone(self._b)
            else:
                wp.copy(self._b_prev, self._b)
        budget = opts["iterations"] or MAX_ITERATIONS[self.solver]
        report = self._diffusion[1].solve(self._b, self._x, budget, opts["tolerance"])
        self._diffusion_key = key
        self._converged = report.converged
        stats.diffused = True
        stats.diffusion = report
        stats.ms["diffusion"] = _elapsed_ms(t, self.device)


def _elapsed_ms(t0: float, device: str) -> float:
    wp.synchronize_device(device)
    return 1000.0 * (time.perf_counter() - t0)


# --- kernels -------------------------------------------------------------------------------------
@wp.kernel
def compose_kernel(T: wp.array3d(dtype=wp.float32), out: wp.array3d(dtype=wp.vec3), kind: int,
                   vec: wp.vec3, rgb: wp.vec3, h: wp.vec3, source_radius: float):
    """Eq. 22 for one light at light-grid point ``wp.tid() = (i, j, k)``: ``out += T E``.

    ``E = rgb`` (irradiance) for a directional light, ``rgb / max(d, source_radius)**2``
    (intensity over squared distance, world units) for a point light at ``vec``.
    """
    i, j, k = wp.tid()
    e = rgb
    if kind == POINT_KIND:
        x = grid_point(i, j, k, h)
        d = wp.max(wp.length(x - vec), source_radius)
        e = rgb / (d * d)
    out[i, j, k] = out[i, j, k] + T[i, j, k] * e


@wp.kernel
def warm_start_kernel(x: wp.array3d(dtype=wp.vec3), b: wp.array3d(dtype=wp.vec3),
                      b_prev: wp.array3d(dtype=wp.vec3)):
    """``x += b - b_prev`` at light-grid point ``wp.tid() = (i, j, k)``."""
    i, j, k = wp.tid()
    x[i, j, k] = x[i, j, k] + b[i, j, k] - b_prev[i, j, k]
