"""Test and demo datasets: procedural volumes (numpy only) and ``builtin:NAME[:SIZE]`` specs.

:mod:`vtkillum.data.procedural`
    :func:`smoke_plume`, :func:`plume_series`, :func:`cornell_box`, :func:`ct_phantom`,
    :func:`marschner_lobb` and :func:`default_scene` (a recommended transfer function,
    lights and camera for each).
:mod:`vtkillum.data.builtin`
    Parse ``builtin:plume:128``-style specs (used by the CLI).

Nothing here imports VTK: the GPU benchmark machine uses these with numpy and warp only.
"""

from vtkillum.data.builtin import DATASETS, is_builtin, load_builtin, parse_builtin
from vtkillum.data.procedural import (
    VALUE_RANGES,
    cornell_box,
    ct_phantom,
    default_scene,
    marschner_lobb,
    plume_series,
    smoke_plume,
)

__all__ = [
    "DATASETS",
    "VALUE_RANGES",
    "cornell_box",
    "ct_phantom",
    "default_scene",
    "is_builtin",
    "load_builtin",
    "marschner_lobb",
    "parse_builtin",
    "plume_series",
    "smoke_plume",
]
