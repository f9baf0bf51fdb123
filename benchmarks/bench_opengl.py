"""Interactive frame time: ``IlluminatedVolume`` against VTK's own volumetric shadows.

Both run in the same process, in the same kind of window (off screen; under OSMesa on a
machine without a GPU: ``VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow``), on the
same data, transfer function, step, light and camera path:

* ``IlluminatedVolume`` (``vtkillum/mappers/illuminated_volume_mapper.py``): VTK's GPU ray
  caster fed a cached convection–diffusion light volume (``ConvectionDiffusionLightFilter``,
  one directional light, scattering on), computed once before the timing, as when the
  camera moves in an interactive window;
* ``vtkGPUVolumeRayCastMapper`` with VTK's volumetric shadows (VTK >= 9.1):
  ``SetVolumetricScatteringBlending(b)`` and ``SetGlobalIlluminationReach(r)``, shading on,
  one directional ``vtkLight`` along the same direction, ``ScatteringAnisotropy = g``.

Each frame turns the camera by one degree (``Azimuth(1)``) and waits for the frame to be
finished (``WaitForCompletion``); the first two frames (shader compilation, texture upload)
are not timed. The renderers take turns frame by frame, so that a change of the machine's
load (the development machines are shared) affects all of them alike. The table gives the
median ms per frame and the median over the rounds of the ratio IlluminatedVolume / VTK.

Examples
--------
VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow python benchmarks/bench_opengl.py
python benchmarks/bench_opengl.py --size 128 --image 512 --frames 5 --reach 0.25 1.0
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")

import numpy as np
import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401  (the GPU volume mapper)
from vtkmodules.vtkRenderingCore import (
    vtkLight,
    vtkRenderer,
    vtkRenderWindow,
    vtkVolume,
    vtkVolumeProperty,
)
from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkOpenGLGPUVolumeRayCastMapper

from vtkillum.data import procedural
from vtkillum.filters import ConvectionDiffusionLightFilter
from vtkillum.io.convert import image_data_from_volume
from vtkillum.mappers import IlluminatedVolume, apply_camera_to_vtk
from vtkillum.mappers.camera_bridge import apply_scene_to_volume_property

#: The light (travel direction, irradiance) of both renderers.
LIGHT = ((1.0, -1.0, -1.0), (3.0, 3.0, 3.0))


def dataset(name: str, size: int):
    """A built-in volume of ``size``³ points and its recommended scene."""
    if name == "ct":
        volume = procedural.ct_phantom(size)
    elif name == "plume":
        volume = procedural.smoke_plume((size, size, size))
    else:
        raise ValueError(f"unknown dataset {name!r}; ct or plume")
    return volume, procedural.default_scene(name, volume)


def window_for(image_size: int):
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(image_size, image_size)
    renderer = vtkRenderer()
    renderer.SetBackground(0, 0, 0)
    window.AddRenderer(renderer)
    return window, renderer


class Frames:
    """A window showing one renderer; :meth:`frame` turns the camera by 1 degree, renders
    and waits for the frame to be finished, returning the milliseconds."""

    def __init__(self, window, renderer, warmup: int = 2):
        self.window, self.renderer = window, renderer
        self.times = []
        for _ in range(warmup):  # shader compilation, texture upload
            self.frame(record=False)

    def frame(self, record: bool = True) -> float:
        self.renderer.GetActiveCamera().Azimuth(1.0)
        self.renderer.ResetCameraClippingRange()
        t0 = time.perf_counter()
        self.window.Render()
        self.window.WaitForCompletion()
        ms = 1000.0 * (time.perf_counter() - t0)
        if record:
            self.times.append(ms)
        return ms

    def picture(self) -> np.ndarray:
        return _read(self.window)


def illuminated_volume(volume, scene, image_size, **options):
    """``(Frames, milliseconds of the light volume)`` for IlluminatedVolume."""
    image = image_data_from_volume(volume)
    light = ConvectionDiffusionLightFilter()
    light.SetInputData(image)
    light.SetTransferFunction(scene.transfer_function)
    light.AddDirectionalLight(*LIGHT)
    light.SetScattering(0.02, 0.02, 0.02)
    t0 = time.perf_counter()
    light.Update()  # the cached light volume: computed once, not per frame
    light_ms = 1000.0 * (time.perf_counter() - t0)
    window, renderer = window_for(image_size)
    actor = IlluminatedVolume(image, scene, illumination=light.GetOutputPort(),
                              exposure=4 * np.pi / 3, **options)
    renderer.AddVolume(actor)
    apply_camera_to_vtk(scene.camera, renderer.GetActiveCamera())
    frames = Frames(window, renderer)
    frames.keep = (actor, light, image)
    return frames, light_ms


def vtk_shadows(volume, scene, image_size, reach, blending):
    """:class:`Frames` for vtkGPUVolumeRayCastMapper with VTK's volumetric shadows."""
    image = image_data_from_volume(volume)
    mapper = vtkOpenGLGPUVolumeRayCastMapper()
    mapper.SetInputData(image)
    mapper.SetBlendModeToComposite()
    mapper.AutoAdjustSampleDistancesOff()
    mapper.SetSampleDistance(scene.resolved_step_size(volume))
    mapper.SetUseJittering(0)
    mapper.SetVolumetricScatteringBlending(blending)
    mapper.SetGlobalIlluminationReach(reach)
    prop = vtkVolumeProperty()
    apply_scene_to_volume_property(scene, volume, prop)
    prop.ShadeOn()
    prop.SetAmbient(0.1)
    prop.SetDiffuse(0.9)
    prop.SetSpecular(0.0)
    prop.SetScatteringAnisotropy(scene.anisotropy)
    actor = vtkVolume()
    actor.SetMapper(mapper)
    actor.SetProperty(prop)
    window, renderer = window_for(image_size)
    renderer.AddVolume(actor)
    renderer.AutomaticLightCreationOff()
    renderer.RemoveAllLights()
    light = vtkLight()
    light.SetLightTypeToSceneLight()
    light.SetPositional(False)
    direction = np.asarray(LIGHT[0], float)
    light.SetPosition(*(-direction))
    light.SetFocalPoint(0.0, 0.0, 0.0)
    light.SetIntensity(1.0)
    renderer.AddLight(light)
    apply_camera_to_vtk(scene.camera, renderer.GetActiveCamera())
    frames = Frames(window, renderer)
    frames.keep = (actor, mapper, image, light)
    return frames


