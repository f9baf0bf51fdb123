"""Helpers several test modules share: the two-blob scene, VTK windows, configured filters.

Imported as ``from helpers import ...`` (pytest puts ``tests/`` on ``sys.path`` for the
root ``conftest.py``). VTK is imported inside the functions that need it, so core tests
can use the scene helpers without VTK.
"""

from __future__ import annotations

import numpy as np

from vtkillum.core.camera import Camera
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def blob_volume() -> Volume:
    """32³ smooth, asymmetric field: a large blob and a small off-centre one.

    Anisotropic spacing and an offset origin, so that axis or geometry mix-ups show.
    """
    n = 32
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    big = np.exp(-((X + 0.15) ** 2 + Y ** 2 + (Z - 0.1) ** 2) / 0.3)
    small = 0.8 * np.exp(-((X - 0.55) ** 2 + (Y - 0.5) ** 2 + (Z + 0.3) ** 2) / 0.06)
    return Volume(big + small, spacing=(1.0, 1.15, 0.85), origin=(-3.0, 2.0, 1.0))


def blob_tf() -> TransferFunction:
    """Coloured transfer function for :func:`blob_volume` (blue halo, green to red core)."""
    return TransferFunction(
        [0.0, 0.15, 0.45, 0.75, 1.0],
        [0.0, 0.0, 0.06, 0.12, 0.2],
        [[0.1, 0.2, 1.0], [0.1, 0.2, 1.0], [0.2, 1.0, 0.4], [1.0, 0.8, 0.1], [1.0, 0.1, 0.1]],
    )


def zoomed_camera(volume: Volume) -> Camera:
    """Oblique perspective view, closer than ResetCamera so that the blobs fill the frame."""
    cam = Camera.looking_at_bounds(volume.bounds, direction=(-0.4, -0.3, -1.0),
                                   view_up=(0.2, 1.0, 0.0))
    position = cam.focal_point + 0.55 * (cam.position - cam.focal_point)
    return Camera(position, cam.focal_point, cam.view_up, cam.view_angle)


def offscreen_window(renderer, camera: Camera, width: int, height: int):
    """An offscreen vtkRenderWindow of ``renderer`` seen through ``camera``, black background.

    No multisampling, so pixels compare one to one with the warp renderers.
    """
    from vtkmodules.vtkRenderingCore import vtkRenderWindow

    from vtkillum.mappers import apply_camera_to_vtk

    renderer.SetBackground(0.0, 0.0, 0.0)
    apply_camera_to_vtk(camera, renderer.GetActiveCamera())
    renderer.ResetCameraClippingRange()
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetMultiSamples(0)
    window.AddRenderer(renderer)
    window.SetSize(width, height)
    return window


def read_window_rgb(window) -> np.ndarray:
    """Render a VTK window and read back linear RGB in [0, 1], (H, W, 3), row 0 at the top."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

    window.Render()
    g = vtkWindowToImageFilter()
    g.SetInput(window)
    g.SetInputBufferTypeToRGB()
    g.ReadFrontBufferOff()
    g.ShouldRerenderOff()
    g.Update()
    w, h, _ = g.GetOutput().GetDimensions()
    rgb = vtk_to_numpy(g.GetOutput().GetPointData().GetScalars()).reshape(h, w, 3)
    return rgb[::-1].astype(np.float64) / 255.0  # VTK's row 0 is the bottom


def pyvista_screenshot(actor, camera: Camera, width: int, height: int) -> np.ndarray:
    """``actor`` alone in an offscreen pyvista Plotter (black) seen through ``camera``.

    Returns the screenshot as floats in [0, 1], (H, W, channels), row 0 at the top.
    """
    import pyvista as pv

    from vtkillum.mappers import apply_camera_to_vtk

    plotter = pv.Plotter(off_screen=True, window_size=(width, height))
    plotter.set_background("black")
    plotter.add_actor(actor)
    # camera_position marks the camera as set, so pyvista does not reset it on first render.
    plotter.camera_position = [tuple(camera.position), tuple(camera.focal_point),
                               tuple(camera.view_up)]
    apply_camera_to_vtk(camera, plotter.renderer.GetActiveCamera())
    plotter.renderer.ResetCameraClippingRange()
    shot = plotter.screenshot(return_img=True).astype(np.float64) / 255.0
    plotter.close()
    return shot


def rel_errors(image, reference) -> tuple[float, float]:
    """Mean and 99th percentile of ``|image - reference|`` relative to the reference's maximum."""
    diff = np.abs(image - reference) / reference.max()
    return float(diff.mean()), float(np.percentile(diff, 99))


def constant_opacity_filter(filter_class, alpha: float = 0.5):
    """A light filter of ``filter_class`` on the CPU: constant opacity ``alpha``, no lights.

    The opacity holds over data values [0, 2]; the unit distance is 1.
    """
    f = filter_class()
    f.SetDevice("cpu")
    f.SetTransferFunction(TransferFunction([0.0, 2.0], [alpha, alpha]))
    f.SetScalarOpacityUnitDistance(1.0)
    f.RemoveAllLights()
    return f
