"""OpenGL ray casting shaded by an illumination volume, inside any VTK render window.

:class:`IlluminatedVolume` is a ``vtkMultiVolume`` (so ``renderer.AddVolume(v)`` and
pyvista's ``plotter.add_actor(v)`` take it) whose ``vtkOpenGLGPUVolumeRayCastMapper``
composites the same source term as the warp ray caster
(:func:`vtkillum.core.raycast.render_illuminated`; the convention is
:mod:`vtkillum.core.illumination`)::

    per step Δ (world units), sample x on a ray travelling along d:
        α  = 1 - exp(-σt(x) Δ)
        J  = albedo · color(s) · [Σ_l p_HG(w_l · d) T_l(x) E_l(x) + φ_s(x) / 4π] · S(x)
        C += T α J ;  T *= 1 - α

with ``w_l`` the unit vector towards light ``l``, ``E_l`` its irradiance at the
sample (directional: ``E``; point: ``I / max(d, r)²``, ``r`` its source radius), ``φ_s`` the isotropic scattered
fluence and ``S`` the Phong factor (two-sided normal from central differences one
voxel apart, mean over the lights, ``S = ka + kd`` where the gradient vanishes). The
direct light's transmittance is read the way
:func:`vtkillum.core.raycast.cached_transmittance` reads it::

    T_l(x) = exp(-∫_0^near σt(x + t w_l) dt) · T_grid,l(x + near w_l)

``near = near_cells ×`` the largest spacing of the transmittance grid (capped at the
light's distance), the integral marched exactly on the data (midpoint rule, segments
no longer than Δ), the grid read only where ``x + near w_l`` lies in the box and
before the light. Reading the grid one or two cells towards the light instead of at
``x`` keeps its interpolation from mixing points in front of and behind a sharp
surface (concentric rings and bands); the short exact march resolves the surface.

How the data reach the shader
-----------------------------
Five inputs of one ``vtkMultiVolume`` (each a texture VTK uploads, re-uploads when
its image is modified, and owns, so the volume survives its window being closed and
shown in a new one). All cover the data's box, but the shader computes every
texture coordinate itself from the sample's position in the volume's local frame
(``[0, extent]``), so each grid keeps its own resolution (ports 1-4 with their axes in
the order z, y, x: numpy's memory as it is, see "How the grids reach VTK" below):

====  ============================  ======================================================
port  image                         contents
====  ============================  ======================================================
0     ``64 × m × 2``, 4 components  the warp kernels' colour and σt tables (4096 entries,
                                    one texel each, interpolated linearly as they do); σt
                                    again as pairs (both ends of an interval in one
                                    texel, for the shadow march); the occupancy
                                    (:func:`optics_rows`). σt lets the shader attenuate
                                    segments of any length
1     data grid, 1 component        the rendered scalar (float32)
2     transmittance grid, 4 comp.   ``T_0 .. T_3``
3     transmittance grid, 4 comp.   ``T_4 .. T_7`` (a 2×2×2 placeholder for ≤ 4 lights)
4     scattered grid, 4 comp.       ``φ_s`` RGB, 0 (a placeholder when there is none)
====  ============================  ======================================================

Hence :data:`MAX_LIGHTS` = 8 lights; more raise a ``ValueError`` (render them with
the compute path, :class:`~vtkillum.mappers.ComputeVolumeRenderer`). Port 0 is the
output of :class:`IlluminationInputs`, a pipeline stage with the data on input 0
and the illumination on input 1 (optional); ports 1–4 are images it keeps and
refreshes only when their source changed (new data, a new illumination output, a
time step, ``array.Modified()``), so a transfer-function or light edit re-uploads
only the small table. Light directions, colours and all other parameters are
custom uniforms of the volume's ``vtkShaderProperty`` (see :data:`UNIFORMS`).

The lights: an illumination image that carries the field array ``vtkillum_lights``
(every vtkillum illumination filter writes it; :mod:`vtkillum.io.illumination_arrays`)
is shaded with those lights, the ones its transmittance channels belong to; otherwise
the scene's lights are used, and a transmittance must have one channel per scene
light. :attr:`IlluminatedVolume.lights` tells which.

GLSL for reuse (e.g. in ParaView's volume representation)
---------------------------------------------------------
The shader is four string constants; only the first depends on how the data are
laid out in textures (all names start with ``il_``):

* :data:`GLSL_LAYOUT_DEC` (format it with :func:`glsl_layout_dec`) -- this mapper's
  fetches: ``il_toLocal(w)`` / ``il_dirToLocal(w)`` (world to the local frame),
  ``il_scalar(p)`` (data value at local position ``p``), ``il_sigmaT(s)`` and
  ``il_optics(s)`` (σt; colour and σt of data value ``s``),
  ``il_gridTransmittance(l, p)`` and ``il_scatteredFluence(p)``. Another host (e.g.
  one 4-component input holding scalar and φ_s, or its own textures bound in an
  ``UpdateShaderEvent`` observer) provides the same functions for its textures.
* :data:`GLSL_SHADING_DEC` -- the convention, written only in terms of those
  functions and the uniforms of :data:`UNIFORMS`: HG phase, light incidence, the
  exact near-field march, the cached transmittance, the Phong factor and
  ``il_source(p, d, color)`` (``J / σt``). Declares the per-ray globals ``il_dir``
  and ``il_step``.
* :data:`GLSL_RAY_INIT` -- per ray (``//VTK::Shading::Init``): ray direction and step
  in the local frame from VTK's ``g_dirStep``, first-sample offset (``il_jitter``,
  ``il_frame``); draws nothing while the accumulator holds its mean (``il_hold``).
* :data:`GLSL_SAMPLE` -- per sample (``//VTK::Shading::Impl``): classification,
  source, front-to-back compositing into ``g_fragColor`` (premultiplied), so VTK's
  early termination at alpha ``1 - 1/255`` applies.

:func:`shading_uniforms` computes the uniform values for a volume, scene and lights and
:func:`set_uniforms` writes them to a ``vtkUniforms`` (``il_exposure`` and
``il_jitter`` come from the volume's :attr:`~IlluminatedVolume.exposure` and
:attr:`~IlluminatedVolume.jitter`, ``il_frame`` and ``il_hold`` from the renderer's
accumulator through :meth:`IlluminatedVolume.set_frame`).

Still pictures: jitter and accumulation
---------------------------------------
Samples lie at ``t0 + (k + ξ) Δ`` from the box entry, ``Δ`` the sample distance
(the scene's step, default half the smallest data spacing; VTK's automatic sample
distances are off, so moving the camera does not coarsen it). Where a surface is
thinner than ``Δ`` the picture depends on ``ξ``: one ``ξ`` for all pixels
(``jitter=False``, ``ξ = 1/2``, the warp caster's ``jitter=False``) draws wood-grain
terraces and streaks along the sample planes; a white-noise ``ξ`` per pixel (before
issue 34) draws salt-and-pepper speckle of the same depth. Now, with ``jitter=True``:

* ``ξ = fract(ign(pixel) + k φ)``: interleaved gradient noise (Jimenez 2014), whose
  neighbouring pixels take evenly spread offsets (no clumps) fixed to the screen (no
  crawling while the camera moves), plus ``k`` times the golden ratio conjugate ``φ``
  in frame ``k`` of an accumulation (the R1 sequence: each pixel's offsets over frames
  are evenly spread, so their mean converges like ``1/k``, white noise like
  ``1/sqrt(k)``);
* while the camera, window, scene and data rest, every render adds a frame and the
  renderer shows the mean (:mod:`vtkillum.mappers.accumulation`, up to
  :attr:`~IlluminatedVolume.accumulate` frames, then it holds the mean and the volume
  draws nothing); any change starts again. An interactive frame costs what it cost
  before (nothing is read back in frame 0); a still frame adds a read-back and a
  write of the viewport.

Measured with ``benchmarks/bench_opengl.py --quality --image 256`` (pyvista's
``add_illuminated_volume`` defaults: bone, linear opacity, a transmittance volume,
isometric view; llvmpipe on 2 shared cores). Error against the mean of 128 frames of the
same view, in 8-bit levels over the covered pixels: RMS / RMS of the 3 × 3 mean (what
the eye integrates) / share of pixels off by 3 levels or more:

================================  ====================  ====================  ====================
picture                           README head (128³)    MNI152 T1, 1 mm       MNI152 T1, 2 mm
================================  ====================  ====================  ====================
before: white noise, 1 frame      1.06 / 0.38 / 2.1 %   0.68 / 0.22 / 0.4 %   0.83 / 0.28 / 1.6 %
``jitter=False``                  1.08 / 0.39 / 2.1 %   0.68 / 0.24 / 0.4 %   0.83 / 0.40 / 1.6 %
after: 1 frame                    1.05 / 0.37 / 2.2 %   0.68 / 0.21 / 0.4 %   0.83 / 0.22 / 1.7 %
after: mean of 4 frames           0.40 / 0.15 / 0.5 %   0.41 / 0.17 / 0       0.44 / 0.17 / 0
after: mean of 16 frames          0.16 / 0.05 / 0       0.20 / 0.07 / 0       0.21 / 0.07 / 0
================================  ====================  ====================  ====================

On a sharp surface sampled every voxel (``tests/rendering/test_accumulation.py``) the
RMS goes from 9.3 (``jitter=False``) and 10.2 (one frame) to 0.44. The ring and dot
patterns that remain in these pictures are the data's: trilinear interpolation of
one-voxel material borders (the CT phantom) and of the template's brain mask; the warp
caster and a 16 times finer step show them too. Frame times on the same views (256²,
median over 10 rounds taking turns): an interactive frame after / before 0.995–1.005;
a still frame that adds to the mean costs what an interactive one does; once converged,
12–22 ms instead of 600–1000 ms.

Tolerance vs the warp caster
----------------------------
``tests/rendering/test_mappers.py`` compares 64² renders, 8-bit read back, of the
mapper with ``jitter=False`` and ``render_illuminated(..., jitter=False,
early_termination=1 - 1/255)``: mean abs difference below 3e-3 of the reference's
maximum and 99th percentile below 1.2e-2, for directional and point lights, one and two
lights, g = 0.3, ±0.6, a pipeline input at half resolution and a sharp sphere with a
half-resolution light grid. Measured: 3e-4 to 7.5e-4 mean and 2.4e-3 99th percentile
in every case, which is the 8-bit read-back alone (the quantised warp image and the
OpenGL image agree to 1e-6; every pixel lies within half an 8-bit level of the warp
radiance); the per-case values are in that module's docstring.

Performance (software OpenGL included)
--------------------------------------
The shader is written for GPUs and for Mesa's llvmpipe (OSMesa), which runs it on the
CPU and pays for much of the code behind a branch not taken, and for the body of a loop
once even when it has no iteration:

* per ray (``il_initLayout``, ``il_initRay``, ``GLSL_RAY_INIT``): every grid's texture
  scale and bias, the sample position's start and step in the local frame (a sample's
  position is ``start + g_currentT step``: no matrix product per sample), the direction
  and ``p_HG(w_l · d) E_l`` of each directional light (the ray's and the light's
  directions are fixed);
* texels are read as uploaded (float32 data and tables; 16-bit grids, normalised by
  OpenGL, times a factor the host knows: ``il_taQ``...), not through VTK's
  ``in_volume_scale``/``in_volume_bias``, which a multi-volume sets only when input 0 has
  one component;
* per sample: the data value, then colour and σt together (two fetches of the
  4-component table, entries found with a mask and a shift); in the shadow marches σt
  alone, one fetch (the pairs); the occupancy fetched once per block a ray enters;
  ``il_cachedTransmittance`` called once per light (not once per light kind);
* compiled only where needed (``IL_PHONG``, ``IL_DIRECT``, ``IL_SCATTERED``; a change
  rebuilds the shader, VTK keeps the programs built): the gradient (six more data
  fetches) where shading has a diffuse or specular term, the direct light where the
  illumination has transmittance (or none: unshadowed), the scattered fluence where it
  has one.

Measured with ``benchmarks/bench_opengl.py --profile --data phantom --size 96 --image 256 --frames 11``
(llvmpipe on 2 shared cores: ratios to VTK's plain composite ray caster on the same data,
step and camera, the two versions taking turns in the same rounds; CT phantom, default
scene with 2 directional lights, light grids at full resolution):

=============================================  ======================  =====
IlluminatedVolume                              before (commit bc9ccad)  after
=============================================  ======================  =====
no illumination (T = 1)                        2.32                    1.98
scattered fluence only (photon density)        1.71                    0.75
transmittance, ``near_cells`` 0                2.41                    2.06
transmittance, ``near_cells`` 2 (default)      3.32                    2.83
transmittance, Phong                           4.19                    3.77
transmittance, moving (``interactive_step`` 2)  1.77                    1.48
the same, ``interactive_near_cells`` 0         --                      1.26
scattered only, moving                         1.10                    0.51
=============================================  ======================  =====

With light grids at half resolution (``--grid-scale 0.5``: a 4-voxel near field, 8
samples per light) the default transmittance frame went from 4.07 to 3.47 and a moving
one from 2.12 to 1.64 (1.19 with ``interactive_near_cells`` 0). On a GPU the balance
differs (empty loops cost nothing there, texture fetches and registers more); the
H200 figures are ``bench_opengl.py --interactive``'s.

The near-field march: its segments are no longer than the sample distance, as the warp
caster's (``raycast.near_transmittance``). Voxel-long segments would halve its samples
at rest, but left rings of 3.7 % of the image on a one-voxel-sharp sphere instead of
1.1 % (``tests/core/test_transmittance_render.py::test_no_rings_on_a_sharp_sphere``), so
both keep the step; while the view moves, ``interactive_step`` 2 makes them voxel-long
anyway. ``interactive_near_cells = 0`` (the default; ``None``: as at rest) skips the march
while the view moves and reads the grid at the sample: a further 15-25 % on llvmpipe and
30 % on the H200 (below), but the grid's bands on sharp surfaces show while dragging (on
the sharp sphere of ``tests/rendering/test_interactive_near_field.py``: mean 2.7e-2, 99th
percentile 0.38 of the still frame's maximum); the frames added at rest march
``near_cells`` again.

On a GPU (NVIDIA H200, EGL, ``bench_opengl.py --profile --size 512 --image 1024`` and
``--interactive``, ``bench_scaling.py``'s CT-like 512³ volume, one light, full-resolution
16-bit grids): **VTK's own composite ray casting of the same data takes 59.7 ms a frame**,
26 times the 2.3 ms of the warp caster's emission kernel. The H200 is a data-centre GPU
whose fragment shaders run on a few of its multiprocessors, so the frame of any
OpenGL ray caster there is bounded by this floor, not by the shading. Against it, a
frame of this mapper costs 0.81 (scattered fluence only), 0.96 (transmittance,
``near_cells`` 0) and 1.98 (transmittance, ``near_cells`` 2: 118 ms; 137 ms before the
light counts were compiled in and the fetches took an explicit level of detail). While
the view moves, ``interactive_step`` 2, ``interactive_image_sample_distance`` 2 (a ray
per 2 × 2 pixels, :mod:`vtkillum.mappers.interaction`) and ``interactive_near_cells`` 0
bring a camera move to 14.6 ms (transmittance), 17.7 ms (convection-diffusion: both
grids) and 12.3 ms (scattered fluence only); at every pixel 35.0, 43.5 and 28.7 ms; at full
quality 116, 135 and 47 ms (``bench_opengl.py``'s docstring has the table).

How the grids reach VTK: numpy keeps a grid ``[x, y, z]`` with z fastest, VTK's point
order has x fastest. Instead of transposing (a slow, cache-hostile pass over every 512³
grid on each edit), grids from numpy (the data, an ``IlluminationVolume``) go into images
whose axes are in the order (z, y, x), so numpy's memory is VTK's as it is, and the shader
reads them with ``.zyx`` (``il_zMajor``); grids from an illumination image (a filter's
output) are read in place from its VTK arrays (:class:`ImageGrids`: no copy, the checks
fused into the packing; 1.07 s → 0.22 s for a 256³ transmittance and scattered fluence on
the development machine) and keep VTK's order. 16-bit packing writes straight into the VTK
array's memory, one slab at a time, and the array's range is declared to VTK (its cached
finite range), so the upload does not scan it. A TF edit with a
new 512³ light grid from host arrays took 6.8 s before, 2.6 s with the first two (H200), of
which 0.45 s was the range pass the third removes and about 0.5 s VTK's upload.

Grids that a light method left on a GPU (an ``IlluminationVolume`` of warp arrays, e.g.
``ConvectionDiffusionSolver.illumination_volume(volume)`` or ``light_transmittance(...,
on_device=True)``) need none of that: with :attr:`IlluminatedVolume.device_upload` on they
are packed to 16 bit on the device (:mod:`vtkillum.core.texels`, the same texels) and
copied through an OpenGL pixel buffer mapped into CUDA into the textures VTK made for the
previous grids (:mod:`vtkillum.mappers.texture_upload`; on by default). On an H200 the
write of a 512³ grid (pack, copy into the pixel buffer, ``glTexSubImage3D``) takes 14 ms,
and a TF edit to the new frame 164–174 ms instead of 1451 ms (transmittance; most of it is
the frame); with the transmittance recomputed on the GPU as well, 210 ms instead of
2156 ms.

``benchmarks/bench_opengl.py`` compares the frame time with VTK's own volumetric shadows
(``docs/benchmarks.md``).

Simplifications and limits
--------------------------
* Jittered pictures (above) agree with the warp caster's only on average (its offsets
  are its own random stream); the tests compare ``jitter=False``. VTK's own
  ``UseJittering`` (a tiled noise texture) is off.
* The accumulated mean is of 8-bit frames read back from the frame buffer (each within
  half a level of its radiance; the varying offsets dither the sum).
* Grids are interpolated by the texture unit (trilinear, clamped to the box as the
  warp samplers; GPUs may use 8-bit interpolation weights).
* Input: point data with one component (the core's convention), not split into
  texture blocks; the volume's own transform (``SetPosition``, ``SetUserMatrix``)
  must stay the identity: place the data with the image's origin, spacing and
  direction. Cropping, clipping planes and depth peeling are not supported
  (``vtkMultiVolume`` restrictions).
* Memory (GPU and CPU): 4 bytes per data point (the float32 scalar), 8 per
  transmittance-grid point per 4 lights and 8 per scattered-grid point (16-bit; 16 with
  ``illumination_16bit = False``).
* Texture units: 5 volumes plus VTK's colour and opacity tables of each and the depth
  buffer (16); implementations with fewer fragment texture units cannot draw it.
"""

