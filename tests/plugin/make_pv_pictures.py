"""Regenerate ``docs/images/pv_plain_transmittance_diffusion.png`` in ParaView (pvbatch).

The built-in smoke plume (48 x 48 x 72) with its recommended transfer function, lights
and camera (``vtkillum.data.procedural.default_scene("plume")``), four panels:

1. ParaView's own volume rendering of the transfer function;
2. vtkIllum Light Transmittance, lit per sample by the render view;
3. vtkIllum Convection-Diffusion Light (Scattering 0.02), the same;
4. Light Transmittance baked into ``illuminated_rgba`` (OutputRGBA, the route for
   remote rendering): colour x light at the voxels, interpolated as a product.

Run from the project's environment (it restarts itself under ``xvfb-run -a pvbatch``)::

    python tests/plugin/make_pv_pictures.py [OUT_PNG]
"""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SIZE = [240, 300]


def relaunch(argv) -> int:
    sys.path.insert(0, str(ROOT / "paraview_plugin"))
    import pvbatch_env

    return pvbatch_env.run_pvbatch(Path(__file__).resolve(), *argv).returncode


def main(argv) -> int:
    import tempfile

    import numpy as np
    from paraview import simple
    from vtkmodules.vtkIOImage import vtkPNGReader, vtkPNGWriter
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkImageData

    simple._DisableFirstRenderCameraReset()
    namespace = globals()
    simple.LoadPlugin(str(ROOT / "paraview_plugin" / "vtkillum_plugin.py"), ns=namespace)
    import vtkillum_plugin as plugin
    from vtkillum.data.procedural import default_scene, smoke_plume
    from vtkillum.io.convert import image_data_from_volume

    target = Path(argv[0]) if argv else ROOT / "docs" / "images" / \
        "pv_plain_transmittance_diffusion.png"
    tmp = Path(tempfile.mkdtemp())
    volume = smoke_plume((48, 48, 72))
    scene = default_scene("plume", volume)
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(tmp / "plume.vti"))
    writer.SetInputData(image_data_from_volume(volume, "density"))
    writer.Write()
    reader = simple.XMLImageDataReader(FileName=[str(tmp / "plume.vti")])
    tf = scene.transfer_function
    lut = simple.GetColorTransferFunction("density")
    lut.AutomaticRescaleRangeMode = "Never"
    lut.ColorSpace = "RGB"
    lut.RGBPoints = [v for x, c in zip(tf.scalars, tf.colors) for v in (x, *c)]
    simple.GetOpacityTransferFunction("density").Points = [
        v for x, a in zip(tf.scalars, tf.opacity) for v in (x, a, 0.5, 0.0)]
    camera = scene.resolved_camera(volume)
    unit = scene.resolved_unit_distance(volume)
    exposure = 1.0  # the key light has irradiance 40: 4 pi / 40 would show it as albedo x colour

    def panel(source, name, setup=None):
        view = simple.CreateRenderView()
        view.ViewSize = SIZE
        view.OrientationAxesVisibility = 0
        view.UseColorPaletteForBackground = 0
        view.Background = list(scene.background)
        display = setup(view) if setup else simple.Show(source, view)
        if setup is None:
            display.SetRepresentationType("Volume")
            simple.ColorBy(display, ("POINTS", "density"))
            display.ScalarOpacityUnitDistance = unit
        view.CameraPosition = list(camera.position)
        view.CameraFocalPoint = list(camera.focal_point)
        view.CameraViewUp = list(camera.view_up)
        view.CameraViewAngle = camera.view_angle
        simple.Render(view)
        simple.SaveScreenshot(str(tmp / name), view, ImageResolution=SIZE)
        simple.Delete(view)

    def lit(constructor, **properties):
        proxy = namespace[constructor](Input=reader)
        proxy.Scalars = ["POINTS", "density"]
        proxy.Albedo = scene.albedo
        proxy.Anisotropy = scene.anisotropy
        proxy.Exposure = exposure
        plugin.SetLights(proxy, scene.lights)
        for key, value in properties.items():
            setattr(proxy, key, value)
        return proxy

    panel(reader, "plain.png")
    panel(lit("vtkIllumLightTransmittance", ScalarOpacityUnitDistance=unit), "transmittance.png")
    panel(lit("vtkIllumConvectionDiffusionLight", ScalarOpacityUnitDistance=unit,
              Scattering=[0.02, 0.02, 0.02]), "diffusion.png")
    baked = lit("vtkIllumLightTransmittance", ScalarOpacityUnitDistance=unit)
    panel(baked, "baked.png", lambda view: plugin.ShowIlluminated(baked, view))

    panels = []
    for name in ("plain.png", "transmittance.png", "diffusion.png", "baked.png"):
        png = vtkPNGReader()
        png.SetFileName(str(tmp / name))
        png.Update()
        image = png.GetOutput()
        w, h, _ = image.GetDimensions()
        panels.append(vtk_to_numpy(image.GetPointData().GetScalars()).reshape(h, w, -1)[..., :3])
    row = np.ascontiguousarray(np.concatenate(panels, axis=1))
    out = vtkImageData()
    out.SetDimensions(row.shape[1], row.shape[0], 1)
    out.GetPointData().SetScalars(numpy_to_vtk(row.reshape(-1, 3)))
    writer = vtkPNGWriter()
    writer.SetFileName(str(target))
    writer.SetInputData(out)
    writer.Write()
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    try:
        import paraview  # noqa: F401
    except ImportError:
        raise SystemExit(relaunch(sys.argv[1:])) from None
    raise SystemExit(main(sys.argv[1:]))
