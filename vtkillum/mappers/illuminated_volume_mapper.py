"""OpenGL ray casting shaded by an illumination volume, inside any VTK render window.

:class:`IlluminatedVolume` is a ``vtkVolume`` (so ``renderer.AddVolume(v)`` and
pyvista's ``plotter.add_actor(v)`` take it) whose ``vtkOpenGLGPUVolumeRayCastMapper``
composites the same source term as the warp ray caster
(:func:`vtkillum.core.raycast.render_illuminated`, Zhang & Ma 2013 eq. 24)::

    per step Δ:   α = 1 - exp(-σt Δ)              (VTK's opacity-corrected table)
                  C += T α · albedo · color(s) · φ(x) / (4π) · S(x)
                  T *= 1 - α

which is ``T (1 - exp(-σt Δ)) / σt · σs φ / (4π) · S`` with
``σs = albedo · color · σt``: the σt of the exact step integral cancels. ``S`` is
the Phong factor of :mod:`vtkillum.core.illumination` (two-sided normal from
central differences one voxel apart, mean over the scene's lights, ``S = ka + kd``
where the gradient vanishes).

How the fluence reaches the shader
----------------------------------
The fluence rides along as three extra components of the mapper's input: a small
pipeline stage, :class:`ScalarFluenceImage`, stacks the rendered scalar and the RGB
fluence (trilinearly resampled onto the data grid when it has another resolution)
into one 4-component float image, and the volume property renders it with
independent components. VTK uploads, normalises and interpolates that texture
itself, re-uploads it whenever the pipeline re-executes (new data, a new time step,
an edited fluence, a new illumination source) and owns its OpenGL lifetime, so
the volume survives its window being closed and shown in a new one (like any
VTK GPU mapper it cannot be drawn by two live windows in turn). The
fragment shader's composite step (``//VTK::Shading::Impl``) is replaced through the
volume's ``vtkShaderProperty``; its parameters are custom uniforms.
(A separate ``vtkTextureObject`` bound in an ``UpdateShaderEvent`` observer also
works, but the observer gets no render window to create the texture in, and
VTK 9.7 does not fire the event on a window's first frame.)

Simplifications
---------------
* The input must be point data with one component (the core's convention);
  the data are not split into texture blocks (``vtkVolumeTexture`` partitions
  are not supported).
* The mapper's sampling follows VTK: samples start one step inside the volume's
  box (not on the entry face as in the warp caster), rays stop at alpha
  ``1 - 1/255``, opacity comes from VTK's 1D table of the corrected opacity.
* Memory: the combined image holds 4 float32 per voxel (16 bytes), on the CPU and
  on the GPU, whatever the fluence's own resolution.
* The fluence is resampled onto the data grid on the CPU when resolutions differ;
  the GPU then interpolates that, which equals trilinear interpolation of the
  coarse grid exactly where the fine points sit on coarse cell boundaries and
  closely elsewhere.
"""

from __future__ import annotations

import math

import numpy as np
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (OpenGL factory overrides)
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonCore import vtkOutputWindow
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkAlgorithm
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP
from vtkmodules.vtkRenderingCore import vtkVolume, vtkVolumeProperty
from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkOpenGLGPUVolumeRayCastMapper

from vtkillum.core.illumination import GRADIENT_EPS, IlluminationVolume, shading_terms
from vtkillum.core.lights import DIRECTIONAL, pack_lights
from vtkillum.core.resample import resample_points
from vtkillum.core.scene import Scene
from vtkillum.core.volume import Volume
from vtkillum.io.convert import (
    add_point_array,
    direction_matrix,
    first_point,
    point_array,
    volume_from_image_data,
)
from vtkillum.mappers.camera_bridge import GridSummary, apply_scene_to_volume_property
from vtkillum.mappers.inputs import connect_input, rendered_point_array

#: Name of the 4-component (scalar, fluence R, G, B) array handed to the mapper.
COMBINED_ARRAY = "vtkillum_scalar_fluence"

#: Name of the fluence array in illumination filter outputs.
FLUENCE_ARRAY = "fluence"