def _read(window) -> np.ndarray:
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

    grab = vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.Update()
    out = grab.GetOutput()
    w, h, _ = out.GetDimensions()
    return vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, 3)[::-1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=128, help="volume points per axis")
    parser.add_argument("--image", type=int, default=512, help="window width and height")
    parser.add_argument("--frames", type=int, default=5, help="timed frames per renderer")
    parser.add_argument("--datasets", nargs="+", default=["ct", "plume"])
    parser.add_argument("--reach", type=float, nargs="+", default=[0.1, 0.25, 0.5, 1.0],
                        help="VTK's GlobalIlluminationReach values to run")
    parser.add_argument("--blending", type=float, default=1.0,
                        help="VTK's VolumetricScatteringBlending (0 surface, 1 volumetric)")
    parser.add_argument("--save", help="folder for the last frame of each renderer (PNG)")
    opts = parser.parse_args(argv)

    window = vtkRenderWindow()
    print(f"window {window.GetClassName()}, volume {opts.size}^3, image {opts.image}^2, "
          f"{opts.frames} frames each, the renderers taking turns frame by frame (median ms "
          "per frame; ratio: median over the rounds of IlluminatedVolume / VTK)")
    print("| data | renderer | ms per frame | ratio IlluminatedVolume / VTK |")
    print("|---|---|---|---|")
    for name in opts.datasets:
        volume, scene = dataset(name, opts.size)
        ours, light_ms = illuminated_volume(volume, scene, opts.image)
        theirs = {reach: vtk_shadows(volume, scene, opts.image, reach, opts.blending)
                  for reach in opts.reach}
        for _ in range(opts.frames):  # taking turns: load changes hit all alike
            ours.frame()
            for frames in theirs.values():
                frames.frame()
        print(f"| {name} | IlluminatedVolume (convection-diffusion volume, computed once in "
              f"{light_ms:.0f} ms) | {statistics.median(ours.times):.0f} | |", flush=True)
        for reach, frames in theirs.items():
            ratio = statistics.median(a / b for a, b in zip(ours.times, frames.times))
            print(f"| {name} | VTK volumetric shadows (reach {reach:g}, blending "
                  f"{opts.blending:g}) | {statistics.median(frames.times):.0f} | {ratio:.2f} |",
                  flush=True)
        if opts.save:
            _save(opts.save, f"{name}_illuminated.png", ours.picture())
            for reach, frames in theirs.items():
                _save(opts.save, f"{name}_vtk_reach{reach:g}.png", frames.picture())
        for frames in (ours, *theirs.values()):
            frames.window.Finalize()
    return 0


def _save(folder, name, rgb) -> None:
    from pathlib import Path

    from vtkillum.core.tonemap import write_png

    Path(folder).mkdir(parents=True, exist_ok=True)
    write_png(Path(folder) / name, rgb)


if __name__ == "__main__":
    raise SystemExit(main())
