"""Ambient volume scattering (Ament, Sadlo & Weiskopf 2013) in VTK's GPU ray caster.

:class:`AmbientScatteringVolume` is a ``vtkMultiVolume`` (so ``renderer.AddVolume(v)``
and pyvista's ``plotter.add_actor(v)`` take it) whose
``vtkOpenGLGPUVolumeRayCastMapper`` runs the ambient ray casting per pixel, the same
per-sample formulas as the warp gather (:mod:`vtkillum.core.ambient.gather`), for both of
its estimators: the centred one (default)::

    J̃ += T(x') (1 - exp(-σt Δ)) Λ color(x') ⊙ Σ_j [p(θ_j) T_j + M(θ_j, r σ̃t(x'), g)] L̃d,j(x_j)

with ``x_j = x' + min(r, d_j) (-ω_j)``, ``T_j`` the transmittance of the data from
``x_j`` to ``x'`` (a short shadow ray, midpoints of steps no longer than the sample
distance) and ``M`` the table's scattered part; and the paper's Algorithm 1
(``gather="paper"``)::

    J̃ += T(x_o) · Δ · Λ σt(x') color(x') ⊙ Σ_j L̃o(θ_j, r σ̃t(x'), g) L̃d,j(x' - r ω_j)

with ``T(x_o)`` the transmittance to the camera from the sphere's exit point
``x_o = x' + r ω``; plus the optional specular lobe and SAT ambient-occlusion terms.
Alpha is ``1 - T`` along the whole ray. The preprocessing runs in warp through an
:class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`, so each edit recomputes
only the stages it invalidates (the paper's Table 1): data or transfer function →
SAT, ``σ̃t`` and radiance cache; radius → ``σ̃t`` and radiance cache; ``g``, albedo
and lights → radiance cache; camera → nothing (only the GPU ray caster runs).

How the data reach the shader
-----------------------------
The mapper renders five inputs as one ``vtkMultiVolume``; each is a texture that VTK
uploads, re-uploads when its image is modified, and owns. All five images cover the
data's box (so the ray caster's bounding box is the data's), but the shader computes
every texture coordinate itself from the sample's position in the volume's local frame:

====  =====================================  ==========================================
port  image                                  contents
====  =====================================  ==========================================
0     ``n_θ × n_σ × 2``, 1 component         ``M(θ, r σ̃t)`` (centred) or ``L̃o`` (paper)
                                             at the scene's ``g`` (both slices equal),
                                             fetched texel by texel and interpolated
                                             bilinearly as the gather does
1     data grid, 1 component                 the rendered scalar (float32)
2     data grid, 1 component                 ambient extinction ``σ̃t`` (1/world units)
3     radiance-cache grid, 4 components      ``L̃d,j / rgb_j`` for lights j = 0..3
4     ``64 × m × 2``, 4 components           the warp kernels' 4096-entry colour and
                                             σt tables, interpolated as they do
====  =====================================  ==========================================

Port 0 is the output of :class:`AmbientScatteringInputs` (a pipeline stage that
follows its data input: new data, time steps, ``array.Modified()``); ports 1–4 are
images it keeps and refreshes only when their stage was recomputed, so a ``g`` edit
re-uploads the small radiance cache and table, not the data. With
:attr:`~AmbientScatteringVolume.device_upload` (default on) a recomputed ``σ̃t`` and
radiance cache do not go through the host at all: they are laid out as texels on the
cache's device (:func:`vtkillum.core.texels.pack_scalar`,
:func:`~vtkillum.core.texels.pack_grey`, bit for bit the host images) and written into the float textures VTK made for ports 2
and 3 (:mod:`vtkillum.mappers.texture_upload`); new data, another size and any failure
take the host path. The shader reads every texel as uploaded (all five are float32
textures), not through VTK's ``in_volume_scale`` / ``in_scalarsRange``, which normalise by
the range of the array a texture was made from and would keep an old grid's range for a
grid written later. The fragment shader's
composite step (``//VTK::Shading::Impl``), its set-up and its exit are replaced
through the volume's ``vtkShaderProperty``; parameters are custom uniforms. (A
``vtkTextureObject`` bound in an ``UpdateShaderEvent`` observer gets no render
window, and VTK 9.7 does not fire the event on a window's first frame, hence the
extra inputs.)

Why the radiance cache fits one texture
---------------------------------------
Tube marching multiplies grey factors (``σ̃t`` and the front transmittance are
wavelength independent) by the light's RGB irradiance at the cache point, so
``L̃d,j(x) = f_j(x) · rgb_j`` with ``rgb_j`` the light's irradiance (directional) or
intensity (point light, ``f_j`` then holds ``1/d²``). The cache of light ``j`` is
stored as the grey ``f_j`` in channel ``j``, and the shader multiplies by ``rgb_j``;
the decomposition is checked on every update.

Speed
-----
While an interactor moves the view, the mapper casts one ray per 2 × 2 pixels
(:attr:`AmbientScatteringVolume.interactive_image_sample_distance`,
:mod:`vtkillum.mappers.interaction`) with samples twice as far apart
(:attr:`~AmbientScatteringVolume.interactive_step`); at rest, and in the frame VTK's
interactor styles draw when a drag ends, every ray at the scene's step. On an NVIDIA H200
(EGL, ``benchmarks/bench_opengl.py --interactive --kinds ambient-scattering --sizes 512
--image 1024 --tf-edit --device-upload``) a camera move of the 512³ CT-like volume takes
365 ms at every pixel and 46 ms while dragging (119 ms before the coarser step); a TF edit
to the new frame 462 ms with ``device_upload``, 5.8 s through the host (``σ̃t`` and the
radiance cache downloaded, laid out and uploaded by VTK). That GPU runs OpenGL's fragment
shaders on a few of its
multiprocessors (VTK's own composite frame of the same data: 60 ms); the compute path
(``ComputeVolumeRenderer(..., method="ambient-scattering")``, pyvista's
``add_computed_volume``) moves the camera in 13.7 ms and edits the TF in 53 ms there.

Simplifications and limits
--------------------------
* At most :data:`MAX_LIGHTS` (4) lights, one channel of the cache texture each; more
  lights: use the compute path (``ComputeVolumeRenderer(..., method="ambient-scattering")``).
* Samples lie at ``t0 + k Δ`` from the box entry with no jitter (the gather with
  ``jitter=False``); the mapper's ``UseJittering`` is off. The ray stops once the
  shifted transmittance ``T(x_o)`` drops below ``1 - early_termination``, as in the
  gather (not at VTK's opacity threshold).
* The radiance cache and ``σ̃t`` are interpolated by the texture unit (trilinear,
  clamped to the box, as the gather does; GPUs may use 8-bit interpolation weights).
* Input: point data with one component (the core's convention), the data are not
  split into texture blocks, the volume's own transform (``SetPosition``,
  ``SetUserMatrix``) must stay the identity: place the data with the image's origin,
  spacing and direction. Cropping, clipping planes and depth peeling are not supported
  (``vtkMultiVolume`` restrictions).
* Memory: the data and ``σ̃t`` textures hold 4 bytes per voxel each (8 in all), the
  cache 16 bytes per cache point; the warp cache keeps its own copies on its device.
  ``device_upload`` adds, on that device, twice each texture it writes (texels and
  pixel buffer: 8 bytes per voxel and 32 per cache point).
* Texture units: 5 volumes plus VTK's colour and opacity tables of each (15) and the
  depth buffer; OpenGL implementations with fewer than 16 fragment texture units
  cannot draw it.
"""