#: Lights the shader takes (each as kind, x, y, z in a float array uniform).
MAX_LIGHTS = 8

# --- GLSL ----------------------------------------------------------------------------------------
# Declarations: placed before the transfer-function helpers; the tag is kept for VTK's own code.
SHADER_DEC = """//VTK::Shading::Dec
// vtkillum: illumination-volume shading (vtkillum/mappers/illuminated_volume_mapper.py)
#define IL_MAX_LIGHTS %(max_lights)d
const float IL_GRADIENT_EPS = %(gradient_eps).9g;
vec3 il_voxel;                 // one voxel in texture coordinates
vec3 il_texToLocal;            // texture-coordinate offset -> local-frame length (dims * spacing)
vec3 il_view;                  // unit vector towards the camera (local frame)
vec3 il_light[IL_MAX_LIGHTS];  // directional: unit vector towards the light; point: position
int il_kind[IL_MAX_LIGHTS];

float il_scalar(vec3 tc)
{
  // Normalised data value (0..1 over the data range), as the transfer-function tables use.
  return texture3D(in_volume[0], tc).r * in_volume_scale[0].r + in_volume_bias[0].r;
}

// Phong factor S = ka + kd mean|n.l| + ks mean max(n.h, 0)^shininess (illumination.py).
float il_phong(vec3 tc)
{
  float ka = il_shading.x;
  float kd = il_shading.y;
  float ks = il_shading.z;
  if (kd == 0.0 && ks == 0.0)
  {
    return ka;
  }
  vec3 sp = in_cellSpacing[0];
  vec3 grad = vec3(
    il_scalar(tc + vec3(il_voxel.x, 0.0, 0.0)) - il_scalar(tc - vec3(il_voxel.x, 0.0, 0.0)),
    il_scalar(tc + vec3(0.0, il_voxel.y, 0.0)) - il_scalar(tc - vec3(0.0, il_voxel.y, 0.0)),
    il_scalar(tc + vec3(0.0, 0.0, il_voxel.z)) - il_scalar(tc - vec3(0.0, 0.0, il_voxel.z))
  ) / (2.0 * sp);
  float glen = length(grad);
  // Normalised units: the data range is 1, so the threshold is GRADIENT_EPS / min spacing.
  if (glen <= IL_GRADIENT_EPS / min(sp.x, min(sp.y, sp.z)))
  {
    return ka + kd;
  }
  vec3 n = grad / glen;
  if (dot(n, il_view) < 0.0)
  {
    n = -n;
  }
  vec3 p = (tc - in_texMin[0]) * il_texToLocal;
  float diff = 0.0;
  float spec = 0.0;
  for (int i = 0; i < il_numLights; ++i)
  {
    vec3 l = il_kind[i] == 0 ? il_light[i] : normalize(il_light[i] - p);
    diff += abs(dot(n, l));
    vec3 h = l + il_view;
    float hlen = length(h);
    if (hlen > 0.0)
    {
      spec += pow(max(dot(n, h / hlen), 0.0), il_shading.w);
    }
  }
  return ka + (kd * diff + ks * spec) / float(il_numLights);
}
"""

# Per ray, before the loop: frames and lights in the volume's local frame.
SHADER_INIT = """//VTK::Shading::Init
  // g_dataPos is a texel coordinate ((i + 0.5) / n at point i); the local frame spans
  // [0, (n - 1) spacing], so a texture offset d is a local offset d * n * spacing.
  il_voxel = (in_texMax[0] - in_texMin[0]) * in_cellStep[0];
  il_texToLocal = in_cellSpacing[0] / il_voxel;
  il_view = -normalize(g_dirStep * il_texToLocal);
  {
    mat4 il_worldToTex = in_cellToPoint[0] *
      inverse(in_volumeMatrix[0] * in_textureDatasetMatrix[0]);
    for (int i = 0; i < il_numLights; ++i)
    {
      vec3 v = vec3(il_lights[4 * i + 1], il_lights[4 * i + 2], il_lights[4 * i + 3]);
      il_kind[i] = int(il_lights[4 * i] + 0.5);
      if (il_kind[i] == 0)
      {
        // travel direction (world) -> unit vector towards the light (local)
        il_light[i] = -normalize((il_worldToTex * vec4(v, 0.0)).xyz * il_texToLocal);
      }
      else
      {
        il_light[i] = ((il_worldToTex * vec4(v, 1.0)).xyz - in_texMin[0]) * il_texToLocal;
      }
    }
  }
"""

