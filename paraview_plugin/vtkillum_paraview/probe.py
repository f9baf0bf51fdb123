"""Does the render-view illumination work in this ParaView? A self-test, run once.

:mod:`.display` replaces the composite step of VTK's GPU ray caster with GLSL
written against VTK's shader template (:mod:`.shaders`). The template's tags
have been the same from VTK 9.2 to 9.6, but a build whose template differs (a
future VTK, a Kitware binary with other options, a driver that rejects the
GLSL) would compile nothing and draw nothing. Rather than trusting a list of
tested VTK versions, :func:`self_test` draws a tiny scene through the very code
path the render view uses (:class:`.display.IlluminatedVolume`, its textures,
uniforms and shader replacements, set up from a renderer's ``StartEvent``) in
an off-screen window of this ParaView's VTK, and checks the pixels:

* a 16^3 volume of constant opacity whose transmittance towards the one light is
  0 on the left half (x < 8) and 1 on the right half, seen head-on;
* it passes when the right half is lit (mean above :data:`LIT_MIN`) and the left
  half is dark (below :data:`DARK_RATIO` x the right half's mean): the shader
  compiled, the textures were bound, and the transmittance reached the pixels.

What VTK prints while the test runs (shader compiler logs) is captured, not
shown; when the test fails its first line becomes part of the one message that
says why the plain volume is drawn (see :func:`.display.hook_views`).
"""

from __future__ import annotations

import numpy as np

#: Mean of the lit (right) half, in [0, 1] per channel, below which the test fails.
LIT_MIN = 0.05
#: The shadowed (left) half must stay below this fraction of the lit half's mean.
DARK_RATIO = 0.25
#: Edge of the probe volume in points, and of the off-screen window in pixels.
N_POINTS = 16
WINDOW = 48