from __future__ import annotations

import math

import numpy as np
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (OpenGL factory overrides)
from vtkmodules.util.numpy_support import numpy_to_vtk
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonCore import vtkCommand, vtkOutputWindow, vtkWeakReference
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkAlgorithm
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP
from vtkmodules.vtkRenderingCore import vtkVolume, vtkVolumeProperty
from vtkmodules.vtkRenderingVolume import vtkMultiVolume
from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkOpenGLGPUVolumeRayCastMapper

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.ambient.render import parse_options
from vtkillum.core.ambient.table import PreintegrationTable, load_table
from vtkillum.core.illumination import gradient_threshold
from vtkillum.core.lights import DIRECTIONAL, pack_lights, resolved_radius
from vtkillum.core.resample import scaled_shape
from vtkillum.core.scene import Scene
from vtkillum.io.convert import add_point_array, image_like, volume_from_image_data
from vtkillum.mappers.camera_bridge import GridSummary, apply_scene_to_volume_property
from vtkillum.mappers.inputs import connect_input, rendered_point_array
from vtkillum.mappers.interaction import (
    INTERACTIVE_IMAGE_SAMPLE_DISTANCE,
    INTERACTIVE_STEP,
    InteractiveSampling,
    interacting,
)
from vtkillum.mappers.texture_upload import R32F, RGBA32F, DeviceUpload, Job

#: Lights the OpenGL path takes (one channel of the radiance-cache texture each).
MAX_LIGHTS = 4

#: Ports of the mapper (= indices of ``in_volume[]`` in the shader).
TABLE_PORT, DATA_PORT, EXTINCTION_PORT, RADIANCE_PORT, OPTICS_PORT = range(5)

#: Entries per row of the optics image (the 4096-entry tables are stored as 64 × 64).
OPTICS_ROW = 64

#: Options taken from the scene's ``ambient_scattering`` section or as keywords.
OPTION_KEYS = ("radius", "radius_units", "radiance_cache_scale", "specular",
               "ambient_occlusion", "ambient_occlusion_strength", "early_termination",
               "step_size", "table", "gather")

