"""Convection–diffusion light volumes (Zhang & Ma, "Fast Global Illumination for
Interactive Volume Visualization", I3D 2013): the ``"convection-diffusion"`` method.

One module per stage of the paper's pipeline (Fig. 2, Algorithm 1), numpy + warp only:

* :mod:`~vtkillum.core.convection_diffusion.opacity` — the light grid and its
  extinction ("opacity volume", §5.2, §7).
* :mod:`~vtkillum.core.convection_diffusion.convection` — convection–absorption of
  each light: steady transmittance in one wavefront-ordered sweep (§4.1–4.5, §5.4).
* :mod:`~vtkillum.core.convection_diffusion.composition` — composition of the lights
  (eq. 22) and the first-scattered source of the physical model.
* Diffusion, two models:

  * ``"physical"`` (default): :mod:`~vtkillum.core.convection_diffusion.radiative` —
    the diffusion approximation of radiative transfer for the scattered light,
    flux-limited, vacuum boundary, nonlinear multigrid (accuracy against the path
    tracer in its docstring); :mod:`~vtkillum.core.convection_diffusion.reconstruction`
    filters it along thick surfaces for the ray caster;
  * ``"paper"``: :mod:`~vtkillum.core.convection_diffusion.diffusion` — Zhang & Ma's
    eq. 23 and its solvers; :mod:`~vtkillum.core.convection_diffusion.stencil` is the
    operator, :mod:`~vtkillum.core.convection_diffusion.multigrid` the geometric
    multigrid (its hierarchy and transfer kernels serve both models).

* :mod:`~vtkillum.core.convection_diffusion.solver` — :class:`ConvectionDiffusionSolver`:
  the pipeline and partial recomputation (Algorithm 1).
* :mod:`~vtkillum.core.convection_diffusion.render` — the render method (eq. 24 via
  :func:`vtkillum.core.raycast.render_illuminated`).
"""

from vtkillum.core.convection_diffusion.convection import SCHEMES, convect_light
from vtkillum.core.convection_diffusion.diffusion import SOLVERS, DiffusionReport, DiffusionSolver
from vtkillum.core.convection_diffusion.render import render_convection_diffusion
from vtkillum.core.convection_diffusion.solver import (
    OPTIONS,
    ConvectionDiffusionSolver,
    UpdateStats,
)

__all__ = [
    "OPTIONS", "SCHEMES", "SOLVERS", "ConvectionDiffusionSolver", "DiffusionReport",
    "DiffusionSolver", "UpdateStats", "convect_light", "render_convection_diffusion",
]
