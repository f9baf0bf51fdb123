"""``RefractionRenderFilter``: the refraction method (Magnus & Bruckner 2017) as an image.

A VTK algorithm around :func:`vtkillum.core.refraction.render.render_refraction`
(called through :func:`vtkillum.core.render.render`, which renders data in any length unit):
the input volume, the colour and opacity transfer functions, the refractive-index
and medium-colour transfer functions (control-point tables), one distant light and
a camera go in; the rendered picture comes out as a 2D ``vtkImageData`` of
``ImageSize`` pixels. No math here: the filter only converts and checks.
"""

from __future__ import annotations

import math

import numpy as np
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.scene import Scene
from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.convert import add_point_array, check_image_data, volume_from_image_data

#: Point arrays of the output image.
RGB_ARRAY = "refraction_rgb"
RADIANCE_ARRAY = "radiance"
ALPHA_ARRAY = "alpha"

#: Default light: travels away from a camera that looks along -z (ParaView's default
#: view) or along the automatic camera's direction, well inside the 85 degree limit.
DEFAULT_LIGHT_DIRECTION = (0.3, -0.5, -1.0)
DEFAULT_IMAGE_SIZE = (256, 256)
#: Largest image side (pixels).
MAX_IMAGE_SIZE = 8192

_CAMERA_WORDS = {"camera.position": "CameraPosition", "camera.focal_point": "CameraFocalPoint",
                 "camera.view_up": "CameraViewUp", "camera.view_angle": "CameraViewAngle",
                 "camera.parallel_scale": "CameraParallelScale"}
_OPTION_WORDS = {"sample_distance": "SampleDistance", "softness": "Softness",
                 "direction_blur": "DirectionBlur", "specular": "Specular",
                 "roughness": "Roughness"}