# --- GLSL ----------------------------------------------------------------------------------------
# Values come back from VTK's normalised textures as mix(range.lo, range.hi, v * scale + bias),
# with in_scalarsRange indexed 4 * port + component.
SHADER_DEC = """//VTK::Shading::Dec
// vtkillum: ambient volume scattering (vtkillum/mappers/ambient_volume_mapper.py)
#define IL_MAX_LIGHTS %(max_lights)d
#define IL_PI 3.14159265358979
vec3 il_dir;        // unit ray direction (local frame)
vec3 il_cam;        // camera position (local frame)
float il_step;      // sample spacing (world units)
float il_trans;     // transmittance along the ray (alpha = 1 - il_trans)
float il_transOut;  // transmittance from the sphere's exit point x_o to the camera
vec3 il_radiance;   // gathered radiance

vec3 il_toLocal(vec3 w)
{
  vec3 q = w - il_origin;
  return vec3(dot(q, il_axis0), dot(q, il_axis1), dot(q, il_axis2));
}

vec3 il_dirToLocal(vec3 w)
{
  return vec3(dot(w, il_axis0), dot(w, il_axis1), dot(w, il_axis2));
}

// Texture coordinate of local position p on a point-centred grid of n points over
// [0, extent] (clamped to the box, like the warp samplers).
vec3 il_gridTex(vec3 p, vec3 n)
{
  return (clamp(p / il_extent, 0.0, 1.0) * (n - 1.0) + 0.5) / n;
}

// Every input is a float32 texture (R32F or RGBA32F): texels hold the values as uploaded,
// read as they are, not through VTK's in_volume_scale / in_volume_bias and
// in_scalarsRange, which normalise by the range of the array a texture was made from
// (so a grid written into the texture later, device_upload, reads back exactly).
float il_scalar(vec3 p)
{
  vec3 n = vec3(textureSize(in_volume[%(data)d], 0));
  return texture3D(in_volume[%(data)d], il_gridTex(p, n)).r;
}

float il_sigmaTilde(vec3 p)
{
  vec3 n = vec3(textureSize(in_volume[%(ext)d], 0));
  return texture3D(in_volume[%(ext)d], il_gridTex(p, n)).r;
}

vec4 il_cache(vec3 p)
{
  vec3 n = vec3(textureSize(in_volume[%(rad)d], 0));
  return texture3D(in_volume[%(rad)d], il_gridTex(p, n));
}

// Entry i of the colour (rgb) and sigma_t (a) tables.
vec4 il_opticsEntry(int i)
{
  int w = textureSize(in_volume[%(opt)d], 0).x;
  return texelFetch(in_volume[%(opt)d], ivec3(i %% w, i / w, 0), 0);
}

// Colour and sigma_t of data value s: linear between table entries (lookup_color/sigma_t).
vec4 il_optics(float s)
{
  float x = clamp((s - il_tableLo) * il_tableScale, 0.0, float(il_tableSize - 1));
  int i = min(int(x), il_tableSize - 2);
  return mix(il_opticsEntry(i), il_opticsEntry(i + 1), x - float(i));
}

float il_sigmaAt(vec3 p)
{
  if (any(lessThan(p, vec3(0.0))) || any(greaterThan(p, il_extent)))
  {
    return 0.0;
  }
  return il_optics(il_scalar(p)).a;
}

float il_tableEntry(int i, int j)
{
  return texelFetch(in_volume[%(table)d], ivec3(i, j, 0), 0).r;
}

// L~o(theta, r sigma~t) bilinearly, both axes clamped (gather.lookup_table).
float il_lobe(float cosTheta, float opticalRadius)
{
  ivec3 size = textureSize(in_volume[%(table)d], 0);
  int nt = size.x;
  int ns = size.y;
  float u = acos(clamp(cosTheta, -1.0, 1.0)) * (float(nt - 1) / IL_PI);
  float v = clamp(opticalRadius / il_sigmaMax * float(ns - 1), 0.0, float(ns - 1));
  int i = clamp(int(u), 0, nt - 2);
  int j = min(int(v), ns - 2);
  float fu = clamp(u - float(i), 0.0, 1.0);
  float fv = v - float(j);
  float a = mix(il_tableEntry(i, j), il_tableEntry(i + 1, j), fu);
  float b = mix(il_tableEntry(i, j + 1), il_tableEntry(i + 1, j + 1), fu);
  return mix(a, b, fv);
}

// Unit direction towards light j, its distance (1e30 for directional lights) and its RGB
// irradiance at p (light_incidence).
void il_incidence(int j, vec3 p, out vec3 toLight, out float dist, out vec3 irradiance)
{
  vec3 v = vec3(il_lights[4 * j + 1], il_lights[4 * j + 2], il_lights[4 * j + 3]);
  vec3 rgb = vec3(il_lightRGB[3 * j], il_lightRGB[3 * j + 1], il_lightRGB[3 * j + 2]);
  if (il_lights[4 * j] < 0.5)
  {
    toLight = -v;
    dist = 1.0e30;
    irradiance = rgb;
  }
  else
  {
    // Point lights are small spheres: I / max(d, r)^2 (vtkillum.core.lights).
    vec3 d = v - p;
    dist = max(length(d), 1.0e-20);
    toLight = d / dist;
    float r = max(dist, il_lightRadius[j]);
    irradiance = rgb / (r * r);
  }
}

// Henyey-Greenstein phase function, normalised to 1 over the sphere (warp_common.hg_phase).
float il_hg(float cosTheta)
{
  float denom = 1.0 + il_g * il_g - 2.0 * il_g * cosTheta;
  return (1.0 - il_g * il_g) / (4.0 * IL_PI * denom * sqrt(denom));
}

// Transmittance of the real medium from p along w over len: equal segments no longer than the
// sample spacing, each sampled at its midpoint (gather.segment_transmittance, xi = 0.5).
float il_segmentTransmittance(vec3 p, vec3 w, float len)
{
  if (len <= 0.0)
  {
    return 1.0;
  }
  int n = int(ceil(len / il_step));
  float h = len / float(n);
  float tau = 0.0;
  for (int q = 0; q < n; ++q)
  {
    tau += il_sigmaAt(p + (float(q) + 0.5) * h * w);
  }
  return exp(-tau * h);
}

// Central-difference gradient facing the viewer, or 0 where it vanishes (gather.view_normal).
vec3 il_normal(vec3 p)
{
  vec3 sp = il_spacing;
  vec3 grad = vec3(
    (il_scalar(p + vec3(sp.x, 0.0, 0.0)) - il_scalar(p - vec3(sp.x, 0.0, 0.0))) / (2.0 * sp.x),
    (il_scalar(p + vec3(0.0, sp.y, 0.0)) - il_scalar(p - vec3(0.0, sp.y, 0.0))) / (2.0 * sp.y),
    (il_scalar(p + vec3(0.0, 0.0, sp.z)) - il_scalar(p - vec3(0.0, 0.0, sp.z))) / (2.0 * sp.z));
  float glen = length(grad);
  if (glen <= il_gradEps)
  {
    return vec3(0.0);
  }
  vec3 n = grad / glen;
  return dot(n, il_dir) > 0.0 ? -n : n;
}
"""

# Per ray: frames, first sample on the entry face (VTK starts one step inside), accumulators.
SHADER_INIT = """//VTK::Shading::Init
  {
    if (il_stepScale != 1.0)  // coarser samples while an interactor moves the view
    {
      g_dirStep *= il_stepScale;
      g_lengthStep *= il_stepScale;
      g_terminatePointMax /= il_stepScale;
    }
    mat4 il_texToWorld = in_volumeMatrix[0] * in_textureDatasetMatrix[0];
    vec3 il_stepWorld = (il_texToWorld * vec4(g_dirStep, 0.0)).xyz;
    il_step = length(il_stepWorld);
    il_dir = il_dirToLocal(il_stepWorld / il_step);
    il_cam = il_toLocal((in_inverseModelViewMatrix * vec4(0.0, 0.0, 0.0, 1.0)).xyz);
    g_dataPos -= g_rayJitter;
    il_trans = 1.0;
    il_transOut = 1.0;
    il_radiance = vec3(0.0);
  }
"""

