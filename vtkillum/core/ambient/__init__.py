"""Ambient volume scattering (Ament, Sadlo & Weiskopf, IEEE TVCG 2013).

Four steps, one module each (numpy + warp only):

* :mod:`~vtkillum.core.ambient.table` — the preintegration table
  ``L̃o(θ, σ̃t, g)``: Monte-Carlo light transport in a homogeneous unit sphere lit
  by a distant light front (paper section 4.1), loading and version check of the
  shipped table, and the generator CLI
  (``python -m vtkillum.core.ambient.table``).
* :mod:`~vtkillum.core.ambient.sat` — the ambient extinction volume ``σ̃t``: the
  mean extinction over a cube of the sphere's volume from a 3D summed-area table
  (eqs. 12–13).
* :mod:`~vtkillum.core.ambient.tube_march` — light distribution by tube marching
  with step ``2r`` (eqs. 14–17; ``σ̃t`` averaged along each step), cached as a radiance
  volume.
* :mod:`~vtkillum.core.ambient.gather` — ambient ray casting: the centred estimator
  (default; exact unscattered light plus the table's scattered part at the sphere's
  centre) or Algorithm 1 as published (eqs. 18–21).

Accuracy against the unbiased path tracer, and what remains of the sphere approximation,
are measured in ``docs/ambient_scattering.md`` (``benchmarks/ambient_accuracy.py``).

:mod:`~vtkillum.core.ambient.cache` keeps the intermediate volumes and recomputes
only what an edit invalidates (the paper's Table 1), and
:mod:`~vtkillum.core.ambient.render` is the ``"ambient-scattering"`` render method.
"""
