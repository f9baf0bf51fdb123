"""Cameras and scenes between VTK objects and the core types.

``vtkCamera`` and :class:`vtkillum.core.camera.Camera` describe the same
pinhole/parallel camera (``DESIGN.md``), so the conversion copies position,
focal point, view up, vertical view angle and parallel scale. What the core
camera does not model -- an off-centre window (``SetWindowCenter``), view shear,
a user view transform, eye separation for stereo -- is refused with an error,
not silently dropped. A horizontal view angle (``UseHorizontalViewAngleOn``) is
converted to the vertical one given the image aspect ratio.

The optical model comes from a ``vtkVolumeProperty`` (colour and scalar opacity
of one component and its ``ScalarOpacityUnitDistance``) through
:func:`vtkillum.io.convert.transfer_function_from_vtk`; lights, albedo, shading
and the other scene fields come from a base :class:`~vtkillum.core.scene.Scene`.
:func:`apply_scene_to_volume_property` goes the other way.
"""

from __future__ import annotations

import copy

import numpy as np
from vtkmodules.vtkRenderingCore import vtkCamera, vtkVolumeProperty

from vtkillum.core.camera import Camera
from vtkillum.core.scene import Scene
from vtkillum.core.volume import GridGeometry
from vtkillum.io.convert import transfer_function_from_vtk, transfer_function_to_vtk


def camera_from_vtk(vtk_camera: vtkCamera, aspect: float | None = None) -> Camera:
    """The core :class:`~vtkillum.core.camera.Camera` equivalent to ``vtk_camera``.

    Parameters
    ----------
    vtk_camera : vtkCamera
    aspect : float, optional
        Image width / height; needed only when the camera uses a horizontal view angle.

    Raises
    ------
    ValueError
        If the camera uses features the core camera does not model (window centre,
        view shear, a user view transform), or a horizontal view angle without ``aspect``.
    """
    if not isinstance(vtk_camera, vtkCamera):
        raise TypeError(f"expected a vtkCamera, got {type(vtk_camera).__name__}")
    if any(abs(c) > 1e-12 for c in vtk_camera.GetWindowCenter()):
        raise ValueError(
            "vtkCamera.SetWindowCenter (an off-centre projection) is not supported; reset it "
            "with SetWindowCenter(0, 0)"
        )
    if any(abs(s - d) > 1e-12 for s, d in zip(vtk_camera.GetViewShear(), (0.0, 0.0, 1.0))):
        raise ValueError(
            "vtkCamera view shear is not supported; reset it with SetViewShear(0, 0, 1)"
        )
    if vtk_camera.GetUserViewTransform() is not None or vtk_camera.GetUserTransform() is not None:
        raise ValueError(
            "vtkCamera user (view) transforms are not supported; apply the transform to the "
            "camera's position, focal point and view up instead"
        )
    angle = float(vtk_camera.GetViewAngle())
    if vtk_camera.GetUseHorizontalViewAngle() and not vtk_camera.GetParallelProjection():
        if aspect is None or not aspect > 0:
            raise ValueError(
                "this vtkCamera uses a horizontal view angle; pass aspect=width/height to convert "
                "it to the vertical angle the core camera uses"
            )
        angle = float(np.degrees(2.0 * np.arctan(np.tan(np.radians(angle) / 2.0) / aspect)))
    return Camera(
        position=vtk_camera.GetPosition(),
        focal_point=vtk_camera.GetFocalPoint(),
        view_up=vtk_camera.GetViewUp(),
        view_angle=angle,
        parallel_projection=bool(vtk_camera.GetParallelProjection()),
        parallel_scale=float(vtk_camera.GetParallelScale()),
    )