# One sample of Algorithm 1 (gather.ambient_gather_kernel). g_fragColor stays 0 inside the
# loop so that VTK's opacity-based termination never fires; the ray stops on T(x_o) instead.
SHADER_IMPL = """
    if (!g_skip)
    {
      vec3 il_p = il_toLocal((in_volumeMatrix[0] * in_textureDatasetMatrix[0] *
        vec4(g_dataPos, 1.0)).xyz);
      vec4 il_opt = il_optics(il_scalar(il_p));
      float il_sig = il_opt.a;
      if (il_sig > 0.0)
      {
        float il_tau = il_radius * il_sigmaTilde(il_p);
        vec3 il_n = il_specular > 0.0 ? il_normal(il_p) : vec3(0.0);
        vec3 il_light = vec3(0.0);
        vec3 il_eSum = vec3(0.0);
        for (int j = 0; j < il_numLights; ++j)
        {
          vec3 il_to;
          float il_dist;
          vec3 il_e;
          il_incidence(j, il_p, il_to, il_dist, il_e);
          // cos(theta_j) = omega . omega_j, omega = -dir towards the camera, omega_j = -il_to
          float il_cos = dot(il_dir, il_to);
          float il_l = il_lobe(il_cos, il_tau);  // M (centred) or L~o (paper)
          float il_spec = 0.0;
          if (il_specular > 0.0 && dot(il_n, il_n) > 0.0)
          {
            vec3 il_h = normalize(il_to - il_dir);
            il_spec = il_specular * pow(max(dot(il_n, il_h), 0.0), il_shininess) / (4.0 * IL_PI);
          }
          vec3 il_rgb = vec3(il_lightRGB[3 * j], il_lightRGB[3 * j + 1], il_lightRGB[3 * j + 2]);
          if (il_centred != 0)
          {
            // x_j = x' + r omega_l (not past a point light); the unscattered part reaches x'
            // through the real medium
            float il_seg = min(il_radius, il_dist);
            float il_f = il_cache(il_p + il_seg * il_to)[j];
            float il_direct = il_segmentTransmittance(il_p, il_to, il_seg);
            il_light += (((il_hg(il_cos) + il_spec) * il_direct + il_l) * il_f) * il_rgb;
          }
          else
          {
            // distributed light at x_j = x' - r omega_j, the point where light j enters the sphere
            float il_f = il_cache(il_p + il_radius * il_to)[j];
            il_light += ((il_l + il_spec) * il_f) * il_rgb;
          }
          il_eSum += il_e;
        }
        if (il_ambientOcclusion > 0.0)
        {
          il_light += (il_ambientOcclusion * exp(-il_tau) / (4.0 * IL_PI)) * il_eSum;
        }
        if (il_centred != 0)
        {
          il_radiance += (il_trans * (1.0 - exp(-il_sig * il_step)) * il_albedo) * il_opt.rgb *
            il_light;
        }
        else
        {
          il_radiance += (il_transOut * il_step * il_albedo * il_sig) * il_opt.rgb * il_light;
        }
      }
      il_trans *= exp(-il_sig * il_step);
      if (il_centred != 0)
      {
        if (il_trans < il_stopTransmittance)
        {
          g_exit = true;
        }
      }
      else
      {
        if (dot(il_p - il_cam, il_dir) - il_radius > 0.0)
        {
          il_transOut *= exp(-il_sigmaAt(il_p - il_radius * il_dir) * il_step);
        }
        if (il_transOut < il_stopTransmittance)
        {
          g_exit = true;
        }
      }
    }
"""

# After the loop: premultiplied radiance and alpha = 1 - T.
SHADER_EXIT = """//VTK::Shading::Exit
  g_fragColor = vec4(il_exposure * il_radiance, 1.0 - il_trans);
"""