class RefractionRenderFilter(IlluminationFilterBase):
    """Render a volume with refraction and caustics; the output is the picture.

    Runs the ``"refraction"`` render method of :mod:`vtkillum.core.refraction`
    (light and view rays bent by a refractive-index field, propagated plane by plane;
    caustics from the intensity law) and returns the image as a 2D ``vtkImageData``
    of ``ImageSize`` points (row ``j = 0`` is the bottom of the picture, as VTK shows
    images): in pixel units (spacing 1, origin 0) by default, or with
    ``PlaceFacingCamera`` on the camera's image plane in the world (see there). Point
    arrays:

    ``refraction_rgb`` (uint8 RGB, active scalars)
        The picture for display: ``tonemap(radiance, Exposure, Gamma)``
        (:func:`vtkillum.core.tonemap.tonemap`); show it with Map Scalars off.
    ``radiance`` (float32 RGB)
        Linear radiance reaching the camera (the method's ``RenderResult.radiance``;
        includes the background when ``Background`` is not black).
    ``alpha`` (float32)
        ``1 - transmittance`` along each view ray.

    Parameters
    ----------
    ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance, Albedo, Anisotropy
        The optical model, see :class:`~vtkillum.filters.base.IlluminationFilterBase`.
    RefractiveIndex
        Control points ``(value, eta)`` of the refractive-index transfer function
        ``eta_tf``: ``AddRefractiveIndexPoint(value, eta)``,
        ``RemoveAllRefractiveIndexPoints()``. Piecewise linear, constant outside the
        points; none (default): ``eta = 1`` everywhere (straight rays).
    MediumColor
        Control points ``(value, r, g, b)`` of the medium colour ``m_tf`` (RGB in
        [0, 1], transmitted per opacity unit distance): ``AddMediumColorPoint(value,
        r, g, b)``, ``RemoveAllMediumColorPoints()``; none (default): white.
        ``SetOptics(RefractiveOptics)`` sets both tables at once.
    LightDirection : (3,) float
        Direction the one distant light travels (world space); within 85 degrees of
        the view direction (the paper's limit). Default ``(0.3, -0.5, -1)``.
    LightIrradiance : (3,) float
        Its RGB irradiance; default ``(1, 1, 1)``.
    Softness : float
        Soft light: tan of the light's angular radius (0: hard shadows).
    SampleDistance : float
        Plane spacing in units of the smallest voxel spacing (1: the paper's setting).
    DirectionBlur, Specular, Roughness, IntensityCorrection, Seed
        The method's other options (``direction_blur``, ``specular``, ``roughness``,
        ``intensity_correction``, ``seed``; see :mod:`vtkillum.core.refraction.render`).
    ImageSize : (int, int)
        Width and height of the picture in pixels; default 256 x 256.
    CameraPosition, CameraFocalPoint, CameraViewUp : (3,) float
        As ``vtkCamera``. Position equal to the focal point (default: both 0 0 0)
        means an automatic camera that frames the data.
    CameraViewAngle : float
        Vertical view angle in degrees (perspective); default 30.
    CameraParallelProjection : bool
        Orthographic projection of half-height ``CameraParallelScale`` (world units).
    PlaceFacingCamera : bool
        Off (default): the image in pixel units (spacing 1, origin 0, axis-aligned). On:
        the image lies where the camera sees the picture, on the plane through the focal
        point facing the camera, cut to the view frustum (``Camera.image_plane``:
        origin, square spacing and a direction matrix whose axes are the camera's right,
        up and backward). Shown in a 3D view beside the data it faces the camera it was
        rendered from, at the data's size; seen from that camera it covers the data's
        picture exactly.
    Background : (3,) float
        Linear RGB radiance seen where the rays leave the volume (along the bent rays).
    Exposure : float
        Factor on the radiance in ``refraction_rgb``; 0 (default): automatic, the
        99.5th percentile of the brightest channel maps to 1.
    Gamma : float
        Display gamma of ``refraction_rgb`` (default 2.2).
    Device, InputComponent, NaNPolicy, CacheSizeMB
        As in the base class.

    Notes
    -----
    Radiance is in the light's irradiance units per steradian (the project's
    convention; with ``eta = 1`` and a white medium the picture equals the ``single``
    method's). The method supports exactly one directional light; the filter has one
    (``LightDirection``/``LightIrradiance``). Table rows may come in any order
    (sorted by value); checks happen when the filter executes and errors name the
    property (e.g. ``RefractiveIndex: eta must be > 0 at every control point``).
    """

    #: Why this filter runs on the whole volume on every rank under MPI (mode 1).
    distributed_needs = ("a distributed version needs the plane sweep's light and viewing planes passed from rank to rank in sweep order (the rays bend across pieces), and the image composited; not built yet")

    def __init__(self) -> None:
        super().__init__()
        self._lights = [DirectionalLight(DEFAULT_LIGHT_DIRECTION, (1.0, 1.0, 1.0))]
        self._eta_points: list = []
        self._medium_points: list = []
        self._image_size = DEFAULT_IMAGE_SIZE
        self._camera_position = (0.0, 0.0, 0.0)
        self._camera_focal_point = (0.0, 0.0, 0.0)
        self._camera_view_up = (0.0, 1.0, 0.0)
        self._camera_view_angle = 30.0
        self._camera_parallel_projection = False
        self._camera_parallel_scale = 1.0
        self._place_facing_camera = False
        self._sample_distance = 1.0
        self._softness = 0.0
        self._direction_blur = 1.0
        self._specular = 1.0
        self._roughness = 0.3
        self._intensity_correction = True
        self._seed = 0
        self._background = (0.0, 0.0, 0.0)
        self._exposure = 0.0
        self._gamma = 2.2
        self.last_result = None  # the core's RenderResult of the last execution

    # === refractive index and medium colour tables =============================================
    def AddRefractiveIndexPoint(self, value, eta) -> None:
        """One row ``(value, eta)`` of the refractive-index table (checked at execution)."""
        self._eta_points.append((value, eta))
        self.Modified()

    def RemoveAllRefractiveIndexPoints(self) -> None:
        if self._eta_points:
            self._eta_points = []
            self.Modified()

    def GetRefractiveIndexPoints(self) -> list:
        return list(self._eta_points)

    def AddMediumColorPoint(self, value, r, g, b) -> None:
        """One row ``(value, r, g, b)`` of the medium-colour table (checked at execution)."""
        self._medium_points.append((value, r, g, b))
        self.Modified()

    def RemoveAllMediumColorPoints(self) -> None:
        if self._medium_points:
            self._medium_points = []
            self.Modified()

    def GetMediumColorPoints(self) -> list:
        return list(self._medium_points)

    def SetOptics(self, optics: RefractiveOptics | None) -> None:
        """Fill both tables from a :class:`RefractiveOptics` (``None``: empty, the defaults)."""
        if optics is not None and not isinstance(optics, RefractiveOptics):
            raise TypeError(f"SetOptics expects a RefractiveOptics or None, got "
                            f"{type(optics).__name__}")
        eta = [] if optics is None else [
            (float(x), float(v)) for x, v in zip(optics.eta_scalars, optics.eta)]
        medium = [] if optics is None else [
            (float(x), *(float(c) for c in rgb))
            for x, rgb in zip(optics.medium_scalars, optics.medium_color)]
        if eta != self._eta_points or medium != self._medium_points:
            self._eta_points, self._medium_points = eta, medium
            self.Modified()

    def GetOptics(self) -> RefractiveOptics:
        """The two tables as :class:`RefractiveOptics`; ``ValueError`` naming the property
        (``RefractiveIndex`` or ``MediumColor``) and the row when a row is wrong."""
        kw = {}
        rows = _table(self._eta_points, "RefractiveIndex", ("eta",))
        if rows is not None:
            for value, eta in rows:
                if not eta > 0:
                    raise ValueError(
                        f"RefractiveIndex: eta must be > 0 at every control point (1 is vacuum/"
                        f"air, 1.33 water, 1.5 glass); the point at value {value:g} has eta "
                        f"{eta:g}")
            kw["eta_scalars"], kw["eta"] = rows[:, 0], rows[:, 1]
        rows = _table(self._medium_points, "MediumColor", ("R", "G", "B"))
        if rows is not None:
            for value, *rgb in rows:
                if min(rgb) < 0 or max(rgb) > 1:
                    raise ValueError(
                        f"MediumColor: R G B must lie in [0, 1] (1 transmits a channel fully, "
                        f"0 absorbs it); the point at value {value:g} has "
                        f"{' '.join(f'{c:g}' for c in rgb)}")
            kw["medium_scalars"], kw["medium_color"] = rows[:, 0], rows[:, 1:]
        try:
            return RefractiveOptics(**kw)
        except ValueError as err:  # e.g. eta beyond the float32 range the kernels accept
            text = str(err)
            name = "MediumColor" if text.startswith("medium_color") else "RefractiveIndex"
            raise ValueError(f"{name}: {text.split(': ', 1)[-1]}") from None

    # === light ===================================================================================
    def SetLightDirection(self, x, y=None, z=None) -> None:
        d = _vector(x, y, z, "LightDirection")
        if not any(d):
            raise ValueError("LightDirection (the direction the light travels) must not be 0 0 0")
        self._set_light(d, self._lights[0].irradiance if self._lights else (1.0, 1.0, 1.0))

    def GetLightDirection(self) -> tuple:
        return tuple(float(v) for v in self._light().direction)

    def SetLightIrradiance(self, r, g=None, b=None) -> None:
        rgb = _vector(r, g, b, "LightIrradiance")
        if min(rgb) < 0:
            raise ValueError(f"LightIrradiance must not be negative, got {rgb}")
        self._set_light(self._lights[0].direction if self._lights else DEFAULT_LIGHT_DIRECTION,
                        rgb)

    def GetLightIrradiance(self) -> tuple:
        return tuple(float(v) for v in self._light().irradiance)

    def _light(self):
        return self._lights[0] if self._lights else DirectionalLight(DEFAULT_LIGHT_DIRECTION)

    def _set_light(self, direction, irradiance) -> None:
        self.SetLights([DirectionalLight(direction, irradiance)])

    # === image and camera =========================================================================
    def SetImageSize(self, width, height=None) -> None:
        size = width if height is None else (width, height)
        try:
            w, h = (float(v) for v in size)
            ok = all(v.is_integer() and 1 <= v <= MAX_IMAGE_SIZE for v in (w, h))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"ImageSize must be two whole numbers of pixels in 1 .. "
                             f"{MAX_IMAGE_SIZE} (width, height), got {size!r}")
        self.set_parameter("_image_size", (int(w), int(h)))

    def GetImageSize(self) -> tuple:
        return self._image_size

    def SetCameraPosition(self, x, y=None, z=None) -> None:
        self.set_parameter("_camera_position", _vector(x, y, z, "CameraPosition"))

    def GetCameraPosition(self) -> tuple:
        return self._camera_position

    def SetCameraFocalPoint(self, x, y=None, z=None) -> None:
        self.set_parameter("_camera_focal_point", _vector(x, y, z, "CameraFocalPoint"))

    def GetCameraFocalPoint(self) -> tuple:
        return self._camera_focal_point

    def SetCameraViewUp(self, x, y=None, z=None) -> None:
        up = _vector(x, y, z, "CameraViewUp")
        if not any(up):
            raise ValueError("CameraViewUp must not be 0 0 0")
        self.set_parameter("_camera_view_up", up)

    def GetCameraViewUp(self) -> tuple:
        return self._camera_view_up

    def SetCameraViewAngle(self, angle) -> None:
        angle = float(angle)
        if not 0.0 < angle < 180.0:
            raise ValueError(f"CameraViewAngle must lie in (0, 180) degrees, got {angle:g}")
        self.set_parameter("_camera_view_angle", angle)

    def GetCameraViewAngle(self) -> float:
        return self._camera_view_angle

    def SetCameraParallelProjection(self, on) -> None:
        self.set_parameter("_camera_parallel_projection", bool(on))

    def GetCameraParallelProjection(self) -> bool:
        return self._camera_parallel_projection

    def SetCameraParallelScale(self, scale) -> None:
        scale = float(scale)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"CameraParallelScale must be a positive number of world units, "
                             f"got {scale:g}")
        self.set_parameter("_camera_parallel_scale", scale)

    def GetCameraParallelScale(self) -> float:
        return self._camera_parallel_scale

    def SetPlaceFacingCamera(self, on) -> None:
        self.set_parameter("_place_facing_camera", bool(on))

    def GetPlaceFacingCamera(self) -> bool:
        return self._place_facing_camera

    def picture_geometry(self, bounds) -> tuple:
        """``(origin, spacing, direction)`` of the output image for an input of world
        ``bounds`` (``PlaceFacingCamera``; pixel units when off)."""
        if not self._place_facing_camera:
            return (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), np.eye(3)
        camera = Scene(camera=self.GetCamera()).resolved_camera(_Bounds(bounds))
        origin, spacing, direction = camera.image_plane(*self._image_size)
        return tuple(map(float, origin)), tuple(map(float, spacing)), direction

    def SetCamera(self, camera) -> None:
        """Copy a core :class:`~vtkillum.core.camera.Camera` or a ``vtkCamera``; ``None``:
        the automatic camera (position = focal point = 0 0 0)."""
        if camera is None:
            self.SetCameraPosition(0.0, 0.0, 0.0)
            self.SetCameraFocalPoint(0.0, 0.0, 0.0)
            return
        if hasattr(camera, "GetPosition"):  # vtkCamera
            camera = Camera(camera.GetPosition(), camera.GetFocalPoint(), camera.GetViewUp(),
                            camera.GetViewAngle(), bool(camera.GetParallelProjection()),
                            camera.GetParallelScale())
        if not isinstance(camera, Camera):
            raise TypeError(f"SetCamera expects a Camera, a vtkCamera or None, got "
                            f"{type(camera).__name__}")
        self.SetCameraPosition(*camera.position)
        self.SetCameraFocalPoint(*camera.focal_point)
        self.SetCameraViewUp(*camera.view_up)
        self.SetCameraViewAngle(camera.view_angle)
        self.SetCameraParallelProjection(camera.parallel_projection)
        self.SetCameraParallelScale(camera.parallel_scale)

    def GetCamera(self) -> Camera | None:
        """The camera as a core :class:`Camera`, ``None`` for the automatic one;
        ``ValueError`` naming the property when the values do not make a camera."""
        if np.array_equal(self._camera_position, self._camera_focal_point):
            return None
        try:
            return Camera(self._camera_position, self._camera_focal_point, self._camera_view_up,
                          self._camera_view_angle, self._camera_parallel_projection,
                          self._camera_parallel_scale)
        except ValueError as err:
            raise ValueError(_reword(str(err), _CAMERA_WORDS)) from None

    # === method options ============================================================================
    def SetSampleDistance(self, distance) -> None:
        self.set_parameter("_sample_distance", _positive(distance, "SampleDistance",
                                                         "a plane spacing in voxels"))

    def GetSampleDistance(self) -> float:
        return self._sample_distance

    def SetSoftness(self, softness) -> None:
        self.set_parameter("_softness", _non_negative(softness, "Softness"))

    def GetSoftness(self) -> float:
        return self._softness

    def SetDirectionBlur(self, blur) -> None:
        self.set_parameter("_direction_blur", _non_negative(blur, "DirectionBlur"))

    def GetDirectionBlur(self) -> float:
        return self._direction_blur

    def SetSpecular(self, weight) -> None:
        self.set_parameter("_specular", _non_negative(weight, "Specular"))

    def GetSpecular(self) -> float:
        return self._specular

    def SetRoughness(self, roughness) -> None:
        self.set_parameter("_roughness", _positive(roughness, "Roughness", "a Beckmann slope"))

    def GetRoughness(self) -> float:
        return self._roughness

    def SetIntensityCorrection(self, on) -> None:
        self.set_parameter("_intensity_correction", bool(on))

    def GetIntensityCorrection(self) -> bool:
        return self._intensity_correction

    def SetSeed(self, seed) -> None:
        seed = float(seed)
        if not (seed.is_integer() and 0 <= seed < 2**31):
            raise ValueError(f"Seed must be a whole number in [0, 2**31), got {seed:g}")
        self.set_parameter("_seed", int(seed))

    def GetSeed(self) -> int:
        return self._seed

    def SetBackground(self, r, g=None, b=None) -> None:
        rgb = _vector(r, g, b, "Background")
        if min(rgb) < 0:
            raise ValueError(f"Background must be three non-negative numbers, got {rgb}")
        self.set_parameter("_background", rgb)

    def GetBackground(self) -> tuple:
        return self._background

    def SetExposure(self, exposure) -> None:
        self.set_parameter("_exposure", _non_negative(exposure, "Exposure"))

    def GetExposure(self) -> float:
        return self._exposure

    def SetGamma(self, gamma) -> None:
        self.set_parameter("_gamma", _positive(gamma, "Gamma", "a display gamma"))

    def GetGamma(self) -> float:
        return self._gamma

    # === what the core gets =======================================================================
    def render_options(self) -> dict:
        """The keyword options of the ``refraction`` render method (optics included)."""
        return {"optics": self.GetOptics(), "sample_distance": self._sample_distance,
                "softness": self._softness, "direction_blur": self._direction_blur,
                "specular": self._specular, "roughness": self._roughness,
                "intensity_correction": self._intensity_correction, "seed": self._seed}

    # === pipeline =================================================================================
    def RequestInformation(self, request, inInfo, outInfo):
        in_info = inInfo[0].GetInformationObject(0)
        out_info = outInfo.GetInformationObject(0)
        try:
            self._last_error = None
            check_image_data(in_info.Get(vtkDataObject.DATA_OBJECT()))
            width, height = self._image_size
            origin, spacing, direction = self.picture_geometry(_input_bounds(in_info))
            out_info.Set(SDDP.WHOLE_EXTENT(), (0, width - 1, 0, height - 1, 0, 0), 6)
            out_info.Set(vtkDataObject.ORIGIN(), origin, 3)
            out_info.Set(vtkDataObject.SPACING(), spacing, 3)
            out_info.Set(vtkDataObject.DIRECTION(),
                         tuple(float(v) for v in np.asarray(direction).reshape(-1)), 9)
            for key in (SDDP.TIME_STEPS(), SDDP.TIME_RANGE()):
                if in_info.Has(key):
                    out_info.CopyEntry(in_info, key)
                else:
                    out_info.Remove(key)
            out_info.Remove(vtkDataObject.POINT_DATA_VECTOR())
            return 1
        except Exception as err:  # noqa: BLE001 - reported through VTK, see _report
            self._report(err)
            return 0

    def _execute(self, image, out_info) -> vtkImageData:
        from vtkillum.core.refraction.render import check_light
        from vtkillum.core.render import render  # canonical units: any length unit works
        from vtkillum.core.tonemap import auto_exposure, tonemap

        check_image_data(image)
        self.UpdateProgress(0.0)
        # Everything the user set is checked before the (longer) conversion and render.
        options = self.render_options()
        camera = self.GetCamera()
        name, association = self._selected_array(image)
        component = "magnitude" if self._input_component == -1 else self._input_component
        volume = volume_from_image_data(image, name, component, self._nan_policy, association)
        scene = Scene(transfer_function=self._transfer_function(volume),
                      opacity_unit_distance=self._unit_distance or volume.mean_spacing(),
                      albedo=self._albedo, anisotropy=self._anisotropy,
                      lights=list(self._lights), camera=camera, background=self._background)
        try:
            check_light(scene, scene.resolved_camera(volume))
        except ValueError as err:
            raise ValueError(f"LightDirection: {err}") from None
        width, height = self._image_size
        try:
            result = render(
                volume, scene, "refraction", width, height, device=self._resolved_device(),
                progress=lambda f: self.UpdateProgress(float(np.clip(f, 0.0, 1.0))), **options)
        except ValueError as err:
            raise ValueError(_reword(str(err), {f"refraction.{k}": v
                                                for k, v in _OPTION_WORDS.items()})) from None
        self.last_result = result
        exposure = self._exposure or auto_exposure(result.radiance)
        rgb = tonemap(result.radiance, exposure=exposure, gamma=self._gamma)

        output = vtkImageData()
        output.SetExtent(0, width - 1, 0, height - 1, 0, 0)
        origin, spacing, direction = self.picture_geometry(volume.bounds)
        output.SetOrigin(origin)
        output.SetSpacing(spacing)
        output.SetDirectionMatrix(*(float(v) for v in np.asarray(direction).reshape(-1)))

        def image_order(a):  # (H, W[, c]), row 0 at the top -> [i, j, 0(, c)], j = 0 at the bottom
            a = np.asarray(a)[::-1]
            return np.swapaxes(a, 0, 1)[:, :, None]

        add_point_array(output, RGB_ARRAY, image_order(rgb), set_active=True)
        add_point_array(output, RADIANCE_ARRAY, image_order(result.radiance))
        add_point_array(output, ALPHA_ARRAY, image_order(result.alpha))
        time = self._input_time(image, out_info)
        if time is not None:
            output.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(), time)
        return output


