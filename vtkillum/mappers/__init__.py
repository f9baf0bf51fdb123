"""Turning data and illumination into pixels inside VTK windows.

* :class:`IlluminatedVolume` -- OpenGL path: a ``vtkMultiVolume`` whose GPU ray caster
  is shaded by an illumination volume (per-light transmittance with the phase function,
  scattered fluence; interactive windows, pyvista ``add_actor``).
* :class:`ComputeVolumeRenderer` -- compute path: any registered warp method
  (``emission``, ``single``, ``illumination``, progressive ``path``, ...) shown in a
  VTK renderer.
* :class:`AmbientScatteringVolume` -- OpenGL path of ambient volume scattering
  (Ament et al. 2013): warp preprocessing, VTK's GPU ray caster gathers.
* :mod:`~vtkillum.mappers.camera_bridge` -- cameras and scenes between VTK and the core.
"""

from vtkillum.mappers.ambient_volume_mapper import AmbientScatteringVolume
from vtkillum.mappers.camera_bridge import (
    apply_camera_to_vtk,
    apply_scene_to_volume_property,
    camera_from_vtk,
    scene_from_vtk,
)
from vtkillum.mappers.compute_mapper import ComputeVolumeRenderer
from vtkillum.mappers.illuminated_volume_mapper import IlluminatedVolume, IlluminationInputs

__all__ = [
    "AmbientScatteringVolume",
    "ComputeVolumeRenderer",
    "IlluminatedVolume",
    "IlluminationInputs",
    "apply_camera_to_vtk",
    "apply_scene_to_volume_property",
    "camera_from_vtk",
    "scene_from_vtk",
]