# The composite step: replaces VTK's classification + front-to-back blending.
SHADER_IMPL = """
    if (!g_skip)
    {
      vec4 il_sample = texture3D(in_volume[0], g_dataPos) * in_volume_scale[0] +
        in_volume_bias[0];
      // Opacity-corrected for the sample distance by VTK: 1 - exp(-sigma_t * step).
      float il_alpha = computeOpacity(il_sample, 0);
      if (il_alpha > 0.0)
      {
        vec3 il_color = texture2D(in_colorTransferFunc_0[0], vec2(il_sample.r, 0.0)).rgb;
        vec3 il_phi = vec3(
          mix(in_scalarsRange[1].x, in_scalarsRange[1].y, il_sample.g),
          mix(in_scalarsRange[2].x, in_scalarsRange[2].y, il_sample.b),
          mix(in_scalarsRange[3].x, in_scalarsRange[3].y, il_sample.a));
        vec3 il_source = (il_sourceScale * il_phong(g_dataPos)) * il_color * il_phi;
        g_fragColor.rgb += (1.0 - g_fragColor.a) * il_alpha * il_source;
        g_fragColor.a += (1.0 - g_fragColor.a) * il_alpha;
      }
    }
"""


class IlluminatedVolume(vtkVolume):
    """A ``vtkVolume`` rendered with an illumination volume by VTK's GPU ray caster.

    Parameters
    ----------
    data : vtkImageData, vtkAlgorithmOutput, vtkAlgorithm or Volume
        The scalar field (also ``pyvista.ImageData``). Point data, one component.
        A pipeline connection keeps following its producer (new data, time steps).
    scene : Scene, optional
        Transfer function, opacity unit distance, albedo, lights (for the Phong
        directions and the default fluence), ``shading`` and step size (the mapper's
        sample distance). Default ``Scene()`` (its defaults resolved on ``data``).
    illumination : optional
        The fluence; see :meth:`set_illumination`.
    array_name : str, optional
        Point array to render; default the active scalars.
    exposure : float
        Factor on the radiance before it reaches the (8-bit, linear) frame buffer.

    Notes
    -----
    Radiance is written linearly (no gamma), premultiplied, over the renderer's
    background, like VTK's own ray caster; with ``exposure = 1`` a pixel's value is the
    radiance in the lights' irradiance units per steradian, clipped to [0, 1].
    The camera is VTK's; the scene's camera is not used.

    Examples
    --------
    >>> volume = IlluminatedVolume(image, scene, illumination=light_filter.GetOutputPort())
    >>> renderer.AddVolume(volume)            # or: plotter.add_actor(volume)
    """

    def __init__(self, data, scene: Scene | None = None, illumination=None,
                 array_name: str | None = None, exposure: float = 1.0) -> None:
        super().__init__()
        self.combiner = ScalarFluenceImage()
        self.combiner.SetArrayName(array_name)
        connect_input(self.combiner, 0, data, "data")
        # The scene's defaults need the data's range and spacing: bring the input up to date.
        self.combiner.GetInputAlgorithm(0, 0).Update(self.combiner.GetInputConnection(0, 0)
                                                    .GetIndex())
        self.mapper = vtkOpenGLGPUVolumeRayCastMapper()
        self.mapper.SetInputConnection(self.combiner.GetOutputPort())
        self.mapper.SetBlendModeToComposite()
        self.mapper.AutoAdjustSampleDistancesOff()
        self.mapper.SetUseJittering(0)
        self.SetMapper(self.mapper)
        prop = vtkVolumeProperty()
        prop.IndependentComponentsOn()
        self.SetProperty(prop)
        shader = self.GetShaderProperty()
        values = {"max_lights": MAX_LIGHTS, "gradient_eps": GRADIENT_EPS}
        shader.AddFragmentShaderReplacement("//VTK::Shading::Dec", True, SHADER_DEC % values,
                                            False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Init", True, SHADER_INIT, False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Impl", True, SHADER_IMPL, False)
        self._exposure = 1.0
        self._scene = None
        self.set_scene(scene if scene is not None else Scene())
        self.exposure = exposure
        self.set_illumination(illumination)

    # --- scene ----------------------------------------------------------------------------------
    @property
    def scene(self) -> Scene:
        """The scene last set (read-only: change it with :meth:`set_scene`)."""
        return self._scene

    def set_scene(self, scene: Scene) -> None:
        """Take transfer function, unit distance, albedo, lights, shading and step size.

        Data-dependent defaults (transfer-function ramp, unit distance = mean spacing,
        step = half the smallest spacing) are resolved on the current data.
        """
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a vtkillum Scene, got {type(scene).__name__}")
        shading = shading_terms(scene.shading)
        if len(scene.lights) > MAX_LIGHTS:
            raise ValueError(
                f"the OpenGL mapper takes at most {MAX_LIGHTS} lights, the scene has "
                f"{len(scene.lights)}; render with the compute path (ComputeVolumeRenderer)"
            )
        grid = self._grid_summary()
        apply_scene_to_volume_property(scene, grid, self.GetProperty(), component=0)
        self.mapper.SetSampleDistance(scene.resolved_step_size(grid))
        self._scene = scene
        self.combiner.SetLights(scene.lights)
        uniforms = self.GetShaderProperty().GetFragmentCustomUniforms()
        uniforms.SetUniform4f("il_shading", [float(v) for v in shading])
        kinds, vecs, _ = pack_lights(scene.lights)
        packed = np.zeros((MAX_LIGHTS, 4), dtype=np.float64)
        packed[: len(kinds), 0] = np.where(kinds == DIRECTIONAL, 0.0, 1.0)
        packed[: len(kinds), 1:] = vecs
        uniforms.SetUniformi("il_numLights", len(kinds))
        uniforms.SetUniform1fv("il_lights", 4 * MAX_LIGHTS, packed.reshape(-1).tolist())
        self._update_source_scale()
        self.Modified()

    @property
    def exposure(self) -> float:
        """Factor on the radiance written to the frame buffer (default 1)."""
        return self._exposure

    @exposure.setter
    def exposure(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"exposure must be a positive number, got {value}")
        self._exposure = value
        self._update_source_scale()

    def _update_source_scale(self) -> None:
        if self._scene is None:
            return
        scale = self._scene.albedo * self._exposure / (4.0 * math.pi)
        self.GetShaderProperty().GetFragmentCustomUniforms().SetUniformf("il_sourceScale", scale)
        self.Modified()

    # --- illumination ----------------------------------------------------------------------------
    def set_illumination(self, source) -> None:
        """Set where the fluence comes from.

        Parameters
        ----------
        source : IlluminationVolume, ndarray, vtkImageData, vtkAlgorithmOutput, vtkAlgorithm or None
            * :class:`~vtkillum.core.illumination.IlluminationVolume` (or an
              ``(nx, ny, nz, 3)`` array covering the data's box): used as is; call
              ``set_illumination`` again after editing it in place.
            * image data with a point array ``fluence`` (RGB, or grey with one
              component) covering the same box as the data at any resolution, or a
              pipeline connection producing it (e.g. an illumination filter's output
              port): followed through the pipeline, so new outputs, time steps and
              edits (``array.Modified()``) re-upload the texture on the next render.
            * ``None``: unshadowed light, ``φ = Σ E_l + Σ I_l / d_l²`` over the scene's lights.
        """
        self.combiner.SetIllumination(source)
        self.Modified()
        self.check()

    def set_time(self, time: float) -> None:
        """Render time step ``time``: requested from the data and the illumination pipelines.

        Later renders keep asking for that time; each new time re-executes the
        pipeline and re-uploads the texture, a time already shown does not.
        """
        self.combiner.UpdateTimeStep(float(time))
        self.Modified()
        self.check()

    def check(self) -> None:
        """Bring the combined input up to date and raise the error it met, if any.

        Errors inside the pipeline (a fluence grid that does not cover the data, a
        missing ``fluence`` array, ...) are otherwise only printed when VTK renders.
        """
        self.combiner.Update()
        if self.combiner.last_error is not None:
            raise self.combiner.last_error

    # --- helpers -------------------------------------------------------------------------------
    def _grid_summary(self) -> GridSummary:
        image = self.combiner.GetInputDataObject(0, 0)
        scalars = rendered_point_array(image, self.combiner.GetArrayName())
        return GridSummary(image, scalars)