from __future__ import annotations

import math

import numpy as np
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (OpenGL factory overrides)
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.util.vtkConstants import VTK_FLOAT, VTK_UNSIGNED_SHORT
from vtkmodules.vtkCommonCore import (
    vtkCommand,
    vtkDataArray,
    vtkFloatArray,
    vtkInformation,
    vtkInformationVector,
    vtkOutputWindow,
    vtkUnsignedShortArray,
    vtkWeakReference,
)
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkAlgorithm
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP
from vtkmodules.vtkRenderingCore import vtkVolume, vtkVolumeProperty
from vtkmodules.vtkRenderingVolume import vtkMultiVolume
from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkOpenGLGPUVolumeRayCastMapper

from vtkillum.core.illumination import IlluminationVolume, gradient_threshold, shading_terms
from vtkillum.core.lights import DIRECTIONAL, pack_lights, resolved_radius
from vtkillum.core.scene import Scene
from vtkillum.core.texels import texel_scales
from vtkillum.core.transfer_function import TABLE_SIZE
from vtkillum.core.volume import Volume
from vtkillum.io.convert import add_point_array, image_like, volume_from_image_data
from vtkillum.io.illumination_arrays import illumination_array_names, lights_from_field
from vtkillum.mappers.accumulation import accumulator_for, existing_accumulator
from vtkillum.mappers.camera_bridge import GridSummary, apply_scene_to_volume_property
from vtkillum.mappers.inputs import check_covers, connect_input, rendered_point_array
from vtkillum.mappers.interaction import (
    INTERACTIVE_IMAGE_SAMPLE_DISTANCE,
    INTERACTIVE_STEP,
    InteractiveSampling,
)
from vtkillum.mappers.texture_upload import DeviceUpload

#: Lights the shader takes: two 4-channel transmittance textures.
MAX_LIGHTS = 8

#: Default near-field march in transmittance-grid cells; equals
#: ``vtkillum.core.raycast.RAYCAST_OPTIONS["near_cells"]`` (kept here so that the OpenGL
#: path imports no warp; a test checks they agree).
NEAR_CELLS = 2.0

#: Default frames an :class:`IlluminatedVolume` averages while the view rests.
ACCUMULATE = 16


#: Default near-field march while the view moves (0: read the grid at the sample; None:
#: ``near_cells``, as at rest). See the module docstring for what it saves on a GPU.
INTERACTIVE_NEAR_CELLS = 0.0

#: Ports of the mapper (= indices of ``in_volume[]`` in the shader).
OPTICS_PORT, DATA_PORT, DIRECT_PORT_A, DIRECT_PORT_B, SCATTERED_PORT = range(5)

#: Entries per row of the optics image (the 4096-entry tables are stored as 64 × 64).
OPTICS_ROW = 64

#: The custom uniforms the GLSL reads (all in the volume's local frame, world units).
UNIFORMS = {
    "il_origin": "vec3: the data's first point (world)",
    "il_axis0": "vec3: first column of the data's direction matrix (world -> local)",
    "il_axis1": "vec3: second column",
    "il_axis2": "vec3: third column",
    "il_extent": "vec3: size of the box, (dims - 1) * spacing",
    "il_spacing": "vec3: data spacing (central differences of the Phong normal)",
    "il_tableLo": "float: data value of optics-table entry 0",
    "il_tableScale": "float: table entries per data unit",
    "il_tableSize": "int: entries of the optics table",
    "il_albedo": "float: single-scattering albedo",
    "il_g": "float: Henyey-Greenstein anisotropy",
    "il_exposure": "float: factor on the radiance written to the frame buffer",
    "il_shading": "vec4: ka, kd, ks, shininess (illumination.py)",
    "il_gradEps": "float: gradient magnitude below which there is no normal (data units/world)",
    "il_numLights": "int: lights (Phong directions; the shader is compiled for this count, "
                    "IL_NUM_LIGHTS)",
    "il_numDirect": "int: lights with a transmittance channel (0: no direct light; compiled "
                    "in as IL_NUM_DIRECT)",
    "il_lights": "float[4 * MAX_LIGHTS]: per light kind (0 directional, 1 point), then the "
                 "travel direction or the position (local)",
    "il_lightRGB": "float[3 * MAX_LIGHTS]: per light RGB irradiance or intensity",
    "il_lightRadius": "float[MAX_LIGHTS]: source radius of point lights (irradiance "
                      "I / max(d, r)^2; vtkillum.core.lights.resolved_radius)",
    "il_near": "float: length of the exact near-field march (world units)",
    "il_nearScale": "float: factor on il_near in this frame (1; interactive_near_cells / "
                    "near_cells while the view moves in an interactive window)",
    "il_hasScattered": "int: 1 when a scattered fluence is bound",
    "il_jitter": "int: 0 samples at step midpoints; 1 offsets each pixel's first sample "
                 "(interleaved gradient noise, R1 sequence over frames)",
    "il_frame": "int: frame of the accumulation (0: a frame after a change; "
                "vtkillum.mappers.accumulation)",
    "il_hold": "int: 1 draws nothing (the accumulator shows its stored mean)",
    "il_stepScale": "float: sample distance factor of this frame (1; interactive_step while "
                    "the view moves in an interactive window)",
    "il_skip": "int: 1 leaps over blocks whose samples are all empty (occupancy rows of "
               "the optics image)",
    "il_blockSize": "vec3: size of an occupancy block (world units)",
    "il_blockCount": "vec3: occupancy blocks along each axis",
    "il_taQ": "vec4: factor from the texel to the physical value of the T_0..T_3 texture "
              "(16-bit: the channel's maximum, texels being normalised to [0, 1]; float: 1)",
    "il_tbQ": "vec4: likewise for T_4..T_7",
    "il_scQ": "vec4: likewise for the scattered fluence",
    "il_zMajor": "vec4: 1 where the data, T_0..T_3, T_4..T_7, scattered texture was uploaded "
                 "z-major (numpy's [x, y, z] order, the image's axes reversed), 0 where in "
                 "VTK's point order (from an illumination image)",
}

