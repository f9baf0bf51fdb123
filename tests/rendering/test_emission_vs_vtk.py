"""The ``emission`` mode agrees pixel by pixel with VTK's ``vtkGPUVolumeRayCastMapper``.

Both render the same smooth volume (two Gaussian blobs, anisotropic spacing, an
offset origin) with the same colour/opacity transfer functions, opacity unit
distance, sample distance, linear interpolation, no shading, no jitter, the same
perspective camera and a black background. VTK runs offscreen through OSMesa
(``conftest.py`` selects ``vtkOSOpenGLRenderWindow``) and its frame buffer is read
back as 8-bit linear RGB, which is directly comparable with our premultiplied
linear radiance.

Tolerances (linear RGB in [0, 1], over all pixels and channels):
mean absolute error < ``MEAN_TOL`` and 99th percentile < ``P99_TOL``. They sit a
few times above the measured agreement (mean 4.5e-4, 99th percentile 2.0e-3;
8-bit quantisation alone gives about 1e-3 on covered pixels) and well below the
error of a 20 % wrong unit distance (mean 8.9e-3, 99th percentile 5.5e-2) or a
mirrored axis (5.4e-2, 0.43); the test renders both of those
deliberately broken variants and requires them to fail the same tolerance, so
it proves it can catch them.
"""

import numpy as np
import pytest
from helpers import blob_tf, blob_volume, read_window_rgb, zoomed_camera

from vtkillum.core.camera import Camera
from vtkillum.core.raycast import render_emission
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

vtk_core = pytest.importorskip("vtkmodules.vtkRenderingCore")
from vtkmodules.util import numpy_support  # noqa: E402
from vtkmodules.vtkCommonDataModel import vtkImageData, vtkPiecewiseFunction  # noqa: E402
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction  # noqa: E402

import vtkmodules.vtkRenderingOpenGL2  # noqa: E402,F401  (OpenGL factory overrides)
import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: E402,F401  (GPU ray caster)

MEAN_TOL = 1.5e-3
P99_TOL = 6e-3
WIDTH, HEIGHT = 64, 48


def vtk_render(volume: Volume, tf: TransferFunction, u: float, step: float, cam: Camera):
    """Render with vtkGPUVolumeRayCastMapper; returns (H, W, 3) linear RGB, row 0 on top."""
    img = vtkImageData()
    img.SetDimensions(*volume.dims)
    img.SetSpacing(*volume.spacing)
    img.SetOrigin(*volume.origin)
    arr = numpy_support.numpy_to_vtk(volume.scalars.ravel(order="F"), deep=True)
    arr.SetName("scalars")
    img.GetPointData().SetScalars(arr)

    ctf = vtkColorTransferFunction()
    otf = vtkPiecewiseFunction()
    for s, a, c in zip(tf.scalars, tf.opacity, tf.colors):
        ctf.AddRGBPoint(s, *c)
        otf.AddPoint(s, a)
    prop = vtk_core.vtkVolumeProperty()
    prop.SetColor(ctf)
    prop.SetScalarOpacity(otf)
    prop.SetScalarOpacityUnitDistance(u)
    prop.SetInterpolationTypeToLinear()
    prop.ShadeOff()

    from vtkmodules.vtkRenderingVolume import vtkGPUVolumeRayCastMapper

    mapper = vtkGPUVolumeRayCastMapper()
    mapper.SetInputData(img)
    mapper.SetBlendModeToComposite()
    mapper.SetAutoAdjustSampleDistances(0)
    mapper.SetSampleDistance(step)
    mapper.SetUseJittering(0)
    actor = vtk_core.vtkVolume()
    actor.SetMapper(mapper)
    actor.SetProperty(prop)

    ren = vtk_core.vtkRenderer()
    ren.AddVolume(actor)
    ren.SetBackground(0.0, 0.0, 0.0)
    vc = ren.GetActiveCamera()
    vc.SetPosition(*cam.position)
    vc.SetFocalPoint(*cam.focal_point)
    vc.SetViewUp(*cam.view_up)
    vc.SetViewAngle(cam.view_angle)
    ren.ResetCameraClippingRange()
    win = vtk_core.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(0)
    win.AddRenderer(ren)
    win.SetSize(WIDTH, HEIGHT)
    win.Render()
    if not mapper.IsRenderSupported(win, prop):
        pytest.skip("vtkGPUVolumeRayCastMapper is not supported by this OpenGL")

    rgb = read_window_rgb(win)
    win.Finalize()
    return rgb


def errors(ours, theirs):
    diff = np.abs(ours - theirs)
    return float(diff.mean()), float(np.percentile(diff, 99))


def test_emission_matches_vtk_gpu_ray_caster():
    vol = blob_volume()
    tf = blob_tf()
    u = 1.3
    step = 0.5 * float(vol.spacing.min())
    cam = zoomed_camera(vol)
    reference = vtk_render(vol, tf, u, step, cam)
    assert reference.max() > 0.3, "VTK rendered an (almost) empty image"

    def ours(volume, unit_distance):
        scene = Scene(transfer_function=tf, opacity_unit_distance=unit_distance, camera=cam)
        res = render_emission(volume, scene, WIDTH, HEIGHT, "cpu", step_size=step, jitter=False,
                              early_termination=1.0)
        assert res.alpha.max() < 0.99  # stays clear of VTK's own early ray termination
        return res.radiance

    mean, p99 = errors(ours(vol, u), reference)
    print(f"emission vs VTK: mean abs error {mean:.2e}, 99th percentile {p99:.2e}")
    assert mean < MEAN_TOL and p99 < P99_TOL, (mean, p99)

    # The tolerance is tight enough to catch a wrong unit distance or a mirrored axis.
    wrong_u = errors(ours(vol, 1.2 * u), reference)
    mirrored = Volume(vol.scalars[::-1], vol.spacing, vol.origin)
    flipped = errors(ours(mirrored, u), reference)
    for name, (m, p) in (("unit distance x1.2", wrong_u), ("x axis mirrored", flipped)):
        assert m > MEAN_TOL or p > P99_TOL, f"{name} was not detected: {m:.2e}, {p:.2e}"
