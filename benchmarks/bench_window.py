"""Frames per second of a VTK window (what a pyvista ``Plotter`` wraps) showing a warp method.

The window is a ``vtkRenderWindow`` of ``--image``² pixels (off screen: set
``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` on a GPU, ``vtkOSOpenGLRenderWindow``
under OSMesa) whose renderer shows a :class:`~vtkillum.mappers.compute_mapper.ComputeVolumeRenderer`:
each frame turns the camera (``Azimuth``), renders the window (the renderer's
``StartEvent`` re-renders the volume with the method at the new camera and uploads the
tone-mapped image as the background texture) and waits for it (``glFinish``). The volume
is ``bench_scaling``'s CT-like volume made on the device; its light volume is computed
before the timing (the first frame), as when a user orbits around loaded data. The first
two frames are not timed. Prints ms per frame (median) and frames per second per method.

Examples
--------
VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow python benchmarks/bench_window.py --sizes 512
python benchmarks/bench_window.py --device cpu --sizes 32 --image 64 --frames 3
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vtkillum.core.device import resolve_device

DEFAULT_METHODS = ["emission", "ambient-scattering", "transmittance", "convection-diffusion"]


def time_window(volume, scene, method: str, image: int, frames: int, device: str) -> float:
    """Median ms per camera-move frame of a window showing ``method``."""
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (the OpenGL backend)
    from vtkmodules.vtkRenderingCore import vtkRenderer, vtkRenderWindow

    from vtkillum.mappers.camera_bridge import apply_camera_to_vtk
    from vtkillum.mappers.compute_mapper import ComputeVolumeRenderer

    renderer = vtkRenderer()
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(image, image)
    window.AddRenderer(renderer)
    apply_camera_to_vtk(scene.resolved_camera(volume), renderer.GetActiveCamera())
    view = ComputeVolumeRenderer(renderer, volume, scene, method=method, device=device)
    times = []
    for frame in range(frames + 2):
        renderer.GetActiveCamera().Azimuth(2.0)
        t0 = time.perf_counter()
        window.Render()
        window.WaitForCompletion()
        if frame >= 2:
            times.append(time.perf_counter() - t0)
    view.detach()
    window.Finalize()
    return 1e3 * float(np.median(times))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="cpu, cuda (default: cuda if present)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--image", type=int, default=1024, help="window width and height")
    ap.add_argument("--frames", type=int, default=10, help="timed camera moves per method")
    ap.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    args = ap.parse_args(argv)

    import warp as wp
    from bench_scaling import device_volume, make_scene

    device = resolve_device(args.device)
    name = wp.get_device(device).name
    print(f"## window frame time — {name}, {args.image}² window, camera moves of 2°\n")
    print("| volume | method | ms per frame | frames per second |")
    print("|---|---|---|---|")
    for n in args.sizes:
        volume, _ = device_volume(n, device)
        scene = make_scene(volume)
        for method in args.methods:
            ms = time_window(volume, scene, method, args.image, args.frames, device)
            print(f"| {n}³ | {method} | {ms:.1f} | {1e3 / ms:.0f} |", flush=True)


if __name__ == "__main__":
    main()
