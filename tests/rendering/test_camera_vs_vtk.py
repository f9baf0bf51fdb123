"""Our Camera sends the ray of pixel (row, col) where vtkCamera projects it."""

import numpy as np
import pytest

from vtkillum.core.camera import Camera

vtk = pytest.importorskip("vtkmodules.vtkRenderingCore")


def _vtk_project(cam: Camera, points, width, height):
    """Project world points to pixel coordinates (col, row-from-top) with VTK's matrices."""
    vc = vtk.vtkCamera()
    vc.SetPosition(*cam.position)
    vc.SetFocalPoint(*cam.focal_point)
    vc.SetViewUp(*cam.view_up)
    vc.SetViewAngle(cam.view_angle)
    vc.SetParallelProjection(cam.parallel_projection)
    vc.SetParallelScale(cam.parallel_scale)
    vc.SetClippingRange(0.01, 1000.0)
    m = vc.GetCompositeProjectionTransformMatrix(width / height, -1, 1)
    M = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
    h = np.c_[points, np.ones(len(points))] @ M.T
    ndc = h[:, :3] / h[:, 3:]
    col = (ndc[:, 0] + 1) / 2 * width
    row = (1 - ndc[:, 1]) / 2 * height
    return np.c_[col, row]


@pytest.mark.parametrize("parallel", [False, True])
def test_rays_hit_vtk_projection(parallel):
    cam = Camera(position=(1.0, 2.0, 6.0), focal_point=(0.2, -0.1, 0.3), view_up=(0.1, 1.0, 0.0),
                 view_angle=35.0, parallel_projection=parallel, parallel_scale=1.7)
    width, height = 40, 24
    origins, dirs = cam.ray_directions(width, height)
    rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    # A point 3 units along each pixel's ray must project to that pixel's centre.
    points = (origins + 3.0 * dirs).reshape(-1, 3)
    projected = _vtk_project(cam, points, width, height)
    expected = np.c_[cols.reshape(-1) + 0.5, rows.reshape(-1) + 0.5]
    assert np.abs(projected - expected).max() < 1e-6


def test_view_up_parallel_to_view_direction_is_an_error():
    with pytest.raises(ValueError, match="view_up"):
        Camera(position=(0, 0, 5), focal_point=(0, 0, 0), view_up=(0, 0, 1))