# --- GLSL ----------------------------------------------------------------------------------------
# Layout: where this mapper keeps its data. Values come back from VTK's normalised textures
# as mix(range.lo, range.hi, v * scale + bias), with in_scalarsRange indexed 4 * port + c.
GLSL_LAYOUT_DEC = """//VTK::Shading::Dec
// vtkillum: illumination-volume shading (vtkillum/mappers/illuminated_volume_mapper.py)
// --- layout: this mapper's textures (another host replaces this block) ---
#define IL_MAX_LIGHTS %(max_lights)d
#define IL_NUM_LIGHTS %(lights)d
#define IL_NUM_DIRECT %(direct_lights)d
#define IL_LIGHT_SLOTS %(slots)d
#define IL_OPTICS_ROW %(row)d
#define IL_OPTICS_SHIFT %(shift)d
#define IL_PHONG %(phong)d
#define IL_DIRECT %(direct)d
#define IL_SCATTERED %(scattered)d
#define IL_SIGMA_ROW %(sigma_row)d
#define IL_OCC_ROW %(occ_row)d

mat4 il_texToLocal;  // VTK's texture coordinates of the box -> local frame (set per ray)
vec3 il_rayStart;    // local position of sample g_currentT = 0 (set per ray)
vec3 il_stepLocal;   // one step (g_dirStep) in the local frame (set per ray)
vec3 il_invBlock;    // 1 / il_blockSize (set per ray)

// Per-ray constants of the layout (il_initLayout): for each grid, texture coordinate =
// clamp(p, 0, extent) * scale + bias (point-centred, clamped to the box like the warp
// samplers), swizzled to .zyx where the grid was uploaded as numpy keeps it ([x, y, z], z
// fastest: the texture's first axis is z, il_zMajor; no transposition on the host). Texels are read as they were uploaded, not through VTK's in_volume_scale /
// in_volume_bias (which a multi-volume sets only for some component layouts): float32
// textures (data, optics) hold the values, 16-bit ones are normalised by OpenGL to [0, 1]
// and il_taQ / il_tbQ / il_scQ scale them back.
vec3 il_dataScale;
vec3 il_dataBias;
vec3 il_taScale;
vec3 il_taBias;
vec3 il_tbScale;
vec3 il_tbBias;
vec3 il_scScale;
vec3 il_scBias;

// World position -> the volume's local frame [0, il_extent].
vec3 il_toLocal(vec3 w)
{
  vec3 q = w - il_origin;
  return vec3(dot(q, il_axis0), dot(q, il_axis1), dot(q, il_axis2));
}

vec3 il_dirToLocal(vec3 w)
{
  return vec3(dot(w, il_axis0), dot(w, il_axis1), dot(w, il_axis2));
}

// Texture axes of a grid: (z, y, x) where it is z-major (zMajor > 0.5), else (x, y, z).
vec3 il_axes(vec3 t, float zMajor)
{
  return zMajor > 0.5 ? t.zyx : t;
}

void il_gridMap(vec3 n, out vec3 scale, out vec3 bias)
{
  scale = (n - 1.0) / (n * il_extent);
  bias = 0.5 / n;
}

// The per-ray constants above (call once per ray, before any fetch).
void il_initLayout()
{
  il_gridMap(il_axes(vec3(textureSize(in_volume[%(data)d], 0)), il_zMajor.x), il_dataScale,
             il_dataBias);
  il_gridMap(il_axes(vec3(textureSize(in_volume[%(ta)d], 0)), il_zMajor.y), il_taScale,
             il_taBias);
  il_gridMap(il_axes(vec3(textureSize(in_volume[%(tb)d], 0)), il_zMajor.z), il_tbScale,
             il_tbBias);
  il_gridMap(il_axes(vec3(textureSize(in_volume[%(sc)d], 0)), il_zMajor.w), il_scScale,
             il_scBias);
}

// Data value (data units) at local position p, trilinear.
float il_scalar(vec3 p)
{
  vec3 tex = clamp(p, vec3(0.0), il_extent) * il_dataScale + il_dataBias;
  return textureLod(in_volume[%(data)d], il_axes(tex, il_zMajor.x), 0.0).r;
}

// Continuous table index of data value s (clamped: constant outside the table).
float il_tableCoord(float s)
{
  return clamp((s - il_tableLo) * il_tableScale, 0.0, float(il_tableSize - 1));
}

// Optics-table entry i (colour rgb, sigma_t a; float32): one texel of the
// 4-component optics image at x = i %% OPTICS_ROW, y = i / OPTICS_ROW (OPTICS_ROW a power of
// two: a mask and a shift, no integer division).
vec4 il_opticsTexel(int i)
{
  return texelFetch(in_volume[%(opt)d], ivec3(i & (IL_OPTICS_ROW - 1), i >> IL_OPTICS_SHIFT, 0),
                    0);
}

// sigma_t (1/world units) of data value s: linear between table entries (lookup_sigma_t).
// One fetch: after the entries, texel j = (sigma_2j, sigma_2j+1, sigma_2j+2, 0) holds both
// ends of the interval [i, i + 1] for i = 2j and i = 2j + 1 (x = j %% OPTICS_ROW,
// y = IL_SIGMA_ROW + j / OPTICS_ROW); the shadow marches read only these.
float il_sigmaT(float s)
{
  float x = il_tableCoord(s);
  int i = min(int(x), il_tableSize - 2);
  int j = i >> 1;
  vec4 v = texelFetch(in_volume[%(opt)d],
                      ivec3(j & (IL_OPTICS_ROW - 1), IL_SIGMA_ROW + (j >> IL_OPTICS_SHIFT), 0), 0);
  float f = x - float(i);
  return (i & 1) == 0 ? mix(v.x, v.y, f) : mix(v.y, v.z, f);
}

// Colour (rgb) and sigma_t (a) of data value s (lookup_color, lookup_sigma_t): two fetches.
vec4 il_optics(float s)
{
  float x = il_tableCoord(s);
  int i = min(int(x), il_tableSize - 2);
  return mix(il_opticsTexel(i), il_opticsTexel(i + 1), x - float(i));
}

// Light l's cached transmittance T_grid,l at local position p, trilinear.
float il_gridTransmittance(int l, vec3 p)
{
  vec3 q = clamp(p, vec3(0.0), il_extent);
  if (l < 4)
  {
    return textureLod(in_volume[%(ta)d], il_axes(q * il_taScale + il_taBias, il_zMajor.y),
                      0.0)[l] * il_taQ[l];
  }
  int c = l & 3;  // l - 4 (never negative: with a constant l, dead code is still checked)
  return textureLod(in_volume[%(tb)d], il_axes(q * il_tbScale + il_tbBias, il_zMajor.z), 0.0)[c] *
    il_tbQ[c];
}

// Scattered fluence phi_s (RGB) at local position p, trilinear.
vec3 il_scatteredFluence(vec3 p)
{
  vec3 tex = clamp(p, vec3(0.0), il_extent) * il_scScale + il_scBias;
  return textureLod(in_volume[%(sc)d], il_axes(tex, il_zMajor.w), 0.0).xyz * il_scQ.xyz;
}

// Occupancy: 1 where block b (of il_blockCount, il_blockSize each, covering the points of
// its cells) holds a data value whose sigma_t may be > 0, 0 where every sample in it is
// empty; stored after the optics table, four flags a texel: entry i in component i %% 4 of
// x = (i / 4) %% OPTICS_ROW, y = IL_OCC_ROW + i / (4 OPTICS_ROW).
bool il_blockEmpty(vec3 b)
{
  int i = int(b.x) + int(il_blockCount.x) * (int(b.y) + int(il_blockCount.y) * int(b.z));
  int j = i >> 2;
  return texelFetch(in_volume[%(opt)d],
                    ivec3(j & (IL_OPTICS_ROW - 1), IL_OCC_ROW + (j >> IL_OPTICS_SHIFT), 0),
                    0)[i & 3] < 0.5;
}
"""

# The convention (vtkillum.core.illumination, raycast.cached_direct_light, phong_factor):
# depends only on the five layout functions above and the uniforms of UNIFORMS.
GLSL_SHADING_DEC = """
// --- shading: the phase-aware illumination-volume convention (host independent) ---
#define IL_PI 3.14159265358979
vec3 il_dir;    // unit ray direction, local frame (set per ray)
float il_step;  // sample spacing, world units (set per ray)
// Per ray (il_initRay): for directional lights the unit vector towards the light and
// p_HG(w_l . d) E_l (the ray's and the light's directions are fixed); the block whose
// occupancy was fetched last and whether it is empty.
vec3 il_rayToLight[IL_LIGHT_SLOTS];
vec3 il_rayLight[IL_LIGHT_SLOTS];
vec3 il_lastBlock;
bool il_lastEmpty;

// Henyey-Greenstein, normalised to 1 over the sphere (warp_common.hg_phase).
float il_hg(float cosTheta, float g)
{
  float denom = 1.0 + g * g - 2.0 * g * cosTheta;
  return (1.0 - g * g) / (4.0 * IL_PI * denom * sqrt(denom));
}

// Unit vector from p towards light l, its distance (1e30: directional) and the RGB
// irradiance at p: E, or I / max(d, r)^2 for a point light of source radius r
// (warp_common.light_incidence).
void il_incidence(int l, vec3 p, out vec3 toLight, out float dist, out vec3 irradiance)
{
  vec3 v = vec3(il_lights[4 * l + 1], il_lights[4 * l + 2], il_lights[4 * l + 3]);
  vec3 rgb = vec3(il_lightRGB[3 * l], il_lightRGB[3 * l + 1], il_lightRGB[3 * l + 2]);
  if (il_lights[4 * l] < 0.5)
  {
    toLight = -v;
    dist = 1.0e30;
    irradiance = rgb;
  }
  else
  {
    vec3 d = v - p;
    dist = max(length(d), 1.0e-20);
    toLight = d / dist;
    float r = max(dist, il_lightRadius[l]);
    irradiance = rgb / (r * r);
  }
}

// Distance from p (inside the box) along unit w to the box's exit.
float il_boxExit(vec3 p, vec3 w)
{
  float t1 = 1.0e30;
  for (int a = 0; a < 3; ++a)
  {
    if (abs(w[a]) >= 1.0e-12)
    {
      float ta = -p[a] / w[a];
      float tb = (il_extent[a] - p[a]) / w[a];
      t1 = min(t1, max(ta, tb));
    }
  }
  return t1;
}

// exp(-integral of sigma_t) from p along unit w over min(dist, box exit): equal segments
// no longer than il_step, each sampled at fraction xi (warp_common.shadow_transmittance).
float il_shadowMarch(vec3 p, vec3 w, float dist, float xi)
{
  float len = min(il_boxExit(p, w), dist);
  if (len <= 0.0)
  {
    return 1.0;
  }
  int n = int(ceil(len / il_step));
  float h = len / float(n);
  float tau = 0.0;
  for (int k = 0; k < n; ++k)
  {
    tau += il_sigmaT(il_scalar(p + ((float(k) + xi) * h) * w));
  }
  return exp(-tau * h);
}

// T_l(p): exact over the first il_near towards the light, then the grid
// (raycast.cached_transmittance).
float il_cachedTransmittance(int l, vec3 p, vec3 w, float dist)
{
  float near = min(il_near * il_nearScale, dist);
  float t = 1.0;
  if (near > 0.0)
  {
    t = il_shadowMarch(p, w, near, 0.5);
  }
  vec3 q = p + near * w;
  if (near < dist && all(greaterThanEqual(q, vec3(0.0))) && all(lessThanEqual(q, il_extent)))
  {
    t *= il_gridTransmittance(l, q);
  }
  return t;
}

// Per ray: direction and p_HG(w_l . d) E_l of every directional light (fixed along the
// ray), and no occupancy fetched yet.
void il_initRay(vec3 d)
{
  for (int l = 0; l < IL_LIGHT_SLOTS; ++l)
  {
    il_rayToLight[l] = vec3(0.0);
    il_rayLight[l] = vec3(0.0);
    if (l < IL_NUM_LIGHTS && il_lights[4 * l] < 0.5)
    {
      vec3 w;
      float dist;
      vec3 e;
      il_incidence(l, vec3(0.0), w, dist, e);
      il_rayToLight[l] = w;
      il_rayLight[l] = il_hg(dot(w, d), il_g) * e;
    }
  }
  il_lastBlock = vec3(-1.0);
  il_lastEmpty = false;
}

// sum_l p_HG(w_l . d) T_l(p) E_l(p) for a ray travelling along d (raycast.cached_direct_light).
// One call of il_cachedTransmittance per light (software rasterisers run both sides of a
// branch: the march must not be written twice).
vec3 il_directLight(vec3 p, vec3 d)
{
  vec3 acc = vec3(0.0);
  for (int l = 0; l < IL_NUM_DIRECT; ++l)
  {
    vec3 w = il_rayToLight[l];
    float dist = 1.0e30;
    vec3 light = il_rayLight[l];
    if (il_lights[4 * l] >= 0.5)
    {
      vec3 e;
      il_incidence(l, p, w, dist, e);
      light = il_hg(dot(w, d), il_g) * e;
    }
    acc += il_cachedTransmittance(l, p, w, dist) * light;
  }
  return acc;
}

// Unit data gradient facing the viewer, or 0 where it vanishes (warp_common.view_normal).
vec3 il_normal(vec3 p, vec3 d)
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
  return dot(n, d) > 0.0 ? -n : n;
}

// S = ka + kd mean|n.w_l| + ks mean max(n.h_l, 0)^shininess (raycast.phong_factor).
// IL_PHONG (0 or 1) is defined by the host: 0 when kd = ks = 0 (the default), so that the
// gradient (six more data fetches per sample) is compiled only where shading needs it;
// software rasterisers (llvmpipe) pay for code behind a branch not taken.
float il_phong(vec3 p, vec3 d)
{
  float ka = il_shading.x;
#if IL_PHONG
  float kd = il_shading.y;
  float ks = il_shading.z;
  if (kd == 0.0 && ks == 0.0)
  {
    return ka;
  }
  vec3 n = il_normal(p, d);
  if (dot(n, n) == 0.0)
  {
    return ka + kd;
  }
  float diff = 0.0;
  float spec = 0.0;
  for (int l = 0; l < IL_NUM_LIGHTS; ++l)
  {
    vec3 w = il_rayToLight[l];
    if (il_lights[4 * l] >= 0.5)
    {
      float dist;
      vec3 e;
      il_incidence(l, p, w, dist, e);
    }
    diff += abs(dot(n, w));
    vec3 h = w - d;
    float hlen = length(h);
    if (hlen > 0.0)
    {
      spec += pow(max(dot(n, h / hlen), 0.0), il_shading.w);
    }
  }
  return ka + (kd * diff + ks * spec) / float(max(IL_NUM_LIGHTS, 1));
#else
  return ka;
#endif
}

// J / sigma_t at p for a ray along d:
// albedo color [sum_l p T_l E_l + phi_s / 4 pi] S.
// IL_DIRECT, IL_SCATTERED (0 or 1; host defines): compile the direct light (il_numDirect > 0)
// and the scattered fluence (il_hasScattered) only where the illumination has them: llvmpipe
// runs a loop's body once even for 0 iterations (the direct light's is most of the frame
// of a scattered-only volume there).
vec3 il_source(vec3 p, vec3 d, vec3 color)
{
  vec3 light = vec3(0.0);
#if IL_DIRECT
  light = il_directLight(p, d);
#endif
#if IL_SCATTERED
  if (il_hasScattered != 0)
  {
    light += il_scatteredFluence(p) / (4.0 * IL_PI);
  }
#endif
  return (il_albedo * il_phong(p, d)) * color * light;
}
"""