class ScalarFluenceImage(VTKPythonAlgorithmBase):
    """Stack the rendered scalar and the RGB fluence into one 4-component image.

    Input port 0: the data (``vtkImageData``, point scalars or ``ArrayName``). Input
    port 1 (optional): image data with a point array ``fluence`` covering the same box,
    at any resolution. Without port 1 the fluence is the numpy illumination volume set
    with :meth:`SetIllumination`, or else the unshadowed fluence of the lights.

    The output has the data's geometry and one float32 point array
    :data:`COMBINED_ARRAY` ``(scalar, φr, φg, φb)`` as active scalars. Time requests
    reach both inputs; port 1 is always requested whole.
    """

    def __init__(self) -> None:
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=2, inputType="vtkImageData",
                                        nOutputPorts=1, outputType="vtkImageData")
        self._array_name = None
        self._illumination = None
        self._lights = []
        #: The error of the last RequestData, or None.
        self.last_error = None

    def FillInputPortInformation(self, port, info):
        info.Set(vtkAlgorithm.INPUT_REQUIRED_DATA_TYPE(), "vtkImageData")
        if port == 1:
            info.Set(vtkAlgorithm.INPUT_IS_OPTIONAL(), 1)
        return 1

    # --- properties ----------------------------------------------------------------------------
    def SetArrayName(self, name: str | None) -> None:
        if name != self._array_name:
            self._array_name = name
            self.Modified()

    def GetArrayName(self) -> str | None:
        return self._array_name

    def SetLights(self, lights) -> None:
        """Lights for the unshadowed default fluence (used only without an illumination)."""
        self._lights = list(lights)
        if self._illumination is None and self.GetNumberOfInputConnections(1) == 0:
            self.Modified()

    def SetIllumination(self, source) -> None:
        """An IlluminationVolume/array, image data, a pipeline connection, or None."""
        if source is None or isinstance(source, (IlluminationVolume, np.ndarray)):
            if isinstance(source, np.ndarray):
                source = _as_fluence_array(source)
            self.SetInputConnection(1, None)
            self._illumination = source
        else:
            connect_input(self, 1, source, "illumination")
            self._illumination = None
        self.Modified()

    # --- pipeline ----------------------------------------------------------------------------
    def RequestUpdateExtent(self, request, inInfo, outInfo):
        # The fluence grid has its own extent: always ask for all of it.
        if self.GetNumberOfInputConnections(1):
            info = inInfo[1].GetInformationObject(0)
            info.Set(SDDP.UPDATE_EXTENT(), info.Get(SDDP.WHOLE_EXTENT()), 6)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        # VTK swallows exceptions raised in a pipeline pass: keep the error for the caller
        # (IlluminatedVolume re-raises it) and report it on VTK's output window.
        self.last_error = None
        try:
            self._combine(inInfo, outInfo)
        except (TypeError, ValueError) as err:
            self.last_error = err
            vtkOutputWindow.GetInstance().DisplayErrorText(f"ScalarFluenceImage: {err}\n")
            return 0
        return 1

    def _combine(self, inInfo, outInfo) -> None:
        image = vtkImageData.GetData(inInfo[0])
        rendered_point_array(image, self._array_name)  # clear errors for missing/multi-component arrays
        volume = volume_from_image_data(image, self._array_name, association="points")
        if self.GetNumberOfInputConnections(1):
            fluence = _fluence_from_image(vtkImageData.GetData(inInfo[1]), volume, image)
        elif self._illumination is not None:
            il = self._illumination
            if isinstance(il, np.ndarray):
                il = IlluminationVolume.for_volume(volume, il)
            il.check_matches(volume)
            fluence = il.fluence(volume, self._lights)
        else:
            fluence = unshadowed_fluence(volume, self._lights)
        if fluence.shape[:3] != volume.dims:
            fluence = resample_points(fluence, volume.dims)
        combined = np.empty(volume.dims + (4,), dtype=np.float32)
        combined[..., 0] = volume.scalars
        combined[..., 1:] = fluence
        out = vtkImageData.GetData(outInfo)
        out.CopyStructure(image)
        add_point_array(out, COMBINED_ARRAY, combined, set_active=True)


