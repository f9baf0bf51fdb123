"""Empty-space skipping for the ambient gather: which blocks of the volume are surely empty.

The classification (:mod:`vtkillum.core.empty_space`): blocks of ``BLOCK``³ cells whose
data range maps to ``σt = 0`` in the transfer function. The gather
(:mod:`vtkillum.core.ambient.gather`) leaps over empty blocks while the shifted
transmittance point ``x_o`` has also left all matter behind; the image is the same as
without skipping (only the samples that are surely empty are left out).
"""

from vtkillum.core.empty_space import BLOCK, block_ranges, block_shape, occupancy

__all__ = ["BLOCK", "block_ranges", "block_shape", "occupancy"]