# Per ray, before the loop (//VTK::Shading::Init; the tag is kept for VTK's own code).
# g_dataPos is in the texture coordinates of the multi-volume's box; VTK starts one step
# (g_rayJitter = g_dirStep with VTK's jittering off) inside it. The first sample goes to
# fraction xi of the first step: 1/2 (the warp caster's jitter=False), or with il_jitter
# xi = fract(ign(pixel) + il_frame * phi): interleaved gradient noise (Jimenez 2014) puts
# different offsets in neighbouring pixels without the clumps of white noise (no salt and
# pepper), fixed to the screen (no crawling while the camera moves); frame k of an
# accumulation adds k times the golden ratio conjugate (the R1 sequence), so every pixel's
# offsets over frames are evenly spread over [0, 1) and their mean converges like 1/k
# (white noise: 1/sqrt(k)). il_hold: the accumulator shows its stored mean; draw nothing.
GLSL_RAY_INIT = """//VTK::Shading::Init
  if (il_hold != 0)
  {
    discard;
  }
  {
    il_initLayout();
    mat4 il_texToWorld = in_volumeMatrix[0] * in_textureDatasetMatrix[0];
    // texture coordinates of the box -> the local frame, once per ray
    mat4 il_worldToLocal = mat4(vec4(il_axis0.x, il_axis1.x, il_axis2.x, 0.0),
                                vec4(il_axis0.y, il_axis1.y, il_axis2.y, 0.0),
                                vec4(il_axis0.z, il_axis1.z, il_axis2.z, 0.0),
                                vec4(-dot(il_origin, il_axis0), -dot(il_origin, il_axis1),
                                     -dot(il_origin, il_axis2), 1.0));
    il_texToLocal = il_worldToLocal * il_texToWorld;
    g_dataPos -= g_rayJitter;
    if (il_stepScale != 1.0)
    {
      g_dirStep *= il_stepScale;
      g_lengthStep *= il_stepScale;
      g_terminatePointMax /= il_stepScale;
    }
    vec3 il_stepWorld = (il_texToWorld * vec4(g_dirStep, 0.0)).xyz;
    il_step = length(il_stepWorld);
    il_dir = il_dirToLocal(il_stepWorld / il_step);
    il_stepLocal = il_dir * il_step;
    il_invBlock = 1.0 / il_blockSize;
    il_initRay(il_dir);
    float il_xi = 0.5;
    if (il_jitter != 0)
    {
      float il_ign = fract(52.9829189 * fract(dot(floor(gl_FragCoord.xy),
                                                  vec2(0.06711056, 0.00583715))));
      il_xi = fract(il_ign + fract(float(il_frame) * 0.6180339887));
    }
    g_dataPos += il_xi * g_dirStep;
    il_rayStart = (il_texToLocal * vec4(g_dataPos, 1.0)).xyz - g_currentT * il_stepLocal;
  }
"""

# Per sample (//VTK::Shading::Impl): replaces VTK's classification and blending. Samples
# outside the data's box (a host whose bounding box is larger) are empty, as in the warp caster.
GLSL_SAMPLE = """
    if (!g_skip)
    {
      // g_dataPos = its first value + g_currentT g_dirStep (leaps add to both)
      vec3 il_p = il_rayStart + g_currentT * il_stepLocal;
      vec3 il_tol = 1.0e-5 * il_extent;
      bool il_inside = all(greaterThanEqual(il_p, -il_tol)) &&
        all(lessThanEqual(il_p, il_extent + il_tol));
      if (il_inside && il_skip != 0)
      {
        vec3 il_b = clamp(floor(il_p * il_invBlock), vec3(0.0), il_blockCount - 1.0);
        if (any(notEqual(il_b, il_lastBlock)))  // one occupancy fetch per block on the ray
        {
          il_lastBlock = il_b;
          il_lastEmpty = il_blockEmpty(il_b);
        }
        if (il_lastEmpty)
        {
          // every sample up to the block's exit is empty: leap over whole steps
          vec3 il_lo = il_b * il_blockSize;
          vec3 il_hi = min(il_lo + il_blockSize, il_extent);
          vec3 il_d = mix(vec3(1.0e-20), il_dir, greaterThan(abs(il_dir), vec3(1.0e-20)));
          vec3 il_t = max((il_lo - il_p) / il_d, (il_hi - il_p) / il_d);
          float il_k = floor(min(il_t.x, min(il_t.y, il_t.z)) / il_step);
          if (il_k >= 1.0)
          {
            g_dataPos += il_k * g_dirStep;
            g_currentT += il_k;
          }
          il_inside = false;
        }
      }
      vec4 il_opt = il_inside ? il_optics(il_scalar(il_p)) : vec4(0.0);
      if (il_opt.a > 0.0)
      {
        float il_alpha = 1.0 - exp(-il_opt.a * il_step);
        vec3 il_src = il_exposure * il_source(il_p, il_dir, il_opt.rgb);
        g_fragColor.rgb += ((1.0 - g_fragColor.a) * il_alpha) * il_src;
        g_fragColor.a += (1.0 - g_fragColor.a) * il_alpha;
      }
    }
"""