class AmbientScatteringVolume(InteractiveSampling, DeviceUpload, vtkMultiVolume):
    """A ``vtkMultiVolume`` rendered with ambient volume scattering by VTK's GPU ray caster.

    Parameters
    ----------
    data : vtkImageData, vtkAlgorithmOutput, vtkAlgorithm or Volume
        The scalar field (also ``pyvista.ImageData``). Point data, one component. A
        pipeline connection keeps following its producer (new data, time steps).
    scene : Scene, optional
        Transfer function, opacity unit distance, albedo ``Λ``, anisotropy ``g``, lights
        (at most :data:`MAX_LIGHTS`), ``shading.shininess`` (specular exponent), step
        size (the mapper's sample distance) and the ``ambient_scattering`` section.
        Default ``Scene()`` (its defaults resolved on ``data``).
    array_name : str, optional
        Point array to render; default the active scalars.
    exposure : float
        Factor on the radiance before it reaches the (8-bit, linear) frame buffer.
    device : str, optional
        Warp device of the preprocessing (SAT, ``σ̃t``, tube marching).
    cache : AmbientScatteringCache, optional
        Cache to use (on ``device``); default a new one.
    interactive_image_sample_distance : float
        Pixels per ray along x and y while an interactor moves the view (default
        :data:`~vtkillum.mappers.interaction.INTERACTIVE_IMAGE_SAMPLE_DISTANCE`; 1: every
        pixel); see :attr:`interactive_image_sample_distance`.
    interactive_step : float
        Sample-distance factor while an interactor moves the view (default
        :data:`~vtkillum.mappers.interaction.INTERACTIVE_STEP`; 1: the scene's step).
    device_upload : bool
        Write ``σ̃t`` and the radiance cache, recomputed on the warp device, straight into
        VTK's textures (default True; see :attr:`device_upload`).
    **options
        Override the scene's ``ambient_scattering`` section: ``radius``,
        ``radius_units``, ``radiance_cache_scale``, ``specular``, ``ambient_occlusion``,
        ``ambient_occlusion_strength``, ``gather``; and ``early_termination`` (0.999),
        ``step_size`` (world units) and ``table`` (a
        :class:`~vtkillum.core.ambient.table.PreintegrationTable`), as for
        ``render(..., method="ambient-scattering")``.

    Notes
    -----
    Radiance is written linearly (no gamma), premultiplied, over the renderer's
    background; with ``exposure = 1`` a pixel's value is the radiance in the lights'
    irradiance units per steradian, clipped to [0, 1]. The camera is VTK's. Edits go
    through :meth:`set_scene` / :meth:`set_options`; the next render recomputes what
    they invalidate (:attr:`state` says what and how long).

    Examples
    --------
    >>> volume = AmbientScatteringVolume(image, scene, radius=4)
    >>> renderer.AddVolume(volume)            # or: plotter.add_actor(volume)
    """

    def __init__(self, data, scene: Scene | None = None, array_name: str | None = None,
                 exposure: float = 1.0, device: str | None = None,
                 cache: AmbientScatteringCache | None = None,
                 interactive_image_sample_distance: float = INTERACTIVE_IMAGE_SAMPLE_DISTANCE,
                 interactive_step: float = INTERACTIVE_STEP, device_upload: bool = True,
                 **options) -> None:
        super().__init__()
        self.inputs = AmbientScatteringInputs(device=device, cache=cache)
        self.inputs.SetArrayName(array_name)
        connect_input(self.inputs, 0, data, "data")
        # The scene's defaults need the data's range and spacing: bring the input up to date.
        self.inputs.GetInputAlgorithm(0, 0).Update(self.inputs.GetInputConnection(0, 0)
                                                  .GetIndex())
        self.mapper = vtkOpenGLGPUVolumeRayCastMapper()
        self.mapper.SetBlendModeToComposite()
        self.mapper.AutoAdjustSampleDistancesOff()
        self.mapper.SetUseJittering(0)
        # Port 0 first: its update refreshes the images of ports 1-4 in the same render.
        self.mapper.SetInputConnection(TABLE_PORT, self.inputs.GetOutputPort())
        for port, image in ((DATA_PORT, self.inputs.data_image),
                            (EXTINCTION_PORT, self.inputs.extinction_image),
                            (RADIANCE_PORT, self.inputs.radiance_image),
                            (OPTICS_PORT, self.inputs.optics_image)):
            self.mapper.SetInputDataObject(port, image)
        self.SetMapper(self.mapper)
        self.volumes = []
        for port in range(5):
            volume = vtkVolume()
            prop = vtkVolumeProperty()
            # vtkMultiVolume takes 1-component inputs as independent, 4-component as not.
            prop.SetIndependentComponents(port not in (RADIANCE_PORT, OPTICS_PORT))
            prop.SetInterpolationTypeToLinear()
            prop.ShadeOff()
            volume.SetProperty(prop)
            self.SetVolume(volume, port)
            self.volumes.append(volume)
        shader = self.GetShaderProperty()
        values = {"max_lights": MAX_LIGHTS, "table": TABLE_PORT, "data": DATA_PORT,
                  "ext": EXTINCTION_PORT, "rad": RADIANCE_PORT, "opt": OPTICS_PORT}
        shader.AddFragmentShaderReplacement("//VTK::Shading::Dec", True, SHADER_DEC % values,
                                            False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Init", True, SHADER_INIT, False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Impl", True, SHADER_IMPL, False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Exit", True, SHADER_EXIT, False)
        self.inputs.uniforms = shader.GetFragmentCustomUniforms()
        self.interactive_image_sample_distance = interactive_image_sample_distance
        self.interactive_step = interactive_step
        self.inputs.uniforms.SetUniformf("il_stepScale", 1.0)  # declared from the start
        # Each render: every pixel at rest, fewer rays while an interactor moves the view
        # (a weak reference: the mapper must not keep its volume alive).
        weak = vtkWeakReference()
        weak.Set(self)
        self.mapper.AddObserver(vtkCommand.VolumeMapperRenderStartEvent,
                                lambda caller, event: _sample_image(weak.Get()))
        self._exposure = 1.0
        self.exposure = exposure
        self.device_upload = device_upload
        self._options = {}
        self._scene = None
        self.set_options(**options)
        self.set_scene(scene if scene is not None else Scene())

    # --- scene and options ---------------------------------------------------------------------
    @property
    def scene(self) -> Scene:
        """The scene last set (read-only: change it with :meth:`set_scene`)."""
        return self._scene

    def set_scene(self, scene: Scene) -> None:
        """Take the optical model, lights, ``g``, albedo, step size and ambient options.

        The next render recomputes what the change invalidates (Table 1 of the paper).
        """
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a vtkillum Scene, got {type(scene).__name__}")
        if len(scene.lights) > MAX_LIGHTS:
            raise ValueError(
                f"the OpenGL ambient-scattering path takes at most {MAX_LIGHTS} lights, the "
                f"scene has {len(scene.lights)}; render with the compute path "
                "(ComputeVolumeRenderer(..., method='ambient-scattering'))")
        grid = self._grid_summary()
        opts = parse_options(self._options, grid, scene)
        apply_scene_to_volume_property(scene, grid, self.volumes[DATA_PORT].GetProperty())
        self.mapper.SetSampleDistance(opts["step_size"])
        self._scene = scene
        self.inputs.set_parameters(scene, self._options)
        self.Modified()
        self.check()

    def set_options(self, **options) -> None:
        """Override ambient options (see the class docstring); ``None`` restores the scene's."""
        unknown = set(options) - set(OPTION_KEYS)
        if unknown:
            raise ValueError(f"unknown ambient-scattering option(s) {sorted(unknown)}; "
                             f"known: {sorted(OPTION_KEYS)}")
        if "table" in options and options["table"] is not None and not isinstance(
                options["table"], PreintegrationTable):
            raise TypeError("table must be a PreintegrationTable (vtkillum.core.ambient.table)")
        merged = dict(self._options)
        merged.update(options)
        merged = {k: v for k, v in merged.items() if v is not None}
        if self._scene is not None:
            old = self._options
            self._options = merged
            try:
                self.set_scene(self._scene)
            except Exception:
                self._options = old
                raise
        else:
            self._options = merged

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
        self.GetShaderProperty().GetFragmentCustomUniforms().SetUniformf("il_exposure", value)
        self.Modified()

    # --- pipeline ---------------------------------------------------------------------------------
    @property
    def cache(self) -> AmbientScatteringCache:
        """The warp cache (``cache.stats`` counts how often each stage ran)."""
        return self.inputs.cache

    @property
    def state(self):
        """The :class:`~vtkillum.core.ambient.cache.AmbientState` of the last update."""
        return self.inputs.state

    def set_time(self, time: float) -> None:
        """Render time step ``time`` of the data pipeline."""
        self.inputs.UpdateTimeStep(float(time))
        self.Modified()
        self.check()

    def check(self) -> None:
        """Bring the inputs up to date and raise the error met there, if any.

        Errors inside the pipeline are otherwise only printed when VTK renders.
        """
        self.inputs.Update()
        if self.inputs.last_error is not None:
            raise self.inputs.last_error

    def _grid_summary(self) -> GridSummary:
        image = self.inputs.GetInputDataObject(0, 0)
        return GridSummary(image, rendered_point_array(image, self.inputs.GetArrayName()))


def _sample_image(volume) -> None:
    """The image sample distance and step of this frame (read as the mapper renders)."""
    if volume is not None:
        volume.sample_for(interacting(volume), volume.inputs.uniforms)


class AmbientScatteringInputs(VTKPythonAlgorithmBase):
    """Run the ambient-scattering preprocessing and lay its results out as textures.

    Input port 0: the data (``vtkImageData``, point scalars or ``ArrayName``). Output
    port 0: the preintegration table at the scene's ``g`` (``n_θ × n_σ × 2`` points, one
    float32 component, stretched over the data's box). The other textures are images
    kept as attributes and refreshed only when their stage was recomputed:
    :attr:`data_image` (the scalar as float32), :attr:`extinction_image` (``σ̃t``),
    :attr:`radiance_image` (grey radiance cache per light, 4 components) and
    :attr:`optics_image` (colour and σt tables, 4 components). The shader uniforms that
    depend on the data's geometry are written to :attr:`uniforms` (a ``vtkUniforms``).

    Parameters
    ----------
    device : str, optional
        Warp device of the cache.
    cache : AmbientScatteringCache, optional
        Default: a new cache on ``device``.
    """

    def __init__(self, device: str | None = None,
                 cache: AmbientScatteringCache | None = None) -> None:
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=1, inputType="vtkImageData",
                                        nOutputPorts=1, outputType="vtkImageData")
        if cache is None:
            cache = AmbientScatteringCache(device, data_textures=False)  # OpenGL gathers
        elif not isinstance(cache, AmbientScatteringCache):
            raise TypeError("cache must be an AmbientScatteringCache")
        self.cache = cache
        self.data_image = vtkImageData()
        self.extinction_image = vtkImageData()
        self.radiance_image = vtkImageData()
        self.optics_image = vtkImageData()
        for image in (self.data_image, self.extinction_image, self.radiance_image,
                      self.optics_image):
            _empty_start_image(image)
        #: vtkUniforms receiving the geometry-dependent parameters (set by the volume).
        self.uniforms = None
        #: AmbientState of the last update.
        self.state = None
        #: The error of the last RequestData, or None.
        self.last_error = None
        #: TextureWriter of σ̃t and the radiance cache (None: through the host; see
        #: AmbientScatteringVolume.device_upload).
        self.writer = None
        self._refill = False  # fill the side images on the host at the next update
        self._last = None     # (volume, lights, cache shape) of the last update
        self._array_name = None
        self._scene = None
        self._options = {}
        self._input_key = None
        self._volume = None

    def FillInputPortInformation(self, port, info):
        info.Set(vtkAlgorithm.INPUT_REQUIRED_DATA_TYPE(), "vtkImageData")
        return 1

    def SetArrayName(self, name: str | None) -> None:
        if name != self._array_name:
            self._array_name = name
            self._input_key = None
            self.Modified()

    def GetArrayName(self) -> str | None:
        return self._array_name

    def set_parameters(self, scene: Scene, options: dict) -> None:
        """The scene and option overrides of the next update."""
        self._scene = scene
        self._options = dict(options)
        self.Modified()

    # --- pipeline ----------------------------------------------------------------------------
    def RequestInformation(self, request, inInfo, outInfo):
        table = self._table()
        info = outInfo.GetInformationObject(0)
        n_theta, n_sigma = table.shape[:2]
        info.Set(SDDP.WHOLE_EXTENT(), (0, n_theta - 1, 0, n_sigma - 1, 0, 1), 6)
        return 1

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        # The output grid is not the input's: always ask for the whole input.
        info = inInfo[0].GetInformationObject(0)
        info.Set(SDDP.UPDATE_EXTENT(), info.Get(SDDP.WHOLE_EXTENT()), 6)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        # VTK swallows exceptions raised in a pipeline pass: keep the error for the caller
        # (AmbientScatteringVolume.check re-raises it) and report it on VTK's output window.
        self.last_error = None
        try:
            self._update(vtkImageData.GetData(inInfo[0]), vtkImageData.GetData(outInfo))
        except (TypeError, ValueError, RuntimeError) as err:
            self.last_error = err
            vtkOutputWindow.GetInstance().DisplayErrorText(f"AmbientScatteringInputs: {err}\n")
            return 0
        return 1

    def _table(self) -> PreintegrationTable:
        table = self._options.get("table")
        if table is None:
            albedo = self._scene.albedo if self._scene is not None else 0.9
            table = load_table(albedo, device=self.cache.device)
        return table

    def _update(self, image, out) -> None:
        if self._scene is None:
            raise ValueError("no scene set")
        array = rendered_point_array(image, self._array_name)
        key = (image.GetAddressAsString("vtkImageData"), image.GetMTime(), array.GetMTime(),
               array.GetName())
        refresh_data = key != self._input_key
        if refresh_data:
            # An unchanged input keeps its Volume, so the cache recognises it without hashing.
            self._volume = volume_from_image_data(image, self._array_name, association="points")
            if min(self._volume.dims) < 2:
                raise ValueError(f"the data must have at least 2 points along every axis, got "
                                 f"{self._volume.dims}")
            self._input_key = key
        volume = self._volume
        scene = self._scene
        opts = parse_options(dict(self._options), volume, scene)
        table = self._table()
        lights = list(scene.lights)
        if len(lights) > MAX_LIGHTS:
            raise ValueError(f"at most {MAX_LIGHTS} lights, got {len(lights)}")
        cache_shape = scaled_shape(volume.dims, opts["radiance_cache_scale"])
        tf = scene.resolved_transfer_function(volume)
        state = self.cache.update(volume, tf, scene.resolved_unit_distance(volume),
                                  scene.albedo, scene.anisotropy, lights, opts["radius"],
                                  opts["radius_units"], opts["radiance_cache_scale"], table,
                                  cache_shape)
        self.state = state
        recomputed = set(state.recomputed)

        # Table slice at g: the pipeline output (re-made on every execution, it is small).
        table_slice = state.scattered_slice if opts["gather"] == "centred" else state.table_slice
        slice_ = np.asarray(table_slice.numpy(), dtype=np.float32)
        out.ShallowCopy(_stretched_image(volume, slice_.shape + (2,)))
        add_point_array(out, "ambient_table", np.repeat(slice_[:, :, None], 2, axis=2),
                        set_active=True)

        # Side images: refreshed when their stage ran; a new input (data, geometry) refreshes
        # all. σ̃t and the radiance cache go straight into VTK's textures where they can
        # (device_upload), else through the host.
        if refresh_data:
            _set_image(self.data_image, image_like(volume), "scalars", volume.scalars)
        self._last = (volume, lights, cache_shape)
        refill, self._refill = refresh_data or self._refill, False
        ports = set()
        if refill or recomputed & {"sat", "extinction"}:
            ports.add(EXTINCTION_PORT)
        if refill or "radiance" in recomputed:
            ports.add(RADIANCE_PORT)
        if ports and (refill or not self._write_on_device(ports, state, volume, lights,
                                                          cache_shape)):
            if self.writer is not None:
                ports |= set(self.writer.pending)  # writes not made yet: the host's now
                self.writer.forget()  # the images (the host path) hold the grids again
            self._set_host_images(ports, state, volume, lights, cache_shape)
        if refresh_data or "sat" in recomputed:  # the transfer function's tables were rebuilt
            medium = state.medium
            optics = optics_rows(medium.color_table.numpy(), medium.sigma_table.numpy())
            _set_image(self.optics_image, _stretched_image(volume, optics.shape[:3]), "optics",
                       optics)
        self._set_uniforms(volume, scene, opts, state, table, lights)

    def _set_host_images(self, ports, state, volume, lights, cache_shape) -> None:
        """Fill the images of ``ports`` (extinction, radiance) from ``state`` on the host;
        VTK uploads them."""
        if EXTINCTION_PORT in ports:
            _set_image(self.extinction_image, image_like(volume), "sigma_tilde",
                       state.sigma_tilde.numpy())
        if RADIANCE_PORT in ports:
            grey = grey_radiance(state.radiance.numpy(), lights, volume)
            _set_image(self.radiance_image, image_like(volume, shape=cache_shape),
                       "radiance_grey", grey)

    def _write_on_device(self, ports, state, volume, lights, cache_shape) -> bool:
        """Schedule ``ports``' grids for :attr:`writer` (straight from the cache's device
        into VTK's textures); False where the host path must draw them all (no writer,
        a cache of half-precision textures, no lights, textures of another size or not
        made yet)."""
        from functools import partial

        from vtkillum.core import texels

        writer = self.writer
        if writer is None or writer.host_stale:
            return False
        jobs = {}
        device = str(state.sigma_tilde.device)
        if EXTINCTION_PORT in ports:
            jobs[EXTINCTION_PORT] = Job(tuple(int(n) for n in volume.dims), device,
                                        partial(texels.pack_scalar, state.sigma_tilde))
        if RADIANCE_PORT in ports:
            radiance = state.radiance
            data = None if radiance is None or radiance.texture is not None \
                else radiance.grid.data
            if data is None or not lights or str(data.device) != device:
                return False
            _, _, rgb = pack_lights(lights, volume.direction, volume.origin)
            texels.check_grey(data, rgb)  # an error now, from check(), not in the render
            jobs[RADIANCE_PORT] = Job(tuple(int(n) for n in cache_shape), device,
                                      partial(texels.pack_grey, data, rgb))
        if not all(writer.can_write(port, job.size) for port, job in jobs.items()):
            return False
        for port, job in jobs.items():
            writer.schedule(port, job)
        return True

    def writer_images(self) -> tuple[dict, dict]:
        """The images :attr:`writer` may write (``port -> image``) and their formats."""
        return ({EXTINCTION_PORT: self.extinction_image, RADIANCE_PORT: self.radiance_image},
                {EXTINCTION_PORT: R32F, RADIANCE_PORT: RGBA32F})

    def refill_host(self) -> None:
        """Fill σ̃t and the radiance cache into their images again at the next update."""
        self._refill = True

    def _host_fallback(self, ports) -> None:
        """A scheduled texture write failed (at the render's start): fill those images on
        the host, in time for VTK to upload them in this render."""
        if self.state is not None and self._last is not None:
            self._set_host_images(set(ports), self.state, *self._last)

    def _set_uniforms(self, volume, scene, opts, state, table, lights) -> None:
        u = self.uniforms
        if u is None:
            return
        medium = state.medium
        axes = np.asarray(volume.direction, dtype=np.float64)
        u.SetUniform3f("il_origin", [float(v) for v in volume.origin])
        for k in range(3):
            u.SetUniform3f(f"il_axis{k}", [float(v) for v in axes[:, k]])
        u.SetUniform3f("il_extent", [float(v) for v in volume.extent])
        u.SetUniform3f("il_spacing", [float(v) for v in volume.spacing])
        u.SetUniformf("il_radius", float(state.radius))
        u.SetUniformf("il_sigmaMax", float(table.sigma_max))
        u.SetUniformf("il_albedo", float(scene.albedo))
        u.SetUniformf("il_g", float(scene.anisotropy))
        u.SetUniformi("il_centred", int(opts["gather"] == "centred"))
        u.SetUniformf("il_tableLo", float(medium.table_lo))
        u.SetUniformf("il_tableScale", float(medium.table_scale))
        u.SetUniformi("il_tableSize", int(medium.sigma_table.shape[0]))
        u.SetUniformf("il_stopTransmittance", float(1.0 - opts["early_termination"]))
        u.SetUniformf("il_specular", float(opts["specular"]))
        u.SetUniformf("il_shininess", float(scene.shading["shininess"]))
        u.SetUniformf("il_ambientOcclusion", float(opts["ambient_occlusion"]))
        u.SetUniformf("il_gradEps", float(gradient_threshold(volume)))
        kinds, vecs, rgb = pack_lights(lights, volume.direction, volume.origin)
        packed = np.zeros((MAX_LIGHTS, 4), dtype=np.float64)
        colours = np.zeros((MAX_LIGHTS, 3), dtype=np.float64)
        packed[: len(kinds), 0] = np.where(kinds == DIRECTIONAL, 0.0, 1.0)
        packed[: len(kinds), 1:] = vecs
        colours[: len(kinds)] = rgb
        u.SetUniformi("il_numLights", len(kinds))
        u.SetUniform1fv("il_lights", 4 * MAX_LIGHTS, packed.reshape(-1).tolist())
        u.SetUniform1fv("il_lightRGB", 3 * MAX_LIGHTS, colours.reshape(-1).tolist())
        radii = np.zeros(MAX_LIGHTS, dtype=np.float64)
        radii[: len(kinds)] = [resolved_radius(light, volume) for light in lights]
        u.SetUniform1fv("il_lightRadius", MAX_LIGHTS, radii.tolist())


