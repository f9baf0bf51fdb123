"""Render the README's VTK and pyvista pictures off screen, with the README's code.

    python examples/readme_pictures.py [--out docs/images] [--size 400]

Writes ``readme_vtk.png`` (the VTK section: a smoke plume lit by a
``ConvectionDiffusionLightFilter`` through :class:`vtkillum.mappers.IlluminatedVolume`)
and ``readme_pyvista.png`` (the pyvista section: the CT head phantom at 128³, smoothed by
a Gaussian of one voxel like a scanner's point-spread function and standing in for
``head.vti``, lit by ``grid.illum.transmittance`` and shown with
``add_illuminated_volume``; unsmoothed, the phantom's voxelised skin shows terraces as
contour rings, in ``single`` as much as here). The code between the ``README`` markers is the README's,
except that the windows render off screen and are saved instead of shown.
"""

# ruff: noqa: I001  (the README's code is kept as the README has it, imports included)
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")  # headless VTK


def vtk_picture(path: Path, size: int) -> None:
    # --- README (VTK) ---------------------------------------------------------------------
    from vtkmodules.vtkRenderingCore import vtkRenderer, vtkRenderWindow
    import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401  (the GPU volume mapper)
    from vtkillum.data.procedural import smoke_plume, default_scene
    from vtkillum.filters import ConvectionDiffusionLightFilter
    from vtkillum.io.convert import image_data_from_volume
    from vtkillum.mappers import IlluminatedVolume, apply_camera_to_vtk

    volume = smoke_plume(shape=(48, 48, 72))
    scene = default_scene("plume", volume)            # transfer function, g, lights, camera
    image = image_data_from_volume(volume)            # or any reader's vtkImageData output

    light = ConvectionDiffusionLightFilter()          # or LightTransmittanceFilter
    light.SetInputData(image)
    light.SetTransferFunction(scene.transfer_function)  # or SetColorTransferFunction/SetScalarOpacity
    light.AddDirectionalLight((1, -1, -1), (3, 3, 3))
    light.SetScattering(0.02, 0.02, 0.02)

    renderer = vtkRenderer()
    renderer.AddVolume(IlluminatedVolume(image, scene, illumination=light.GetOutputPort(),
                                         exposure=4 * 3.14159 / 3))
    apply_camera_to_vtk(scene.camera, renderer.GetActiveCamera())
    window = vtkRenderWindow()
    window.AddRenderer(renderer)
    # --- end README (off screen instead of an interactor) -----------------------------------
    window.SetOffScreenRendering(1)
    window.SetSize(size, size)
    renderer.ResetCameraClippingRange()
    window.Render()
    _save_window(window, path)
    window.Finalize()


def pyvista_picture(path: Path, size: int) -> None:
    import pyvista as pv

    from vtkillum.data.procedural import ct_phantom
    from vtkillum.io.convert import image_data_from_volume

    from scipy.ndimage import gaussian_filter

    from vtkillum.core.volume import Volume

    phantom = ct_phantom(128)
    smooth = Volume(gaussian_filter(phantom.scalars, 1.0), spacing=phantom.spacing,
                    origin=phantom.origin)
    with tempfile.TemporaryDirectory() as tmp:
        head = Path(tmp) / "head.vti"
        pv.wrap(image_data_from_volume(smooth, "density")).save(head)
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            # --- README (pyvista) ---------------------------------------------------------
            import pyvista as pv
            import vtkillum

            grid = pv.read("head.vti")                        # any pv.ImageData
            lit = grid.illum.transmittance(vtkillum.DirectionalLight((1, -1, -1), (3, 3, 3)),
                                           cmap="bone", opacity="linear")
            pl = pv.Plotter(off_screen=True, window_size=(size, size))
            pl.set_background("black")
            vtkillum.add_illuminated_volume(pl, grid, illumination=lit, cmap="bone",
                                            opacity="linear")
            # --- end README (pl.show() replaced by a screenshot) ---------------------------
            pl.screenshot(str(path.resolve() if path.is_absolute() else Path(cwd) / path))
            pl.close()
        finally:
            os.chdir(cwd)


def _save_window(window, path: Path) -> None:
    from vtkmodules.vtkIOImage import vtkPNGWriter
    from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

    grab = vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.Update()
    writer = vtkPNGWriter()
    writer.SetFileName(str(path))
    writer.SetInputConnection(grab.GetOutputPort())
    writer.Write()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="docs/images", help="directory for the pictures")
    parser.add_argument("--size", type=int, default=400, help="width and height in pixels")
    opts = parser.parse_args(argv)
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    vtk_picture(out / "readme_vtk.png", opts.size)
    pyvista_picture(out / "readme_pyvista.png", opts.size)
    print(f"wrote {out / 'readme_vtk.png'} and {out / 'readme_pyvista.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