def glsl_layout_dec(max_lights: int = MAX_LIGHTS, phong: bool = True, direct: bool = True,
                    scattered: bool = True, lights: int | None = None,
                    direct_lights: int | None = None) -> str:
    """:data:`GLSL_LAYOUT_DEC` with this mapper's port numbers filled in.

    ``phong``: compile the diffuse and specular terms (``IL_PHONG``; without them the
    shader takes ``S = ka`` and never computes a gradient). ``direct``, ``scattered``:
    compile the direct light (``IL_DIRECT``) and the scattered fluence (``IL_SCATTERED``);
    without them the source has no such term. ``lights``, ``direct_lights``: the lights
    (``IL_NUM_LIGHTS``, default ``max_lights``) and those with a transmittance channel
    (``IL_NUM_DIRECT``, default ``lights`` where ``direct``, else 0) the shader is compiled
    for: loops over lights of a known count are unrolled and keep the per-ray light values
    in registers (an array indexed by a uniform count lives in local memory on GPUs).
    """
    lights = int(max_lights if lights is None else lights)
    direct_lights = int((lights if direct else 0) if direct_lights is None else direct_lights)
    if not 0 <= direct_lights <= lights <= max_lights:
        raise ValueError(f"need 0 <= direct_lights <= lights <= max_lights, got "
                         f"{direct_lights}, {lights}, {max_lights}")
    ports = {"data": DATA_PORT, "opt": OPTICS_PORT, "ta": DIRECT_PORT_A, "tb": DIRECT_PORT_B,
             "sc": SCATTERED_PORT}
    shift = int(OPTICS_ROW).bit_length() - 1
    if 1 << shift != OPTICS_ROW:
        raise ValueError("OPTICS_ROW must be a power of two")
    values = {"max_lights": int(max_lights), "row": OPTICS_ROW, "shift": shift,
              "lights": lights, "direct_lights": direct_lights, "slots": max(1, lights),
              "phong": int(bool(phong)), "direct": int(bool(direct and direct_lights)),
              "scattered": int(bool(scattered)), **ports}
    values.update({f"{k}4": 4 * v for k, v in ports.items()})
    values["sigma_row"] = -(-TABLE_SIZE // OPTICS_ROW)
    values["occ_row"] = values["sigma_row"] + -(-TABLE_SIZE // (2 * OPTICS_ROW))
    return GLSL_LAYOUT_DEC % values


class IlluminatedVolume(InteractiveSampling, DeviceUpload, vtkMultiVolume):
    """A ``vtkMultiVolume`` rendered with an illumination volume by VTK's GPU ray caster.

    Parameters
    ----------
    data : vtkImageData, vtkAlgorithmOutput, vtkAlgorithm or Volume
        The scalar field (also ``pyvista.ImageData``). Point data, one component.
        A pipeline connection keeps following its producer (new data, time steps).
    scene : Scene, optional
        Transfer function, opacity unit distance, albedo, anisotropy ``g``, lights (at
        most :data:`MAX_LIGHTS`; used unless the illumination carries its own),
        ``shading`` and step size (the mapper's sample distance). Default ``Scene()``
        (its defaults resolved on ``data``).
    illumination : optional
        See :meth:`set_illumination`; default ``None`` (unshadowed direct light).
    array_name : str, optional
        Point array to render; default the active scalars.
    exposure : float
        Factor on the radiance before it reaches the (8-bit, linear) frame buffer.
    near_cells : float
        Length of the exact near-field march in transmittance-grid cells (default
        :data:`NEAR_CELLS`, the warp caster's; 0 reads the grid at the sample).
    jitter : bool
        Offset each pixel's first sample by a fraction of a step (default True):
        interleaved gradient noise, different in neighbouring pixels and fixed to the
        screen, instead of the wood-grain terraces that one offset for all pixels draws at
        sharp surfaces. ``False``: samples at step midpoints, as the warp caster with
        ``jitter=False``, and no accumulation.
    accumulate : int
        Frames averaged while the view rests (default :data:`ACCUMULATE`; 0: every
        render shows one frame). Each render after the first with an unchanged camera,
        window, scene and data adds a frame with the next offset of each pixel's
        sequence; any change starts again (:mod:`vtkillum.mappers.accumulation`). In a
        window with an interactor the frames are added by a timer; off screen, each
        ``Render()`` adds one, or :meth:`refine` renders until the mean has converged.
    interactive_step : float
        Sample-distance factor while the view moves in an interactive window (default
        :data:`INTERACTIVE_STEP`; see :attr:`interactive_step`).
    interactive_near_cells : float or None
        Near-field march while the view moves in an interactive window (default
        :data:`INTERACTIVE_NEAR_CELLS`: 0; see :attr:`interactive_near_cells`).
    interactive_image_sample_distance : float
        Pixels per ray along x and y while the view moves in an interactive window
        (default :data:`INTERACTIVE_IMAGE_SAMPLE_DISTANCE`; see
        :attr:`interactive_image_sample_distance`).
    device_upload : bool
        Write light grids that are warp arrays (on a GPU, or warp's CPU device) straight
        into VTK's textures (default True; see :attr:`device_upload`).

    Notes
    -----
    Radiance is written linearly (no gamma), premultiplied, over the renderer's
    background; with ``exposure = 1`` a pixel's value is the radiance in the lights'
    irradiance units per steradian, clipped to [0, 1]. The camera is VTK's; the
    scene's camera is not used.

    Examples
    --------
    >>> volume = IlluminatedVolume(image, scene, illumination=light_filter.GetOutputPort())
    >>> renderer.AddVolume(volume)            # or: plotter.add_actor(volume)
    """

    def __init__(self, data, scene: Scene | None = None, illumination=None,
                 array_name: str | None = None, exposure: float = 1.0,
                 near_cells: float = NEAR_CELLS, jitter: bool = True,
                 accumulate: int = ACCUMULATE,
                 interactive_step: float = INTERACTIVE_STEP,
                 interactive_near_cells: float | None = INTERACTIVE_NEAR_CELLS,
                 interactive_image_sample_distance: float = INTERACTIVE_IMAGE_SAMPLE_DISTANCE,
                 device_upload: bool = True) -> None:
        super().__init__()
        self.inputs = IlluminationInputs()
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
        self.mapper.SetInputConnection(OPTICS_PORT, self.inputs.GetOutputPort())
        for port, image in ((DATA_PORT, self.inputs.data_image),
                            (DIRECT_PORT_A, self.inputs.direct_images[0]),
                            (DIRECT_PORT_B, self.inputs.direct_images[1]),
                            (SCATTERED_PORT, self.inputs.scattered_image)):
            self.mapper.SetInputDataObject(port, image)
        self.SetMapper(self.mapper)
        self.volumes = []
        for port in range(5):
            volume = vtkVolume()
            prop = vtkVolumeProperty()
            # vtkMultiVolume takes 1-component inputs as independent, 4-component as not.
            prop.SetIndependentComponents(port == DATA_PORT)
            prop.SetInterpolationTypeToLinear()
            prop.ShadeOff()
            volume.SetProperty(prop)
            self.SetVolume(volume, port)
            self.volumes.append(volume)
        shader = self.GetShaderProperty()
        self.inputs.shader_property = shader
        self.inputs.declare((False, True, False))
        shader.AddFragmentShaderReplacement("//VTK::Shading::Init", True, GLSL_RAY_INIT, False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Impl", True, GLSL_SAMPLE, False)
        self.inputs.uniforms = shader.GetFragmentCustomUniforms()
        self._exposure = 1.0
        self.exposure = exposure
        self.jitter = jitter
        self._accumulate = 0
        self.accumulate = accumulate
        self.interactive_step = interactive_step
        self._interactive_near_cells = None
        self.interactive_near_cells = interactive_near_cells
        self.interactive_image_sample_distance = interactive_image_sample_distance
        self.set_frame(0, False)
        # Attach the renderers that show this volume to their accumulator at each render
        # (a weak reference: the mapper must not keep its volume alive).
        weak = vtkWeakReference()
        weak.Set(self)
        self.mapper.AddObserver(vtkCommand.VolumeMapperRenderStartEvent,
                                lambda caller, event: _attach_renderers(weak.Get()))
        self._scene = None
        self._ready = False
        #: ``relight(scene)`` -> illumination (anything :meth:`set_illumination` takes), or
        #: None: called by :meth:`set_scene` when the scene's light-relevant parts change.
        self.relight = None
        self.near_cells = near_cells
        self.device_upload = device_upload
        self.set_scene(scene if scene is not None else Scene())
        self.set_illumination(illumination)
        self._ready = True

    # --- scene ----------------------------------------------------------------------------------
    @property
    def scene(self) -> Scene:
        """The scene last set (read-only: change it with :meth:`set_scene`)."""
        return self._scene

    def set_scene(self, scene: Scene) -> None:
        """Take transfer function, unit distance, albedo, ``g``, lights, shading and step size.

        Data-dependent defaults (transfer-function ramp, unit distance = mean spacing,
        step = half the smallest spacing) are resolved on the current data. The light
        grids are recomputed only with :attr:`relight` set (pyvista's
        ``add_illuminated_volume`` sets it for a named illumination): then a change of
        the transfer function, unit distance, albedo, ``g`` or lights gives
        ``relight(scene)`` to :meth:`set_illumination`. Otherwise they are what
        :meth:`set_illumination` was given: after such an edit compute them again (e.g.
        ``light_transmittance(..., on_device=True)``) and pass them on, or give an
        illumination filter's output port, whose own transfer function you edit.
        """
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a vtkillum Scene, got {type(scene).__name__}")
        shading_terms(scene.shading)
        if len(scene.lights) > MAX_LIGHTS:
            raise ValueError(
                f"the OpenGL mapper takes at most {MAX_LIGHTS} lights, the scene has "
                f"{len(scene.lights)}; render with the compute path (ComputeVolumeRenderer)"
            )
        relight = self._ready and self.relight is not None and \
            _lighting_key(self._scene) != _lighting_key(scene)
        relit = self.relight(scene) if relight else None  # first: an error changes nothing
        grid = self._grid_summary()
        apply_scene_to_volume_property(scene, grid, self.volumes[DATA_PORT].GetProperty())
        self.mapper.SetSampleDistance(scene.resolved_step_size(grid))
        self._scene = scene
        self.inputs.set_scene(scene)
        self.Modified()
        if relight:
            self.set_illumination(relit)  # checks too
        elif self._ready:
            self.check()

    @property
    def lights(self) -> list:
        """The lights the last update shades with (the illumination's, else the scene's)."""
        self.check()
        return list(self.inputs.lights)

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

    @property
    def jitter(self) -> bool:
        """Whether each pixel's first sample is offset by a hash (see the class docstring)."""
        return self._jitter

    @jitter.setter
    def jitter(self, value: bool) -> None:
        self._jitter = bool(value)
        self.GetShaderProperty().GetFragmentCustomUniforms().SetUniformi(
            "il_jitter", int(self._jitter))
        self.Modified()

    @property
    def accumulate(self) -> int:
        """Frames averaged while the view rests (0: no accumulation)."""
        return self._accumulate

    @accumulate.setter
    def accumulate(self, value: int) -> None:
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise ValueError(f"accumulate must be a non-negative number of frames, got "
                             f"{value!r}")
        self._accumulate = int(value)
        self.Modified()

    @property
    def frames(self) -> int:
        """Frames in the mean that the (first) renderer showing this volume shows now.

        0 after a change (camera, window, scene, data), before the second render.
        """
        acc = self._accumulator()
        return acc.count if acc is not None else 0

    def refine(self, frames: int | None = None) -> int:
        """Render the window showing this volume until its mean holds ``frames`` frames.

        Default: :attr:`accumulate` frames, or fewer where a frame moved the mean by at
        most half an 8-bit level (a view the offsets hardly change; the mean is complete).
        For off-screen windows and scripts (an interactive window refines by itself
        while the camera rests). Returns the frames in the mean.
        """
        acc = self._accumulator(create=True)
        if acc is None:
            raise ValueError("the volume is in no renderer: add it (renderer.AddVolume, "
                             "plotter.add_actor) first")
        return acc.refine(frames)

    def set_frame(self, index: int, hold: bool, moving: bool = False) -> None:
        """Sample with the offsets of accumulation frame ``index``; ``hold``: draw nothing;
        ``moving``: the view moves in an interactive window (sample distance times
        :attr:`interactive_step`, image sample distance
        :attr:`interactive_image_sample_distance`, near field
        :attr:`interactive_near_cells`).

        Called by the renderer's :class:`~vtkillum.mappers.accumulation.FrameAccumulator`
        before each render; changes no modification time.
        """
        uniforms = self.GetShaderProperty().GetFragmentCustomUniforms()
        uniforms.SetUniformi("il_frame", int(index))
        uniforms.SetUniformi("il_hold", int(bool(hold)))
        interactive = moving and self._jitter
        # a changed image sample distance modifies the mapper, but the accumulator takes its
        # key after this call, so it starts no new mean
        self.sample_for(interactive, uniforms)
        near_scale = 1.0
        if interactive and self._interactive_near_cells is not None and self.near_cells > 0:
            near_scale = self._interactive_near_cells / self.near_cells
        uniforms.SetUniformf("il_nearScale", float(near_scale))

    @property
    def interactive_near_cells(self) -> float | None:
        """Near-field march of the frames drawn while the view moves, in transmittance-grid
        cells (default :data:`INTERACTIVE_NEAR_CELLS`, 0: read the grid at the sample while
        moving; ``None``: :attr:`near_cells`, as at rest).

        Like :attr:`interactive_step`, it applies only to the frames of a drag; the frames
        drawn at rest march :attr:`near_cells`. What it saves and costs is in the module docstring.
        """
        return self._interactive_near_cells

    @interactive_near_cells.setter
    def interactive_near_cells(self, value: float | None) -> None:
        if value is not None:
            value = float(value)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"interactive_near_cells must be None or a non-negative "
                                 f"number of light-grid cells, got {value}")
        self._interactive_near_cells = value

    @property
    def skip_empty(self) -> bool:
        """Leap over blocks of the data whose samples are all empty (default True; the
        picture is the same, see the module docstring)."""
        return self.inputs.skip_empty

    @skip_empty.setter
    def skip_empty(self, value: bool) -> None:
        self.inputs.skip_empty = bool(value)
        self.inputs.Modified()
        self.Modified()

    @property
    def illumination_16bit(self) -> bool:
        """Keep illumination grids as 16-bit fixed point (default True) or float32."""
        return self.inputs.illumination_16bit

    @illumination_16bit.setter
    def illumination_16bit(self, value: bool) -> None:
        if bool(value) != self.inputs.illumination_16bit:
            self.inputs.illumination_16bit = bool(value)
            self.inputs._light_key = None  # re-pack the grids
            self.inputs.Modified()
            self.Modified()

    def content_mtime(self) -> int:
        """Latest modification of anything that changes this volume's picture.

        The volume, mapper and properties, the shader, the inputs stage, its input data
        and the textures (data, illumination, optics table); not the per-frame uniforms
        of :meth:`set_frame`. The accumulator starts again when it grows.
        """
        inputs = self.inputs
        objects = [self, self.mapper, self.GetShaderProperty(), inputs,
                   inputs.GetOutputDataObject(0), inputs.data_image, *inputs.direct_images,
                   inputs.scattered_image]
        for port in range(inputs.GetNumberOfInputPorts()):
            if inputs.GetNumberOfInputConnections(port):
                objects.append(inputs.GetInputDataObject(port, 0))
        for volume in self.volumes:
            objects += [volume, volume.GetProperty()]
        return max(o.GetMTime() for o in objects if o is not None)

    def _accumulator(self, create: bool = False):
        """The accumulator of the first renderer showing this volume (None: none)."""
        for i in range(self.GetNumberOfConsumers()):
            consumer = self.GetConsumer(i)
            if consumer is not None and consumer.IsA("vtkRenderer"):
                return accumulator_for(consumer) if create else existing_accumulator(consumer)
        return None

    @property
    def near_cells(self) -> float:
        """Exact near-field march in transmittance-grid cells (0: read the grid at the sample)."""
        return self.inputs.near_cells

    @near_cells.setter
    def near_cells(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"near_cells must be a non-negative number of light-grid cells, "
                             f"got {value}")
        self.inputs.set_near_cells(value)
        self.Modified()

    # --- illumination ----------------------------------------------------------------------------
    def set_illumination(self, source) -> None:
        """Set where the light comes from.

        Parameters
        ----------
        source : IlluminationVolume, ndarray, vtkImageData, vtkAlgorithmOutput, vtkAlgorithm or None
            * :class:`~vtkillum.core.illumination.IlluminationVolume` (per-light
              transmittance for the scene's lights and/or scattered fluence; an
              ``(nx, ny, nz, 3)`` array is a scattered fluence) covering the data's box:
              used as is; call ``set_illumination`` again after editing it in place.
            * image data covering the same box as the data (any resolution) with the
              point arrays of :mod:`vtkillum.io.illumination_arrays` (``transmittance``
              and ``scattered_fluence``, or only ``fluence``, taken as an isotropic
              scattered fluence) and, optionally, the lights as field data; or a
              pipeline connection producing it (e.g. an illumination filter's output
              port): followed through the pipeline, so new outputs, time steps and edits
              (``array.Modified()``) re-upload the textures on the next render.
            * ``None``: unshadowed direct light, ``T_l = 1`` (with the phase function).
        """
        self.inputs.set_illumination(source)
        self.Modified()
        self.check()

    def set_time(self, time: float) -> None:
        """Render time step ``time``: requested from the data and the illumination pipelines.

        Later renders keep asking for that time; each new time re-executes the
        pipeline and re-uploads the textures, a time already shown does not.
        """
        self.inputs.UpdateTimeStep(float(time))
        self.Modified()
        self.check()

    def check(self) -> None:
        """Bring the inputs up to date and raise the error they met, if any.

        Errors inside the pipeline (an illumination grid that does not cover the data,
        missing arrays, too many lights, ...) are otherwise only printed when VTK renders.
        """
        self.inputs.Update()
        if self.inputs.last_error is not None:
            raise self.inputs.last_error

    # --- helpers -------------------------------------------------------------------------------
    def _grid_summary(self) -> GridSummary:
        image = self.inputs.GetInputDataObject(0, 0)
        scalars = rendered_point_array(image, self.inputs.GetArrayName())
        return GridSummary(image, scalars)


def _lighting_key(scene) -> bytes | None:
    """What of ``scene`` a light method's result depends on (transfer function, unit
    distance, albedo, g, lights), as comparable bytes."""
    import pickle

    if scene is None:
        return None
    return pickle.dumps((scene.transfer_function, scene.opacity_unit_distance,
                         float(scene.albedo), float(scene.anisotropy), list(scene.lights)))


def _attach_renderers(volume) -> None:
    """Give every renderer showing ``volume`` its accumulator (once per renderer)."""
    if volume is None:
        return
    for i in range(volume.GetNumberOfConsumers()):
        consumer = volume.GetConsumer(i)
        if consumer is not None and consumer.IsA("vtkRenderer"):
            accumulator_for(consumer)


class IlluminationInputs(VTKPythonAlgorithmBase):
    """Lay the data, the optical model and an illumination volume out as textures.

    Input port 0: the data (``vtkImageData``, point scalars or ``ArrayName``). Input
    port 1 (optional): image data with illumination arrays covering the same box, at
    any resolution (:mod:`vtkillum.io.illumination_arrays`). Without port 1 the
    illumination is the object set with :meth:`set_illumination`, or else unshadowed.

    Output port 0: the colour and σt tables (``64 × m × 2`` points, 4 float32
    components, stretched over the data's box). The other textures are images kept
    as attributes and refreshed only when their source changed: :attr:`data_image`
    (the scalar as float32), :attr:`direct_images` (two images of 4 transmittance
    channels each) and :attr:`scattered_image` (``φ_s`` RGB + 0). The shader uniforms
    (:data:`UNIFORMS`) are written to :attr:`uniforms` (a ``vtkUniforms``). Time
    requests reach both inputs; port 1 is always requested whole.
    """

    def __init__(self) -> None:
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=2, inputType="vtkImageData",
                                        nOutputPorts=1, outputType="vtkImageData")
        self.data_image = vtkImageData()
        self.direct_images = (vtkImageData(), vtkImageData())
        self.scattered_image = vtkImageData()
        _empty_start_image(self.data_image, 1)
        for image in (*self.direct_images, self.scattered_image):
            _empty_start_image(image)
        #: vtkUniforms receiving the parameters (set by the volume).
        self.uniforms = None
        #: vtkShaderProperty whose declarations follow the variant (set by the volume).
        self.shader_property = None
        #: (phong, direct, scattered) the declarations were compiled for.
        self.variant = None
        self._declared = None  # (variant, lights, direct lights) of the declarations
        #: The error of the last RequestData, or None.
        self.last_error = None
        #: Lights of the last update (the illumination's or the scene's).
        self.lights = []
        #: IlluminationVolume of the last update (None: unshadowed).
        self.illumination = None
        self.near_cells = NEAR_CELLS
        self._array_name = None
        self._scene = Scene()
        self._illumination = None
        self._illumination_version = 0
        #: Leap over blocks whose samples are all empty (the image is the same).
        self.skip_empty = True
        #: Store illumination grids as 16-bit fixed point (True) or float32 (False).
        self.illumination_16bit = True
        #: TextureWriter of device-resident grids (None: every grid goes through the host;
        #: see IlluminatedVolume.device_upload).
        self.writer = None
        self._data_key = None
        self._light_key = None
        self._volume = None
        self._blocks = None
        # layout uniforms of the grid images (16-bit factors, axis order)
        self._texture_uniforms = {"il_taQ": [1.0] * 4, "il_tbQ": [1.0] * 4,
                                  "il_scQ": [1.0] * 4, "il_zMajor": [1.0] * 4}

    def FillInputPortInformation(self, port, info):
        info.Set(vtkAlgorithm.INPUT_REQUIRED_DATA_TYPE(), "vtkImageData")
        if port == 1:
            info.Set(vtkAlgorithm.INPUT_IS_OPTIONAL(), 1)
        return 1

    # --- properties ----------------------------------------------------------------------------
    def SetArrayName(self, name: str | None) -> None:
        if name != self._array_name:
            self._array_name = name
            self._data_key = None
            self.Modified()

    def GetArrayName(self) -> str | None:
        return self._array_name

    def set_scene(self, scene: Scene) -> None:
        """Optical model, anisotropy, shading and default lights of the next update."""
        self._scene = scene
        self.Modified()

    def set_near_cells(self, value: float) -> None:
        if value != self.near_cells:
            self.near_cells = float(value)
            self.Modified()

    def set_illumination(self, source) -> None:
        """An IlluminationVolume/array, image data, a pipeline connection, or None."""
        if source is None or isinstance(source, (IlluminationVolume, np.ndarray)):
            if isinstance(source, np.ndarray):
                source = _as_fluence_array(source)
            self.SetInputConnection(1, None)
            self._illumination = source
        else:
            connect_input(self, 1, source, "illumination")
            self._illumination = None
        self._illumination_version += 1
        self.Modified()

    # --- pipeline ----------------------------------------------------------------------------
    def RequestInformation(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        rows = -(-TABLE_SIZE // OPTICS_ROW)
        info.Set(SDDP.WHOLE_EXTENT(), (0, OPTICS_ROW - 1, 0, rows - 1, 0, 1), 6)
        return 1

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        # The output grid is not the inputs': always ask for all of both.
        for port in range(self.GetNumberOfInputPorts()):
            if self.GetNumberOfInputConnections(port):
                info = inInfo[port].GetInformationObject(0)
                info.Set(SDDP.UPDATE_EXTENT(), info.Get(SDDP.WHOLE_EXTENT()), 6)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        # VTK swallows exceptions raised in a pipeline pass: keep the error for the caller
        # (IlluminatedVolume.check re-raises it) and report it on VTK's output window.
        self.last_error = None
        try:
            fimage = vtkImageData.GetData(inInfo[1]) if self.GetNumberOfInputConnections(1) \
                else None
            self._update(vtkImageData.GetData(inInfo[0]), fimage, vtkImageData.GetData(outInfo))
        except (TypeError, ValueError) as err:
            self.last_error = err
            vtkOutputWindow.GetInstance().DisplayErrorText(f"IlluminationInputs: {err}\n")
            return 0
        return 1

    def _update(self, image, fimage, out) -> None:
        array = rendered_point_array(image, self._array_name)
        key = (image.GetAddressAsString("vtkImageData"), image.GetMTime(), array.GetMTime(),
               array.GetName())
        refresh_data = key != self._data_key
        if refresh_data:
            volume = volume_from_image_data(image, self._array_name, association="points")
            if min(volume.dims) < 2:
                raise ValueError(f"the data must have at least 2 points along every axis, got "
                                 f"{volume.dims}")
            self._volume = volume
        volume = self._volume
        scene = self._scene

        # The illumination and its lights.
        if fimage is not None:
            check_covers(fimage, volume)
            light_key = ("image", fimage.GetAddressAsString("vtkImageData"), fimage.GetMTime())
            previous = self.illumination
            if isinstance(previous, ImageGrids) and previous.key == light_key and \
                    not refresh_data:
                illumination = previous  # the same image: its arrays were read and checked
            else:
                illumination = ImageGrids(fimage, volume, light_key)
            lights = lights_from_field(fimage) or list(scene.lights)
        else:
            illumination = self._illumination
            if isinstance(illumination, np.ndarray):
                illumination = IlluminationVolume.for_volume(volume, illumination)
            lights = list(scene.lights)
            light_key = ("object", self._illumination_version)
        if len(lights) > MAX_LIGHTS:
            raise ValueError(f"the OpenGL mapper takes at most {MAX_LIGHTS} lights, the "
                             f"illumination has {len(lights)}; render with the compute path "
                             "(ComputeVolumeRenderer)")
        if illumination is not None:
            illumination.check_matches(volume, lights)
        light_key = (*light_key, len(lights))

        if refresh_data:
            _set_grid_image(self.data_image, volume, "scalars", volume.scalars,
                            value_range=volume.value_range)
        if refresh_data or light_key != self._light_key:
            self._set_light_images(volume, illumination, len(lights))
        self._data_key = key
        self._light_key = light_key
        self.illumination = illumination
        self.lights = lights

        # Optical model and occupancy: re-made on every execution (small: the data's
        # per-block ranges are kept while the data do not change).
        tf = scene.resolved_transfer_function(volume)
        unit = scene.resolved_unit_distance(volume)
        sigma, color, lo, hi = tf.lookup_tables(unit, volume.value_range)
        if refresh_data or self._blocks is None:
            self._blocks = BlockRanges(volume)
        occupied = self._blocks.occupied(sigma, lo, hi)
        optics = optics_rows(color, sigma, occupied)
        out.ShallowCopy(image_like(volume, shape=optics.shape[:3]))
        add_point_array(out, "optics", optics, set_active=True)
        if self.uniforms is not None:
            values = shading_uniforms(volume, scene, lights, illumination, self.near_cells,
                                      (lo, hi, len(sigma)))
            values.update(self._blocks.uniforms(self.skip_empty))
            values.update(self._texture_uniforms)
            set_uniforms(self.uniforms, values)
            _, kd, ks, _ = shading_terms(scene.shading)
            self.declare((kd > 0 or ks > 0, values["il_numDirect"] > 0,
                          values["il_hasScattered"] != 0),
                         values["il_numLights"], values["il_numDirect"])

    def declare(self, variant: tuple, lights: int = MAX_LIGHTS,
                direct_lights: int | None = None) -> None:
        """(Re)declare the shader functions for ``(phong, direct, scattered)`` and the light
        counts (see :func:`glsl_layout_dec`); a new variant or count recompiles the shader
        (VTK keeps the programs it built, so switching back is a cache hit)."""
        variant = tuple(bool(v) for v in variant)
        phong, direct, scattered = variant
        lights = int(lights)
        direct_lights = (lights if direct else 0) if direct_lights is None else int(direct_lights)
        key = (variant, lights, direct_lights)
        if key == self._declared or self.shader_property is None:
            return
        self.variant, self._declared = variant, key
        self.shader_property.AddFragmentShaderReplacement(
            "//VTK::Shading::Dec", True,
            glsl_layout_dec(phong=phong, direct=direct, scattered=scattered, lights=lights,
                            direct_lights=direct_lights) + GLSL_SHADING_DEC,
            False)

    def _set_light_images(self, volume, illumination, n_lights: int,
                          direct: bool = True) -> None:
        if direct and self._write_device_grids(illumination):
            return
        if self.writer is not None:
            self.writer.forget()  # the images (the host path) hold the grids again
        if isinstance(illumination, ImageGrids):  # VTK's order, checked while packing
            transmittance, scattered = illumination.transmittance, illumination.drawn_scattered()
            vtk_order = True
        else:  # numpy's order (checked by IlluminationVolume)
            if illumination is None:  # unshadowed: T = 1 for every light
                transmittance, scattered = np.ones((2, 2, 2, n_lights), np.float32), None
            else:
                t = illumination.transmittance
                transmittance = None if t is None else np.moveaxis(t, 0, -1)
                scattered = illumination.scattered
            vtk_order = False
        self._texture_uniforms = _upload_light_grids(self, volume, transmittance, scattered,
                                                     vtk_order)

    def writer_images(self) -> tuple[dict, None]:
        """The images :attr:`writer` may write (``port -> image``) and their formats
        (None: 16-bit RGBA, every port)."""
        return {DIRECT_PORT_A: self.direct_images[0], DIRECT_PORT_B: self.direct_images[1],
                SCATTERED_PORT: self.scattered_image}, None

    def refill_host(self) -> None:
        """Pack the light grids into the images again at the next update."""
        self._light_key = None

    def _write_device_grids(self, illumination) -> bool:
        """Schedule the grids of an IlluminationVolume that lives on a warp device for
        :attr:`writer` (straight into VTK's textures, :mod:`.texture_upload`); False where
        the host path must draw them (no writer, float32 textures, grids on the host,
        textures of another size or not made yet)."""
        writer = self.writer
        if writer is None or not self.illumination_16bit or writer.host_stale or \
                not isinstance(illumination, IlluminationVolume):
            return False
        device = illumination.resident_device()
        if device is None:
            return False
        from functools import partial

        from vtkillum.core import texels
        from vtkillum.mappers.texture_upload import Job

        jobs = {}
        uniforms = {"il_taQ": [1.0] * 4, "il_tbQ": [1.0] * 4, "il_scQ": [1.0] * 4,
                    "il_zMajor": [1.0] * 4}  # z-major textures, as the host path makes them
        t = illumination.device_transmittance(device)
        if t is not None:
            size = tuple(int(n) for n in t.shape[1:][::-1])
            for half, port in enumerate((DIRECT_PORT_A, DIRECT_PORT_B)):
                lights = list(range(4 * half, min(4 * half + 4, t.shape[0])))
                if lights:
                    jobs[port] = Job(size, device,
                                     partial(texels.pack_transmittance, t, lights))
        s = illumination.device_scattered(device)
        if s is not None:
            tops = texels.fluence_tops(s)
            uniforms["il_scQ"] = texels.fluence_factors(tops)
            jobs[SCATTERED_PORT] = Job(tuple(int(n) for n in s.shape[::-1]), device,
                                       partial(texels.pack_fluence, s, tops=tops))
        if not jobs or not all(writer.can_write(port, job.size) for port, job in jobs.items()):
            return False
        for port, job in jobs.items():
            writer.schedule(port, job)
        # ports without a job keep their texels: this illumination's shader variant does
        # not read them
        self._texture_uniforms = uniforms
        return True

    def _host_fallback(self, ports) -> None:
        """A scheduled texture write failed (at the render's start): put the grids on the
        host path, in time for VTK to upload them in this render."""
        if self._volume is None:
            return
        self._set_light_images(self._volume, self.illumination, len(self.lights),
                               direct=False)
        if self.uniforms is not None:
            set_uniforms(self.uniforms, self._texture_uniforms)


def _upload_light_grids(inputs, volume: Volume, transmittance, scattered,
                        vtk_order: bool) -> dict:
    """Pack the per-light transmittance (``[..., light]``) and the scattered fluence
    (``[..., c]``, c 1 or 3) into ``inputs``' images (placeholders for what is absent);
    returns their layout uniforms. ``vtk_order``: the grids are a VTK array's memory
    (``[z, y, x, c]``, checked as they are packed), else numpy's (``[x, y, z, c]``)."""
    sixteen = inputs.illumination_16bit
    # Placeholders cover the data's box too: the ray caster marches the union of all
    # inputs' boxes.
    placeholder = np.zeros((2, 2, 2, 4), np.float32)
    layout = 0.0 if vtk_order else 1.0
    uniforms = {"il_taQ": [1.0] * 4, "il_tbQ": [1.0] * 4, "il_scQ": [1.0] * 4,
                "il_zMajor": [1.0, layout, layout, layout]}
    n = 0 if transmittance is None else transmittance.shape[-1]
    for half, (target, key) in enumerate(zip(inputs.direct_images, ("il_taQ", "il_tbQ"))):
        if n <= 4 * half:
            _set_grid_image(target, volume, "unused", placeholder)
            continue
        uniforms[key] = _set_grid_image(
            target, volume, "transmittance", transmittance, pack=(sixteen, True),
            vtk_order=vtk_order, channels=list(range(4 * half, min(4 * half + 4, n))),
            check="transmittance" if vtk_order else None)
    if scattered is None:
        _set_grid_image(inputs.scattered_image, volume, "unused", placeholder)
    else:
        uniforms["il_scQ"] = _set_grid_image(
            inputs.scattered_image, volume, "scattered_fluence", scattered,
            pack=(sixteen, False), vtk_order=vtk_order,
            channels=[0, 0, 0] if scattered.shape[-1] == 1 else [0, 1, 2],
            check="fluence" if vtk_order else None)
    return uniforms


# --- uniforms --------------------------------------------------------------------------------------
def shading_uniforms(volume: Volume, scene: Scene, lights, illumination, near_cells: float,
                     table: tuple) -> dict:
    """Values of the uniforms of :data:`UNIFORMS` for a volume, scene and lights.

    Parameters
    ----------
    volume : Volume
        The data (local frame, spacing, value range).
    scene : Scene
        Albedo, anisotropy, shading.
    lights : sequence of lights
        The lights shaded with (at most :data:`MAX_LIGHTS`).
    illumination : IlluminationVolume or None
        ``None``: unshadowed direct light for every light.
    near_cells : float
        Near-field march in cells of the transmittance grid.
    table : (lo, hi, size)
        Data range and entry count of the optics table.

    Returns
    -------
    dict
        ``name -> value`` (floats, ints, lists), for :func:`set_uniforms`.
    """
    lo, hi, size = table
    ka, kd, ks, shininess = shading_terms(scene.shading)
    kinds, vecs, rgb = pack_lights(lights, volume.direction, volume.origin)
    packed = np.zeros((MAX_LIGHTS, 4), np.float64)
    colours = np.zeros((MAX_LIGHTS, 3), np.float64)
    radii = np.zeros(MAX_LIGHTS, np.float64)
    packed[: len(kinds), 0] = np.where(kinds == DIRECTIONAL, 0.0, 1.0)
    packed[: len(kinds), 1:] = vecs
    colours[: len(kinds)] = rgb
    radii[: len(kinds)] = [resolved_radius(light, volume) for light in lights]
    if illumination is None:
        n_direct, near, has_scattered = len(lights), 0.0, 0
    else:
        n_direct = illumination.n_lights
        if isinstance(illumination, ImageGrids):
            has_scattered = int(illumination.has_scattered)
            shape = illumination.transmittance_shape
            shape = None if shape is None else shape[1:]
        else:  # shapes only: reading the grids would download those living on a device
            has_scattered = int(illumination.has("scattered"))
            shape = illumination.transmittance_shape
        near = 0.0
        if shape is not None:
            spacing = illumination.extent / (np.asarray(shape) - 1)
            near = float(near_cells) * float(spacing.max())
    axes = np.asarray(volume.direction, np.float64)
    return {
        "il_origin": [float(v) for v in volume.origin],
        "il_axis0": [float(v) for v in axes[:, 0]],
        "il_axis1": [float(v) for v in axes[:, 1]],
        "il_axis2": [float(v) for v in axes[:, 2]],
        "il_extent": [float(v) for v in volume.extent],
        "il_spacing": [float(v) for v in volume.spacing],
        "il_tableLo": float(lo),
        "il_tableScale": float((size - 1) / (hi - lo)),
        "il_tableSize": int(size),
        "il_albedo": float(scene.albedo),
        "il_g": float(scene.anisotropy),
        "il_shading": [float(ka), float(kd), float(ks), float(shininess)],
        "il_gradEps": float(gradient_threshold(volume)),
        "il_numLights": len(kinds),
        "il_numDirect": int(n_direct),
        "il_lights": packed.reshape(-1).tolist(),
        "il_lightRGB": colours.reshape(-1).tolist(),
        "il_lightRadius": radii.tolist(),
        "il_near": float(near),
        "il_hasScattered": has_scattered,
    }


def set_uniforms(uniforms, values: dict) -> None:
    """Write :func:`shading_uniforms`' values to a ``vtkUniforms``."""
    for name, value in values.items():
        if isinstance(value, int):
            uniforms.SetUniformi(name, value)
        elif isinstance(value, float):
            uniforms.SetUniformf(name, value)
        elif len(value) == 3 and name not in ("il_lights", "il_lightRGB", "il_lightRadius"):
            uniforms.SetUniform3f(name, value)
        elif name in ("il_shading", "il_zMajor") or name.endswith("Q"):
            uniforms.SetUniform4f(name, value)
        else:
            uniforms.SetUniform1fv(name, len(value), value)


# --- host helpers ----------------------------------------------------------------------------------
def optics_rows(color: np.ndarray, sigma_t: np.ndarray,
                occupied: np.ndarray | None = None) -> np.ndarray:
    """The colour and σt tables (and the occupancy) as a 4-component float32 image.

    The shape is ``(OPTICS_ROW, rows, 2, 4)`` (both z slices alike), in three parts:

    * entry ``i`` (colour RGB, σt) is the texel ``(i % OPTICS_ROW, i // OPTICS_ROW)``, so
      the two entries around a value are two fetches;
    * then σt alone: texel ``j`` holds ``(σt[2j], σt[2j+1], σt[2j+2], 0)``, so both ends of
      the interval ``[i, i + 1]`` (``j = i // 2``) are one fetch (the shadow marches);
    * with ``occupied`` (one flag per block, x fastest: :meth:`BlockRanges.occupied`), four
      flags a texel: flag ``k`` in component ``k % 4`` of texel ``k // 4`` (1 or 0).

    Each part starts on a new row; texel ``t`` of a part is ``(t % OPTICS_ROW, first row +
    t // OPTICS_ROW)``.
    """
    n = int(sigma_t.shape[0])
    entries = np.zeros((n, 4), dtype=np.float32)
    entries[:, :3] = color
    entries[:, 3] = sigma_t
    pairs = np.zeros((-(-n // 2), 4), dtype=np.float32)
    padded = np.concatenate([np.asarray(sigma_t, np.float32), np.zeros(2, np.float32)])
    for c in range(3):
        pairs[:, c] = padded[c: c + 2 * len(pairs): 2][: len(pairs)]
    parts = [entries, pairs]
    if occupied is not None:
        flags = np.asarray(occupied, bool).reshape(-1, order="F").astype(np.float32)
        occ = np.zeros((-(-flags.size // 4), 4), np.float32)
        occ.reshape(-1)[: flags.size] = flags
        parts.append(occ)
    rows = []
    for part in parts:
        grid = np.zeros((-(-len(part) // OPTICS_ROW) * OPTICS_ROW, 4), np.float32)
        grid[: len(part)] = part
        rows.append(grid.reshape(-1, OPTICS_ROW, 4).transpose(1, 0, 2))  # [t % row, t // row]
    grid = np.concatenate(rows, axis=1)
    return np.ascontiguousarray(np.repeat(grid[:, :, None, :], 2, axis=2))


#: Most occupancy blocks (256 per image row; llvmpipe takes 3D textures up to 2048 rows).
MAX_BLOCKS = 256 * 1024


class BlockRanges:
    """Per-block data ranges, for leaping over blocks whose samples are all empty.

    Block ``b`` covers the cells ``[b B, (b + 1) B]`` of each axis (``B`` points: 8, or
    more so that there are at most :data:`MAX_BLOCKS`), i.e. every point a trilinear
    sample inside it interpolates. One pass over the data when they change (kept while
    they do not); a transfer-function edit only re-reads the small ranges.
    """

    def __init__(self, volume: Volume) -> None:
        dims = np.asarray(volume.dims)
        size = 8
        while np.prod(-(-(dims - 1) // size)) > MAX_BLOCKS:
            size *= 2
        self.size = size
        self.count = -(-(dims - 1) // size)
        self.block_extent = np.asarray(volume.spacing, np.float64) * size
        a = np.asarray(volume.scalars, np.float32)
        lo, hi = a, a
        for axis in range(3):
            lo = _block_reduce(lo, size, axis, np.minimum)
            hi = _block_reduce(hi, size, axis, np.maximum)
        self.lo, self.hi = lo, hi
        self.nan = ~(np.isfinite(lo) & np.isfinite(hi))

    def occupied(self, sigma_t: np.ndarray, lo: float, hi: float) -> np.ndarray:
        """True where a sample in the block may have σt > 0 (table of ``len(sigma_t)``
        entries over ``[lo, hi]``, interpolated linearly as the shader does); a margin of
        one entry on each side keeps it conservative."""
        n = int(sigma_t.shape[0])
        scale = (n - 1) / (hi - lo) if hi > lo else 0.0
        nonzero = np.concatenate([[0], np.cumsum(np.asarray(sigma_t) > 0)])

        def index(v):
            return np.clip(np.floor((np.nan_to_num(v).astype(np.float64) - lo) * scale),
                           0, n - 1).astype(np.int64)

        i0 = np.clip(index(self.lo) - 1, 0, n - 1)
        i1 = np.clip(index(self.hi) + 2, 0, n - 1)
        return (nonzero[i1 + 1] - nonzero[i0] > 0) | self.nan

    def uniforms(self, enabled: bool) -> dict:
        return {"il_skip": int(bool(enabled)),
                "il_blockSize": [float(v) for v in self.block_extent],
                "il_blockCount": [float(v) for v in self.count]}


def _block_reduce(a: np.ndarray, size: int, axis: int, fn) -> np.ndarray:
    """``fn`` over the points ``[b size, min((b + 1) size, n - 1)]`` of each block along
    ``axis`` (neighbouring blocks share their border points)."""
    n = a.shape[axis]
    blocks = max(1, -(-(n - 1) // size))
    starts = np.arange(blocks) * size
    out = fn.reduceat(a, starts, axis=axis)
    if blocks > 1:
        border = np.take(a, starts[1:], axis=axis)
        head = [slice(None)] * a.ndim
        head[axis] = slice(0, blocks - 1)
        out[tuple(head)] = fn(out[tuple(head)], border)
    return out


def pack_channels(values: np.ndarray, sixteen_bit: bool, unit_range: bool = False,
                  out: np.ndarray | None = None, channels: list | None = None,
                  check: str | None = None):
    """Up to 4 channels (last axis) as a 4-component texture image and its factors.

    Returns ``(image, q)``: ``image`` float32, or uint16 with ``sixteen_bit`` (half the
    bytes of float32: texture uploads and the texture unit's reads); ``q`` (4 floats) turns
    a texel as the shader reads it back into the physical value: 1 for float32; for 16 bit,
    whose texels OpenGL normalises to ``stored / 65535``, the channel's top value, with
    ``stored = round(65535 v / top)``, ``top = 1`` for transmittances (``unit_range``,
    clipped to [0, 1]) and the channel's maximum otherwise (non-negative values): an
    absolute error of at most ``top / 131070``. ``out``: write into this array (shape
    ``values.shape[:-1] + (4,)``, the image's dtype; e.g. a VTK array's memory) instead of
    a new one. Works one slab of the first axis at a time (the temporaries stay in cache).
    ``channels``: the input channel of each output channel (default ``0 .. c-1``; e.g.
    ``[0, 0, 0]`` spreads a grey fluence over RGB). ``check``: ``"transmittance"`` (finite,
    in [0, 1]) or ``"fluence"`` (finite, non-negative) raises a ``ValueError`` for values
    outside, checked slab by slab as they are packed.
    """
    values = np.asarray(values)
    channels = list(range(values.shape[-1])) if channels is None else list(channels)
    c = len(channels)
    dtype = np.uint16 if sixteen_bit else np.float32
    shape = values.shape[:-1] + (4,)
    if out is None:
        out = np.empty(shape, dtype)
    elif out.shape != shape or out.dtype != dtype:
        raise ValueError(f"out must be {shape} {np.dtype(dtype)}, got {out.shape} {out.dtype}")
    scale, q = [1.0] * 4, [1.0] * 4
    if sixteen_bit:
        tops = [1.0] * c if unit_range else \
            [float(np.max(values[..., ch])) if values[..., 0].size else 0.0 for ch in channels]
        scale, q = texel_scales(tops)
    empty = [sixteen_bit and scale[k] == 0.0 for k in range(c)]  # stored as 0
    scale = [np.float32(v) for v in scale]
    slab = max(1, (1 << 18) // max(1, int(np.prod(shape[1:-1]))))  # ~256k points a slab
    tmp = None
    for i in range(0, shape[0], slab):
        part = out[i:i + slab]
        part[..., c:] = 0
        if check is not None:
            _check_slab(values[i:i + slab], check)
        for k in range(c):
            channel = values[i:i + slab, ..., channels[k]]
            if not sixteen_bit:
                part[..., k] = channel
                continue
            if empty[k]:
                part[..., k] = 0
                continue
            if tmp is None or tmp.shape != channel.shape:
                tmp = np.empty(channel.shape, np.float32)
            np.multiply(channel, scale[k], out=tmp)
            np.clip(tmp, 0.0, 65535.0, out=tmp)
            np.rint(tmp, out=tmp)
            part[..., k] = tmp
    return out, q


class ImageGrids:
    """An illumination image's grids as the mapper uploads them: numpy views of its VTK
    arrays in VTK's point order (``[z, y, x, c]``), neither copied nor transposed.

    An illumination filter's output holds ``transmittance`` (one channel per light) and
    ``scattered_fluence``, or a ``fluence`` (1 or 3 components;
    :mod:`vtkillum.io.illumination_arrays`). :func:`_upload_light_grids` packs them into textures in the
    same order (``il_zMajor`` 0), checking what
    :class:`~vtkillum.core.illumination.IlluminationVolume` checks (finite; transmittance in
    [0, 1], fluence non-negative) slab by slab as it packs. Converting the image to an
    ``IlluminationVolume`` instead (``illumination_from_image``) copied and transposed every
    grid and checked it in further passes: 1.07 s for a 256³ transmittance and scattered
    fluence on the development machine, before any packing.
    """

    def __init__(self, image, volume: Volume, key) -> None:
        pd = image.GetPointData()
        dims = tuple(int(n) for n in image.GetDimensions())
        if min(dims) < 2:
            raise ValueError(f"the illumination image needs at least 2 points along every "
                             f"axis to be interpolated, got {dims}")
        #: The image's identity and modification time when read.
        self.key = key
        #: The box covered (the caller checked that it is the data's).
        self.extent = np.asarray(volume.extent, np.float64)
        self.transmittance = None
        self.scattered = None
        t_name, name = illumination_array_names(image)
        if t_name is not None:
            self.transmittance = _vtk_order_view(pd.GetArray(t_name), dims, t_name)
        if name is not None:
            values = _vtk_order_view(pd.GetArray(name), dims, name)
            if values.shape[-1] not in (1, 3):
                raise ValueError(f"the {name!r} array must have 1 (grey) or 3 (RGB) "
                                 f"components, got {values.shape[-1]}")
            self.scattered = values
        t = self.transmittance
        #: Lights with a transmittance channel.
        self.n_lights = 0 if t is None else int(t.shape[-1])
        #: ``(n_lights, nx, ny, nz)`` of the transmittance, or None.
        self.transmittance_shape = None if t is None else (self.n_lights, *dims)
        #: Whether a scattered fluence is drawn (an all-zero one beside a transmittance is
        #: not: :meth:`drawn_scattered` decides).
        self.has_scattered = self.scattered is not None

    def check_matches(self, volume, lights=None) -> None:
        """Raise ``ValueError`` unless the transmittance has one channel per light."""
        if lights is not None and self.transmittance is not None and \
                self.n_lights != len(lights):
            raise ValueError(
                f"the illumination volume has transmittance for {self.n_lights} light(s) but "
                f"the scene has {len(lights)}; compute it with the scene's lights")

    def drawn_scattered(self):
        """The scattered fluence to draw: None for an all-zero one beside a transmittance
        (a transmittance-only method's output); sets :attr:`has_scattered`."""
        values = self.scattered
        if values is not None and self.transmittance is not None and values.size and \
                not float(values.max()) > 0:
            values = None
        self.has_scattered = values is not None
        return values


def _vtk_order_view(array, dims: tuple, name: str) -> np.ndarray:
    """A VTK point array as a numpy view ``[z, y, x, c]`` (VTK's point order)."""
    values = vtk_to_numpy(array)
    if values.dtype.kind not in "biuf":
        raise ValueError(f"the {name!r} array must hold real numbers, got {values.dtype}")
    if values.shape[0] != int(np.prod(dims)):
        raise ValueError(f"the {name!r} array has {values.shape[0]} values, the image "
                         f"{int(np.prod(dims))} points")
    return values.reshape(dims[::-1] + (-1,))


def _check_slab(values: np.ndarray, what: str) -> None:
    """The checks of :class:`~vtkillum.core.illumination.IlluminationVolume` on a slab."""
    if not np.all(np.isfinite(values)):
        raise ValueError(f"illumination {what} contains NaN or Inf values")
    if values.size and float(values.min()) < 0:
        raise ValueError(f"illumination {what} must be non-negative (minimum "
                         f"{float(values.min()):g})")
    if what == "transmittance" and values.size and float(values.max()) > 1 + 1e-5:
        raise ValueError("illumination transmittance must lie in [0, 1]")


def _set_grid_image(target: vtkImageData, volume: Volume, name: str, values,
                    pack: tuple | None = None, value_range: tuple | None = None,
                    vtk_order: bool = False, **pack_options):
    """Give ``target`` the grid ``values`` (``[x, y, z(, c)]``, covering the data's box) as
    its active scalars, **without transposing**: the image's axes are (z, y, x), so numpy's
    C order (z fastest) is VTK's point order; the shader reads it with ``.zyx``
    (``il_zMajor``). ``vtk_order``: ``values`` are ``[z, y, x(, c)]`` (a VTK array's memory)
    and the image's axes are (x, y, z).

    ``pack``: ``(sixteen_bit, unit_range)`` packs ``values`` (last axis: channels) with
    :func:`pack_channels` straight into the VTK array's memory and returns the factors
    ``q``; otherwise ``values`` are copied as float32 (or uint16).

    The array's range is declared (16 bit: the type's; otherwise ``value_range`` when given)
    so that VTK's texture upload does not scan the whole array for it: the shader reads
    texels as they are, not through the scale and bias VTK derives from the range.
    """
    values = np.asarray(values)
    shape = values.shape[:3]
    box = (np.asarray(volume.dims) - 1) * volume.spacing  # the data's box (local frame)
    dims = shape[::-1]  # z-major: the image's axes are (z, y, x); VTK order: (x, y, z)
    if pack is not None:
        dtype, comps = (np.uint16 if pack[0] else np.float32), 4
    else:
        dtype = np.uint16 if values.dtype == np.uint16 else np.float32
        comps = 1 if values.ndim == 3 else values.shape[3]
    vtk_type = VTK_UNSIGNED_SHORT if dtype == np.uint16 else VTK_FLOAT
    # The image's array of the last grid is written again when it fits: a new one of a
    # 512³ grid's gigabyte costs more to fault in than the packing that fills it.
    array = target.GetPointData().GetScalars()
    if array is None or array.GetDataType() != vtk_type or \
            array.GetNumberOfComponents() != comps or \
            array.GetNumberOfTuples() != int(np.prod(shape)):
        array = vtkUnsignedShortArray() if dtype == np.uint16 else vtkFloatArray()
        array.SetNumberOfComponents(comps)
        array.SetNumberOfTuples(int(np.prod(shape)))
    target.Initialize()
    target.SetDimensions(*(int(n) for n in dims))
    # either way the image's axis a spans the box's extent along x, y, z in turn
    target.SetSpacing(*(float(e) / (n - 1) for e, n in zip(box, dims)))
    target.SetOrigin(*(float(v) for v in volume.origin))
    target.SetDirectionMatrix(*np.asarray(volume.direction, np.float64).reshape(-1))
    array.SetName(name)
    view = vtk_to_numpy(array).reshape(shape + ((comps,) if comps > 1 or pack else ()))
    q = None
    if pack is not None:
        _, q = pack_channels(values, pack[0], unit_range=pack[1], out=view, **pack_options)
    else:
        np.copyto(view, values.reshape(view.shape), casting="unsafe")
    array.Modified()  # new values (a reused array); drops the ranges it cached
    if dtype == np.uint16:
        _declare_range(array, (0.0, 65535.0))
    elif value_range is not None:
        _declare_range(array, value_range)
    target.GetPointData().SetScalars(array)
    target.Modified()
    return q


def _declare_range(array, value_range: tuple) -> None:
    """Store ``value_range`` as every component's cached finite range of a VTK array (what
    ``GetFiniteRange`` returns until the array is modified), so that VTK does not compute it
    with a pass over the array (about 0.45 s for a 512³ four-component grid)."""
    lo, hi = (float(v) for v in value_range)
    ranges = vtkInformationVector()
    for _ in range(array.GetNumberOfComponents()):
        info = vtkInformation()
        info.Set(vtkDataArray.COMPONENT_RANGE(), (lo, hi), 2)
        ranges.Append(info)
    array.GetInformation().Set(vtkDataArray.PER_FINITE_COMPONENT(), ranges)


def _empty_start_image(image: vtkImageData, components: int = 4) -> None:
    """A 2×2×2 zero image, so the mapper has scalars before the first update."""
    image.Initialize()
    image.SetDimensions(2, 2, 2)
    array = numpy_to_vtk(np.zeros((8, components), dtype=np.float32), deep=True)
    array.SetName("empty")
    image.GetPointData().SetScalars(array)


def _as_fluence_array(array: np.ndarray) -> np.ndarray:
    a = np.asarray(array, dtype=np.float32)
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"a fluence array must have shape (nx, ny, nz, 3), got {a.shape}")
    return a


__all__ = [
    "ACCUMULATE",
    "GLSL_LAYOUT_DEC",
    "GLSL_RAY_INIT",
    "GLSL_SAMPLE",
    "GLSL_SHADING_DEC",
    "INTERACTIVE_IMAGE_SAMPLE_DISTANCE",
    "INTERACTIVE_NEAR_CELLS",
    "INTERACTIVE_STEP",
    "MAX_LIGHTS",
    "NEAR_CELLS",
    "UNIFORMS",
    "IlluminatedVolume",
    "IlluminationInputs",
    "glsl_layout_dec",
    "optics_rows",
    "set_uniforms",
    "shading_uniforms",
]
