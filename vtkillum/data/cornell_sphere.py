"""The Cornell box with a sphere: the photon-mapping paper's test scene (Jönsson et al. 2012).

:func:`vtkillum.data.procedural.cornell_box` (dense walls and blocks around a thin
fog, one point light under the ceiling) with a sphere of its own data value
:data:`SPHERE` on the floor, front left, whose colour :func:`cornell_sphere_scene`
sets -- the edit of the paper's Figs. 4 and 7 and Table 1 ("changed the color of the
sphere"): a transfer-function change confined to one data interval.
"""

from __future__ import annotations

import numpy as np

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.data.procedural import cornell_box, default_scene

#: Data value of the sphere (between the white 0.5 and red 0.75 materials).
SPHERE = 0.62
#: Centre and radius of the sphere (world units, box [-1, 1]³, y up).
SPHERE_CENTRE = (-0.42, -0.6, 0.42)
SPHERE_RADIUS = 0.3
#: Half-width of the sphere's opacity peak in the transfer function.
PEAK = 0.04


def cornell_sphere(n: int = 64) -> Volume:
    """The Cornell box of :func:`~vtkillum.data.procedural.cornell_box` with the sphere."""
    box = cornell_box(n)
    h = float(box.spacing[0])
    x = -1.0 + h * np.arange(box.dims[0])
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij", sparse=True)
    cx, cy, cz = SPHERE_CENTRE
    inside = (X - cx) ** 2 + (Y - cy) ** 2 + (Z - cz) ** 2 <= SPHERE_RADIUS ** 2
    values = np.where(inside, np.float32(SPHERE), box.scalars)
    return Volume(values.astype(np.float32), box.spacing, box.origin)


def cornell_sphere_scene(volume: Volume, color=(0.9, 0.75, 0.15), opacity: float = 0.4):
    """The Cornell box's default scene with an opacity peak and ``color`` for the sphere."""
    scene = default_scene("cornell", volume)
    tf = scene.transfer_function
    points = [SPHERE - PEAK, SPHERE, SPHERE + PEAK]
    scalars = np.concatenate([tf.scalars, points])
    order = np.argsort(scalars)
    opacity_values = np.concatenate([tf.opacity, [0.0, opacity, 0.0]])
    colors = np.vstack([tf.colors, [color] * 3])
    scene.transfer_function = TransferFunction(scalars[order], opacity_values[order],
                                               colors[order])
    return scene