def apply_camera_to_vtk(camera: Camera, vtk_camera: vtkCamera) -> vtkCamera:
    """Set ``vtk_camera`` to ``camera`` (vertical view angle); returns ``vtk_camera``.

    The clipping range is not touched: call ``renderer.ResetCameraClippingRange()``
    afterwards.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"expected a vtkillum Camera, got {type(camera).__name__}")
    vtk_camera.SetPosition(*camera.position)
    vtk_camera.SetFocalPoint(*camera.focal_point)
    vtk_camera.SetViewUp(*camera.view_up)
    vtk_camera.UseHorizontalViewAngleOff()
    vtk_camera.SetViewAngle(camera.view_angle)
    vtk_camera.SetParallelProjection(int(camera.parallel_projection))
    vtk_camera.SetParallelScale(camera.parallel_scale)
    return vtk_camera


def scene_from_vtk(volume_property: vtkVolumeProperty, vtk_camera: vtkCamera | None = None,
                   base: Scene | None = None, component: int = 0,
                   aspect: float | None = None) -> Scene:
    """A :class:`~vtkillum.core.scene.Scene` whose optical model is ``volume_property``'s.

    Parameters
    ----------
    volume_property : vtkVolumeProperty
        Colour transfer function, scalar opacity and ``ScalarOpacityUnitDistance`` of
        ``component`` are used (a gray-level colour function is not supported: use RGB).
    vtk_camera : vtkCamera, optional
        Camera of the scene; default: the base scene's.
    base : Scene, optional
        Lights, albedo, anisotropy, shading, step size, background and method options;
        default ``Scene()``. It is copied, not modified.
    component : int
        Component whose functions to read (independent components).
    aspect : float, optional
        Image width / height, for a camera with a horizontal view angle.
    """
    if not isinstance(volume_property, vtkVolumeProperty):
        raise TypeError(f"expected a vtkVolumeProperty, got {type(volume_property).__name__}")
    if volume_property.GetColorChannels(component) != 3:
        raise ValueError(
            "the volume property has a gray-level transfer function (SetColor with a "
            "vtkPiecewiseFunction); give it a vtkColorTransferFunction"
        )
    scene = copy.deepcopy(base) if base is not None else Scene()
    scene.transfer_function = transfer_function_from_vtk(
        volume_property.GetRGBTransferFunction(component),
        volume_property.GetScalarOpacity(component),
    )
    scene.opacity_unit_distance = float(volume_property.GetScalarOpacityUnitDistance(component))
    if vtk_camera is not None:
        scene.camera = camera_from_vtk(vtk_camera, aspect)
    return scene


def apply_scene_to_volume_property(scene: Scene, volume, volume_property: vtkVolumeProperty,
                                   component: int = 0) -> vtkVolumeProperty:
    """Give ``volume_property`` the scene's transfer function and opacity unit distance.

    Parameters
    ----------
    scene : Scene
    volume : object
        Anything with the attributes the scene's ``resolved_*`` helpers read
        (``value_range`` and ``mean_spacing()``): a core ``Volume`` or
        :class:`GridSummary`. Used for the defaults of a scene without a transfer
        function or unit distance.
    volume_property : vtkVolumeProperty
        Modified in place: colour and scalar opacity of ``component``, its unit distance,
        linear interpolation, shading off (the illumination is the shading).
    """
    tf = scene.resolved_transfer_function(volume)
    color_tf, opacity_tf = transfer_function_to_vtk(tf)
    volume_property.SetColor(component, color_tf)
    volume_property.SetScalarOpacity(component, opacity_tf)
    volume_property.SetScalarOpacityUnitDistance(component, scene.resolved_unit_distance(volume))
    volume_property.SetInterpolationTypeToLinear()
    volume_property.ShadeOff()
    return volume_property


class GridSummary(GridGeometry):
    """The geometry and value range of a VTK image, as ``Scene.resolved_*`` read them.

    The scene's data-dependent defaults (transfer-function ramp, unit distance, step
    size, camera) need only these attributes of a core ``Volume``; this avoids copying a
    large image into one just to resolve them.

    Parameters
    ----------
    image : vtkImageData
    scalars : vtkDataArray
        The rendered array (its range is the value range).
    """

    def __init__(self, image, scalars) -> None:
        from vtkillum.io.convert import direction_matrix, first_point

        self.dims = tuple(int(n) for n in image.GetDimensions())
        self.spacing = np.array(image.GetSpacing(), dtype=np.float64)
        self.direction = direction_matrix(image)
        self.origin = first_point(image.GetOrigin(), image.GetExtent(), self.spacing,
                                  self.direction)
        lo, hi = scalars.GetRange(0)
        self.value_range = (float(lo), float(hi))