def probe_image():
    """The probe's data: a 16^3 image carrying illumination as a vtkIllum filter writes it."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkDoubleArray, vtkStringArray
    from vtkmodules.vtkCommonDataModel import vtkImageData

    from vtkillum_paraview.glue import (
        DEFAULT_EXPOSURE,
        LIGHTS_FIELD,
        RENDER_FIELD,
        SCALARS_FIELD,
        SCATTERED,
        TRANSMITTANCE,
    )

    n = N_POINTS
    image = vtkImageData()
    image.SetDimensions(n, n, n)
    image.SetSpacing(1.0, 1.0, 1.0)
    x = np.tile(np.arange(n), n * n)  # VTK point order: x fastest
    arrays = {
        "s": np.ones(n**3, dtype=np.float32),
        TRANSMITTANCE: (x >= n // 2).astype(np.float32),
        SCATTERED: np.zeros((n**3, 3), dtype=np.float32),
    }
    pd = image.GetPointData()
    for name, values in arrays.items():
        array = numpy_to_vtk(values, deep=True)
        array.SetName(name)
        pd.AddArray(array)
    pd.SetActiveScalars("s")
    fd = image.GetFieldData()
    # One directional light travelling away from the camera (-z), irradiance 1.
    lights = numpy_to_vtk(np.array([[0, 0, 0, -1, 1, 1, 1, 0]], dtype=np.float64), deep=True)
    lights.SetName(LIGHTS_FIELD)
    fd.AddArray(lights)
    render = vtkDoubleArray()
    render.SetName(RENDER_FIELD)
    for value in (1.0, 0.0, 1.0, DEFAULT_EXPOSURE, 1.0):  # albedo g u exposure light spacing
        render.InsertNextValue(value)
    fd.AddArray(render)
    scalars = vtkStringArray()
    scalars.SetName(SCALARS_FIELD)
    scalars.InsertNextValue("s")
    fd.AddArray(scalars)
    return image


def self_test() -> str | None:
    """Draw the probe through :class:`.display.IlluminatedVolume` off screen.

    Returns
    -------
    str or None
        None when the illumination drew as it should; otherwise why not, in one line.
    """
    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

    previous = vtkOutputWindow.GetInstance()
    previous.Register(None)  # keep ParaView's output window alive while it is swapped out
    captured = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(captured)
    verbosity = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)  # VTK logs errors to stderr too
    try:
        pixels = _draw()
        reason = _judge(pixels)
    except Exception as err:  # noqa: BLE001 - any failure means: not here
        reason = f"{type(err).__name__}: {err}"
    finally:
        vtkLogger.SetStderrVerbosity(verbosity)
        vtkOutputWindow.SetInstance(previous)
        previous.UnRegister(None)
    if reason is not None:
        log = [line.strip() for line in captured.GetOutput().splitlines()
               if "error" in line.lower()]
        if log:
            reason += f" (VTK said: {log[0][:200]})"
    return reason


def _draw() -> np.ndarray:
    """Render the probe once; the window's pixels as floats in [0, 1], (H, W, 3), row 0 at
    the bottom."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import (
        vtkColorTransferFunction,
        vtkRenderer,
        vtkRenderWindow,
        vtkVolume,
        vtkVolumeProperty,
        vtkWindowToImageFilter,
    )
    from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkOpenGLGPUVolumeRayCastMapper

    from vtkillum_paraview.display import IlluminatedVolume

    image = probe_image()
    # Stands in for ParaView's volume actor: its mapper holds the data, its property the TF.
    host = vtkVolume()
    host_mapper = vtkOpenGLGPUVolumeRayCastMapper()
    host_mapper.SetInputDataObject(image)
    host.SetMapper(host_mapper)
    colour = vtkColorTransferFunction()
    colour.AddRGBPoint(0.0, 1.0, 1.0, 1.0)
    colour.AddRGBPoint(2.0, 1.0, 1.0, 1.0)
    opacity = vtkPiecewiseFunction()
    opacity.AddPoint(0.0, 0.3)
    opacity.AddPoint(2.0, 0.3)
    prop = vtkVolumeProperty()
    prop.SetColor(colour)
    prop.SetScalarOpacity(opacity)
    prop.SetInterpolationTypeToLinear()
    host.SetProperty(prop)

    ours = IlluminatedVolume(host)
    renderer = vtkRenderer()
    renderer.SetBackground(0.0, 0.0, 0.0)
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(WINDOW, WINDOW)
    window.SetMultiSamples(0)
    window.AddRenderer(renderer)
    renderer.AddVolume(ours.volume)
    # As in the render view: textures and uniforms set while the renderer's context is current.
    renderer.AddObserver("StartEvent", lambda *a: ours.sync(renderer))
    renderer.AddObserver("EndEvent", lambda *a: ours.release_textures())
    camera = renderer.GetActiveCamera()
    centre = 0.5 * (N_POINTS - 1)
    camera.SetFocalPoint(centre, centre, centre)
    camera.SetPosition(centre, centre, centre + 4.0 * N_POINTS)
    camera.SetViewUp(0.0, 1.0, 0.0)
    camera.ParallelProjectionOn()
    camera.SetParallelScale(0.55 * N_POINTS)
    renderer.ResetCameraClippingRange()
    try:
        window.Render()
        grab = vtkWindowToImageFilter()
        grab.SetInput(window)
        grab.SetInputBufferTypeToRGB()
        grab.ReadFrontBufferOff()
        grab.Update()
        out = grab.GetOutput()
        w, h, _ = out.GetDimensions()
        rgb = vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, -1)[..., :3]
        return rgb.astype(np.float64) / 255.0
    finally:
        ours.remove(renderer)
        window.Finalize()


def _judge(pixels: np.ndarray) -> str | None:
    """None if the left half is dark and the right half lit (see module doc), else why."""
    h, w, _ = pixels.shape
    # The volume covers the middle 16/(2 * 0.55 * 16) of the window; keep away from its edges.
    inner = slice(int(0.2 * h), int(0.8 * h))
    left = pixels[inner, int(0.15 * w): int(0.4 * w)].mean()
    right = pixels[inner, int(0.6 * w): int(0.85 * w)].mean()
    if right < LIT_MIN:
        return (f"the self-test volume drew nothing (lit half {right:.3f}): the shader did "
                "not compile or the mapper did not draw")
    if left > DARK_RATIO * right:
        return (f"the self-test volume was not shadowed (shadowed half {left:.3f}, lit half "
                f"{right:.3f}): the illumination textures did not reach the shader")
    return None


__all__ = ["probe_image", "self_test"]