# --- host helpers ------------------------------------------------------------------------------
def grey_radiance(cache: np.ndarray, lights, volume) -> np.ndarray:
    """The radiance cache as one grey channel per light, ``(nx, ny, nz, 4)`` float32.

    Channel ``j`` holds ``L̃d,j / rgb_j`` (``rgb_j`` the light's irradiance or intensity);
    unused channels are 0.

    Raises
    ------
    RuntimeError
        If a light's cache is not its RGB times a grey factor (it always is for the
        grey extinction of DESIGN.md).
    """
    cache = np.asarray(cache, dtype=np.float64)
    grey = np.zeros(cache.shape[1:4] + (MAX_LIGHTS,), dtype=np.float32)
    _, _, rgb = pack_lights(lights, volume.direction, volume.origin)
    for j in range(cache.shape[0]):
        colour = rgb[j].astype(np.float64)
        c = int(np.argmax(colour))
        if colour[c] <= 0.0:
            continue
        g = cache[j, ..., c] / colour[c]
        scale = float(np.abs(cache[j]).max()) + 1e-30
        if np.abs(cache[j] - g[..., None] * colour).max() > 1e-4 * scale:
            raise RuntimeError(f"the radiance cache of light {j} is not grey times its colour; "
                               "the OpenGL path cannot store it (use the compute path)")
        grey[..., j] = g
    return grey