class _Bounds:
    """What ``Scene.resolved_camera`` reads of a volume: its world bounds."""

    def __init__(self, bounds) -> None:
        self.bounds = np.asarray(bounds, dtype=np.float64)


def _input_bounds(in_info) -> np.ndarray:
    """World bounds of the input image from its pipeline information (as ``Volume.bounds``)."""
    whole = in_info.Get(SDDP.WHOLE_EXTENT())
    spacing = np.asarray(in_info.Get(vtkDataObject.SPACING()) or (1.0, 1.0, 1.0))
    origin = np.asarray(in_info.Get(vtkDataObject.ORIGIN()) or (0.0, 0.0, 0.0))
    direction = (np.asarray(in_info.Get(vtkDataObject.DIRECTION())).reshape(3, 3)
                 if in_info.Has(vtkDataObject.DIRECTION()) else np.eye(3))
    lo = np.asarray(whole[0::2], dtype=np.float64)
    hi = np.asarray(whole[1::2], dtype=np.float64)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    world = (corners * spacing) @ direction.T + origin
    return np.stack([world.min(0), world.max(0)], 1).reshape(-1)


def _vector(x, y, z, name: str) -> tuple:
    values = x if y is None and z is None else (x, y, z)
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be three numbers, got {values!r}") from None
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be three finite numbers, got {values!r}")
    return out


def _positive(value, name: str, what: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be > 0 ({what}), got {value:g}")
    return value


def _non_negative(value, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a number >= 0, got {value:g}")
    return value


def _table(rows, name: str, columns) -> np.ndarray | None:
    """The rows of a control-point table sorted by value (``None`` when empty)."""
    if not rows:
        return None
    width = 1 + len(columns)
    try:
        table = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: every row must be {width} numbers (value, "
                         f"{', '.join(columns)})") from None
    if not np.all(np.isfinite(table)):
        raise ValueError(f"{name}: every entry must be a finite number")
    table = table[np.argsort(table[:, 0], kind="stable")]
    same = np.flatnonzero(np.diff(table[:, 0]) == 0)
    if same.size:
        raise ValueError(f"{name}: two control points at value {table[same[0], 0]:g}; give "
                         "each value once")
    return table


def _reword(text: str, words: dict) -> str:
    for old, new in words.items():
        text = text.replace(old, new)
    return text