def unshadowed_fluence(volume: Volume, lights) -> np.ndarray:
    """Fluence of the lights without any attenuation at the grid points, ``(nx, ny, nz, 3)``.

    Directional lights contribute their irradiance, point lights ``I / d²``
    (``d`` clamped to a tenth of the smallest spacing so a light on a grid point stays finite).
    """
    phi = np.zeros(volume.dims + (3,), dtype=np.float64)
    points = None
    for light in lights:
        if light.kind == DIRECTIONAL:
            phi += light.irradiance
            continue
        if points is None:
            idx = np.stack(np.meshgrid(*(np.arange(n) for n in volume.dims), indexing="ij"), -1)
            points = (idx * volume.spacing) @ volume.direction.T + volume.origin
        d2 = np.maximum(((points - light.position) ** 2).sum(-1), (0.1 * volume.spacing.min()) ** 2)
        phi += light.intensity / d2[..., None]
    return phi.astype(np.float32)


# --- module helpers -----------------------------------------------------------------------------
def _as_fluence_array(array: np.ndarray) -> np.ndarray:
    a = np.asarray(array, dtype=np.float32)
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"a fluence array must have shape (nx, ny, nz, 3), got {a.shape}")
    return a


def _fluence_from_image(fimage, volume: Volume, image) -> np.ndarray:
    """The ``fluence`` point array of ``fimage``, ``(nx, ny, nz, 3)``, checked against the data."""
    if fimage is None or fimage.GetNumberOfPoints() == 0:
        raise ValueError("the illumination input produced no image; check its pipeline")
    pd = fimage.GetPointData()
    array = pd.GetArray(FLUENCE_ARRAY)
    if array is None:
        names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
        raise ValueError(
            f"the illumination image has no point array {FLUENCE_ARRAY!r} (it has {names}); "
            "connect an illumination filter's output or name the RGB fluence array 'fluence'"
        )
    if array.GetNumberOfComponents() not in (1, 3):
        raise ValueError(f"the fluence array must have 1 (grey) or 3 (RGB) components, got "
                         f"{array.GetNumberOfComponents()}")
    # Same box: same direction, same first and last points (any resolution).
    dims = np.array(fimage.GetDimensions())
    spacing = np.array(fimage.GetSpacing(), dtype=np.float64)
    direction = direction_matrix(fimage)
    first = first_point(fimage.GetOrigin(), fimage.GetExtent(), spacing, direction)
    last = first + direction @ ((dims - 1) * spacing)
    data_last = volume.origin + volume.direction @ volume.extent
    tol = 1e-5 * float(np.linalg.norm(volume.extent)) + 1e-9
    if (min(dims) < 2 or not np.allclose(direction, volume.direction, atol=1e-6)
            or np.abs(first - volume.origin).max() > tol or np.abs(last - data_last).max() > tol):
        raise ValueError(
            f"the illumination image (first point {first.tolist()}, last {last.tolist()}) does "
            f"not cover the data's box (first {volume.origin.tolist()}, last "
            f"{data_last.tolist()}) with the same orientation; compute it from the same data"
        )
    values = point_array(fimage, FLUENCE_ARRAY)
    if values.ndim == 3:
        values = np.repeat(values[..., None], 3, axis=-1)
    values = np.asarray(values, dtype=np.float32)
    if not np.all(np.isfinite(values)) or values.min() < 0:
        raise ValueError("the fluence contains negative, NaN or Inf values")
    return values


__all__ = ["IlluminatedVolume", "ScalarFluenceImage", "unshadowed_fluence", "COMBINED_ARRAY"]
