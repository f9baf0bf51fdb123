"""The refraction method inside VTK: transfer functions as VTK objects, the compute mapper."""

from __future__ import annotations

import os

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction  # noqa: E402
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction, vtkRenderer  # noqa: E402

from vtkillum.core.refraction.optics import RefractiveOptics  # noqa: E402
from vtkillum.io.optics import optics_from_vtk, optics_to_vtk  # noqa: E402


def test_vtk_functions_round_trip():
    optics = RefractiveOptics([0.0, 1.0, 2.0], [1.0, 1.5, 1.33], [0.0, 2.0],
                              [[1, 1, 1], [0.9, 0.6, 0.2]])
    eta, medium = optics_to_vtk(optics)
    back = optics_from_vtk(eta, medium)
    v = np.linspace(-1, 3, 41)
    np.testing.assert_allclose(back.eta_at(v), optics.eta_at(v))
    np.testing.assert_allclose(back.medium_at(v), optics.medium_at(v))


def test_defaults_and_curved_functions():
    assert optics_from_vtk().is_identity
    assert optics_from_vtk(vtkPiecewiseFunction(), vtkColorTransferFunction()).is_identity
    eta = vtkPiecewiseFunction()
    eta.AddPoint(0.0, 1.0, 0.2, 0.0)  # midpoint 0.2: not linear between the nodes
    eta.AddPoint(1.0, 1.6)
    optics = optics_from_vtk(eta)
    x = np.linspace(0, 1, 101)
    assert np.abs(optics.eta_at(x) - [eta.GetValue(t) for t in x]).max() < 0.01
    with pytest.raises(TypeError):
        optics_from_vtk(medium_color=eta)
    bad = vtkPiecewiseFunction()
    bad.AddPoint(0.0, -1.0)
    with pytest.raises(ValueError, match="> 0"):
        optics_from_vtk(bad)


def test_compute_mapper_renders_refraction_and_follows_the_camera():
    from helpers import offscreen_window

    from vtkillum.core.camera import Camera
    from vtkillum.core.lights import DirectionalLight
    from vtkillum.core.scene import Scene
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume
    from vtkillum.mappers import ComputeVolumeRenderer

    x = np.linspace(-1, 1, 16)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    volume = Volume(np.exp(-(X ** 2 + Y ** 2 + Z ** 2) * 3).astype(np.float32),
                    spacing=(2 / 15,) * 3, origin=(-1, -1, -1))
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.3]),
                  lights=[DirectionalLight((0.1, -0.2, -1.0), (3, 3, 3))])
    eta = vtkPiecewiseFunction()
    eta.AddPoint(0.0, 1.0)
    eta.AddPoint(1.0, 1.4)
    renderer = vtkRenderer()
    view = ComputeVolumeRenderer(renderer, volume, scene, method="refraction", device="cpu",
                                 optics=optics_from_vtk(eta))
    camera = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0)
    window = offscreen_window(renderer, camera, 24, 24)
    window.Render()
    first = view.display_image().copy()
    assert view.result.info["method"] == "refraction" and first.max() > 0
    renderer.GetActiveCamera().Azimuth(20)
    window.Render()
    assert np.abs(view.display_image().astype(int) - first).max() > 0  # re-rendered
