"""vtkillum: global illumination for direct volume rendering in VTK, ParaView and pyvista.

The compute core (:mod:`vtkillum.core`) needs only numpy and warp; VTK glue lives
in :mod:`vtkillum.filters` and :mod:`vtkillum.mappers`.
"""

__version__ = "0.1.0"

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import METHODS, RenderResult, render
from vtkillum.core.scene import Scene, load_scene, save_scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume



def __getattr__(name: str):
    # Lazy, so that importing vtkillum loads neither pyvista nor vtk.
    if name in ("add_illuminated_volume", "add_computed_volume"):
        import vtkillum.pyvista_accessor as accessor

        return getattr(accessor, name)
    raise AttributeError(f"module 'vtkillum' has no attribute {name!r}")


__all__ = [
    "add_computed_volume",
    "add_illuminated_volume",
    "Camera",
    "DirectionalLight",
    "PointLight",
    "METHODS",
    "RenderResult",
    "render",
    "Scene",
    "load_scene",
    "save_scene",
    "TransferFunction",
    "Volume",
]