def optics_rows(color: np.ndarray, sigma_t: np.ndarray) -> np.ndarray:
    """The colour and σt tables as an ``(OPTICS_ROW, rows, 2, 4)`` float32 image.

    Entry ``i`` sits at ``(i % OPTICS_ROW, i // OPTICS_ROW)`` in both z slices.
    """
    n = int(sigma_t.shape[0])
    rows = -(-n // OPTICS_ROW)
    flat = np.zeros((rows * OPTICS_ROW, 4), dtype=np.float32)
    flat[:n, :3] = color
    flat[:n, 3] = sigma_t
    grid = flat.reshape(rows, OPTICS_ROW, 4).transpose(1, 0, 2)
    return np.ascontiguousarray(np.repeat(grid[:, :, None, :], 2, axis=2))


def _stretched_image(volume, shape) -> vtkImageData:
    """Image of ``shape`` points spread over the data's box (its contents are not positions)."""
    return image_like(volume, shape=tuple(int(n) for n in shape))


def _set_image(target: vtkImageData, geometry: vtkImageData, name: str, values) -> None:
    """Give ``target`` the geometry of ``geometry`` and ``values`` as its active scalars."""
    target.Initialize()
    target.CopyStructure(geometry)
    add_point_array(target, name, np.asarray(values, dtype=np.float32), set_active=True)
    target.Modified()


def _empty_start_image(image: vtkImageData) -> None:
    """A 2×2×2 zero image, so the mapper has scalars before the first update."""
    image.SetDimensions(2, 2, 2)
    array = numpy_to_vtk(np.zeros(8, dtype=np.float32), deep=True)
    array.SetName("empty")
    image.GetPointData().SetScalars(array)


__all__ = ["AmbientScatteringVolume", "AmbientScatteringInputs", "MAX_LIGHTS", "grey_radiance",
           "optics_rows"]
