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

``--quality`` measures instead what the picture of a still camera is worth and what it
costs, the way pyvista's ``add_illuminated_volume`` shows data (``cmap="bone"``,
``opacity="linear"``, a transmittance volume of one directional light, exposure 4π, the
default sample distance: half the smallest spacing; an isometric camera), on the
README's CT head (``builtin:ct:128``) and the MNI152 T1 template (nilearn) at full
and half resolution. Per scene it prints the error of each picture against a reference
of the same view and step (the mean of ``--reference-frames`` accumulated frames: the
value that jitter averages to), in 8-bit levels over the pixels the volume covers: RMS,
RMS after a 3 × 3 mean (what the eye integrates), 99th percentile and the share of
pixels off by 3 levels or more (speckle); and the median ms per frame, the variants
taking turns frame by frame:

* before: the white-noise hash of the first sample (one frame), and ``jitter=False``;
* after: one frame of interleaved gradient noise, and the mean of 4, 8, 16 frames
  accumulated while the camera rests (``IlluminatedVolume.accumulate``);
* ms: an interactive frame (camera turning) before and after (and the median over the
  rounds of their ratio), a still frame that adds to the mean (read back, summed,
  written back) and a frame once the mean converged.

``--interactive`` (issue 35) times, per illumination kind (the textures each method hands
``IlluminatedVolume``: transmittance; transmittance + scattered fluence for
convection-diffusion; scattered fluence alone for photon density and many-lights
fluence; default transmittance and photon density; ``ambient-scattering``: the
``AmbientScatteringVolume`` mapper, its inputs computed on the warp device) and volume size,
with ``--data ct-like`` (default: ``bench_scaling.py``'s CT-like volume, made on the device,
and its one-light scene, as the warp ray caster's figures) or ``--data phantom`` (the CT
phantom upsampled from 256³, 2 lights), light grids at ``--grid-scale`` times the data's
points (default 1, the methods' default): a camera move at full quality (still), the same
move while dragging in an interactive window (the interactor's update rate: the defaults
``interactive_step`` 2, ``interactive_image_sample_distance`` 2, ``interactive_near_cells``
0), that at every pixel, that with ``interactive_near_cells`` 0, a still move with
``near_cells`` 0, and with ``--history`` the move before issue 35's first changes (float32
grids, no leaps), with ``--tf-edit`` a TF edit to the new frame from host arrays (16-bit
grids; the method's own compute is not included; the ambient mapper recomputes its inputs,
``device_upload`` off), with ``--device-upload`` too the same edits from grids on the warp
device written straight into VTK's textures (``device_upload``; for the ambient mapper its
σ̃t and radiance cache; the writes made are counted, and the last edit's picture is
compared with the host path's: the largest 8-bit difference); and counts 3D uploads per
camera move. One table.

Measured on an NVIDIA H200 (EGL, VTK 9.7.2), 512³ CT-like, 1024², grids at full resolution
(2026-11-29, after the z-major textures and the moving defaults; ms):

====================  ======  ========  ============  ============  =======
illumination          still   dragging  dragging,     still,        TF edit
                                        every pixel   near_cells 0
====================  ======  ========  ============  ============  =======
transmittance         116.0   14.6      35.0          56.5          2561
convection-diffusion  135.2   17.7      43.5          70.0          5992
photon density        46.8    12.3      28.7          46.2          3593
ambient-scattering    376.5   119.1     372.5         --            5970
====================  ======  ========  ============  ============  =======

Earlier the same day, before them (``interactive_near_cells`` None, no image sample
distance while dragging, grids transposed on the host): dragging 67 ms with transmittance
(56 with the compiled-in light counts alone) and 30 ms with photon density; TF edit 6841 /
14188 / 8337 ms. From an earlier session, ``--data phantom --grid-scale 0.5`` (before and
after that session's shader changes):

=====  ====================  ==========  ======  ==========  ===============
data   illumination          before ms   after   moving      TF edit 16/32 b
=====  ====================  ==========  ======  ==========  ===============
256³   transmittance         221         163     61          266 / 360
256³   convection-diffusion  239         166     62          404 / 559
256³   photon density        78          33      20          121 / 166
512³   transmittance         462         350     129         1039 / 1363
512³   convection-diffusion  498         359     134         2015 / 2662
512³   photon density        161         64      37          963 / 1062
=====  ====================  ==========  ======  ==========  ===============

``--profile`` prints where the shader's time goes, as ratios to VTK's plain composite ray
caster (``vtkGPUVolumeRayCastMapper``, no shading: the floor) on the same data, step and
camera (``--data``: ``bench_scaling.py``'s CT-like volume made on the device and its scene,
or the CT phantom and its default scene; ``--size``): ``IlluminatedVolume`` without
illumination, with a scattered fluence only, with transmittance and ``near_cells`` 0 or 2,
with Phong, without leaps, and moving (with and without ``interactive_near_cells`` 0).
``--baseline FILE`` runs another version of ``illuminated_volume_mapper.py`` in the same
rounds. Measured on llvmpipe (2 shared cores: ratios only), 96³, 256², 11 rounds,
against the mapper before this change (the numbers are in that module's docstring), and
on the H200 at 512³, 1024² (``--profile --size 512 --image 1024 --frames 5``): VTK's
composite frame 59.7 ms; ratios 0.81 (scattered only, unchanged), 0.82 (no illumination;
0.96 before the light counts were compiled in), 0.96 / 1.98 (transmittance, ``near_cells``
0 / 2; 1.14 / 2.30 before), 2.74 (Phong; 3.11 before).

``--interop`` (same run): a 256³ RGBA16 grid (134 MB) from a warp array through a
registered pixel buffer into a 3D texture took 3.6 ms, through the host 137 ms (128³:
0.9 / 17.6 ms).

Examples
--------
VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow python benchmarks/bench_opengl.py
python benchmarks/bench_opengl.py --size 128 --image 512 --frames 5 --reach 0.25 1.0
python benchmarks/bench_opengl.py --quality --image 256 --datasets head mni mni-half
VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow python benchmarks/bench_opengl.py --interactive \
    --sizes 512 --image 1024
python benchmarks/bench_opengl.py --profile --data phantom --size 96 --image 256 --frames 11 \
    --baseline /tmp/old_mapper.py
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
from vtkillum.mappers import AmbientScatteringVolume, IlluminatedVolume, apply_camera_to_vtk
from vtkillum.mappers.camera_bridge import apply_scene_to_volume_property
from vtkillum.mappers.illuminated_volume_mapper import NEAR_CELLS
from vtkillum.mappers.interaction import INTERACTIVE_IMAGE_SAMPLE_DISTANCE

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


def vtk_mapper(volume, scene):
    """A composite ``vtkGPUVolumeRayCastMapper`` of ``volume`` at the scene's step, unjittered
    (what VTK's own renderers here share)."""
    mapper = vtkOpenGLGPUVolumeRayCastMapper()
    mapper.SetInputData(image_data_from_volume(volume))
    mapper.SetBlendModeToComposite()
    mapper.AutoAdjustSampleDistancesOff()
    mapper.SetSampleDistance(scene.resolved_step_size(volume))
    mapper.SetUseJittering(0)
    return mapper


def vtk_shadows(volume, scene, image_size, reach, blending):
    """:class:`Frames` for vtkGPUVolumeRayCastMapper with VTK's volumetric shadows."""
    mapper = vtk_mapper(volume, scene)
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
    frames.keep = (actor, mapper, light)  # the mapper holds its input image
    return frames


def _read(window) -> np.ndarray:
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

    grab = vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.ShouldRerenderOff()  # a render would add a frame to an accumulating volume
    grab.Update()
    out = grab.GetOutput()
    w, h, _ = out.GetDimensions()
    return vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, 3)[::-1]


# --- --quality: speckle and terraces of a still picture -----------------------------------------
#: The first-sample offset before the accumulation (commit 8ff7e48): a white-noise hash
#: (pcg2d) of the pixel, the same in every frame.
WHITE_NOISE_XI = """    if (il_jitter != 0)
    {
      uvec2 v = uvec2(gl_FragCoord.xy) + uvec2(uint(il_jitter) * 1664525u, 1013904223u);
      v = v * 1664525u + 1013904223u;
      v.x += v.y * 1664525u;
      v.y += v.x * 1664525u;
      v = v ^ (v >> 16u);
      v.x += v.y * 1664525u;
      v.y += v.x * 1664525u;
      v = v ^ (v >> 16u);
      il_xi = float(v.x >> 8u) * (1.0 / 16777216.0);
    }
"""


def white_noise_ray_init() -> str:
    """GLSL_RAY_INIT with the offset of before the accumulation (:data:`WHITE_NOISE_XI`)."""
    from vtkillum.mappers.illuminated_volume_mapper import GLSL_RAY_INIT

    start = GLSL_RAY_INIT.index("    if (il_jitter != 0)")
    end = GLSL_RAY_INIT.index("    g_dataPos +=")
    return GLSL_RAY_INIT[:start] + WHITE_NOISE_XI + GLSL_RAY_INIT[end:]


def quality_grid(name: str):
    """``(pyvista.ImageData, zoom)`` of a ``--quality`` scene."""
    import pyvista as pv

    if name == "head":
        from vtkillum.data.builtin import load_builtin
        from vtkillum.io.convert import image_data_from_volume

        return pv.wrap(image_data_from_volume(load_builtin("builtin:ct:128"))), 1.6
    if name in ("mni", "mni-half"):
        import tempfile

        from nilearn import datasets

        with tempfile.TemporaryDirectory() as tmp:
            path = f"{tmp}/mni152.nii.gz"
            datasets.load_mni152_template().to_filename(path)
            grid = pv.read(path)
        if name == "mni-half":  # every second point: 2 mm spacing
            dims = grid.dimensions
            grid = grid.extract_subset((0, dims[0] - 1, 0, dims[1] - 1, 0, dims[2] - 1),
                                       rate=(2, 2, 2))
        return grid, 1.5
    raise ValueError(f"unknown --quality dataset {name!r}; head, mni or mni-half")


def quality_scene(name: str, image_size: int):
    """A pyvista plotter showing one scene twice: ``(plotter, volumes)``, volumes keyed by
    variant (``before``: white-noise offsets, no accumulation; ``after``), one visible."""
    import pyvista as pv

    import vtkillum

    grid, zoom = quality_grid(name)
    lit = grid.illum.transmittance(vtkillum.DirectionalLight((-0.3, -1.0, -1.0), (3, 3, 3)),
                                   cmap="bone", opacity="linear")
    plotter = pv.Plotter(off_screen=True, window_size=(image_size, image_size))
    plotter.set_background("black")
    volumes = {}
    for variant in ("before", "after"):
        volumes[variant] = vtkillum.add_illuminated_volume(
            plotter, grid, illumination=lit, cmap="bone", opacity="linear", render=False)
    before = volumes["before"]
    before.accumulate = 0
    before.GetShaderProperty().AddFragmentShaderReplacement(
        "//VTK::Shading::Init", True, white_noise_ray_init(), False)
    plotter.camera_position = "iso"
    plotter.camera.zoom(zoom)
    return plotter, volumes


def _show_only(volumes, variant: str) -> None:
    for name, volume in volumes.items():
        volume.SetVisibility(name == variant)


def picture_errors(image, reference) -> tuple[float, float, float, float]:
    """Errors of ``image`` against ``reference`` (8-bit levels) over the pixels the
    reference covers: RMS, RMS after a 3 × 3 mean (the error the eye integrates: fine
    noise averages out there, terraces and clumps stay), 99th percentile, and the share
    of pixels off by 3 levels or more (speckle)."""
    covered = reference.max(axis=-1) > 2.0
    diff = image.astype(np.float64) - reference
    padded = np.pad(diff, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = diff.shape[:2]
    smooth = sum(padded[i:i + h, j:j + w] for i in range(3) for j in range(3)) / 9.0
    err = np.abs(diff)[covered].max(axis=-1)
    return (float(np.sqrt(np.mean(diff[covered] ** 2))),
            float(np.sqrt(np.mean(smooth[covered] ** 2))),
            float(np.percentile(err, 99)), float(np.mean(err >= 3.0)))


def quality(opts) -> int:
    """The ``--quality`` tables (see the module docstring)."""
    print(f"window {vtkRenderWindow().GetClassName()}, image {opts.image}^2, reference: "
          f"mean of {opts.reference_frames} accumulated frames; errors in 8-bit levels over "
          "the covered pixels; ms: median of "
          f"{opts.frames} frames, the variants taking turns")
    from vtkillum.mappers import accumulation

    accumulation.SETTLED_LEVELS = -1.0  # exactly the frames asked for, no early stop
    print("| data | picture | RMS | RMS of the 3x3 mean | p99 | pixels off by >= 3 | "
          "ms per frame |")
    print("|---|---|---|---|---|---|---|")
    for name in opts.datasets:
        plotter, volumes = quality_scene(name, opts.image)
        window = plotter.render_window
        after = volumes["after"]
        _show_only(volumes, "after")
        after.accumulate = opts.reference_frames
        after.refine()
        reference = _read(window).astype(np.float64)
        after.accumulate = 16
        pictures = {}
        _show_only(volumes, "before")
        window.Render()
        pictures["before: white-noise offsets, 1 frame"] = _read(window)
        volumes["before"].jitter = False
        window.Render()
        pictures["before and after: jitter=False"] = _read(window)
        volumes["before"].jitter = True
        _show_only(volumes, "after")
        for frames in (1, 4, 8, 16):
            after.refine(frames)  # the first render after a change is frame 0: 1 frame
            pictures[f"after: {frames} frame{'s' * (frames > 1)} (IGN"
                     f"{', accumulated' if frames > 1 else ''})"] = _read(window)
        times = _quality_times(window, plotter.renderer, volumes, opts.frames)
        rows = [(label, picture_errors(image, reference)) for label, image in pictures.items()]
        for label, (rms, smooth, p99, speckle) in rows:
            key = ("interactive, before" if label.startswith("before: white") else
                   "interactive, after" if label.startswith("after: 1 frame") else
                   "still, adding a frame" if label.startswith("after: 16") else None)
            ms = f"{times[key]:.0f} ({key})" if key else ""
            print(f"| {name} | {label} | {rms:.2f} | {smooth:.2f} | {p99:.1f} | "
                  f"{100 * speckle:.2f} % | {ms} |", flush=True)
        print(f"| {name} | after, converged (the stored mean shown) | | | | | "
              f"{times['converged']:.0f} |", flush=True)
        print(f"| {name} | interactive frame after / before (median over the rounds) | | | | | "
              f"{times['ratio']:.3f} |", flush=True)
        if opts.save:
            _save(opts.save, f"quality_{name}_reference.png", reference.astype(np.uint8))
            for i, image in enumerate(pictures.values()):
                _save(opts.save, f"quality_{name}_{i}.png", image)
        plotter.close()
    return 0


def _quality_times(window, renderer, volumes, frames: int) -> dict:
    """Median ms of interactive frames before/after (taking turns), of still frames that add
    to the mean and of frames once it converged."""
    camera = renderer.GetActiveCamera()
    turns = {"interactive, before": [], "interactive, after": []}

    def timed():
        t0 = time.perf_counter()
        window.Render()
        window.WaitForCompletion()
        return 1000.0 * (time.perf_counter() - t0)

    for i in range(frames):
        for key, variant in (("interactive, before", "before"), ("interactive, after", "after")):
            _show_only(volumes, variant)
            camera.Azimuth(1.0 if i % 2 == 0 else -1.0)
            turns[key].append(timed())
    _show_only(volumes, "after")
    timed()  # frame 0
    still = [timed() for _ in range(frames)]
    after = volumes["after"]
    after.refine()
    converged = [timed() for _ in range(frames)]
    return {**{k: statistics.median(v) for k, v in turns.items()},
            "ratio": statistics.median(a / b for a, b in zip(turns["interactive, after"],
                                                             turns["interactive, before"])),
            "still, adding a frame": statistics.median(still),
            "converged": statistics.median(converged)}


# --- --interactive: camera move and TF edit per illumination kind, sizes, GPU named -----------
#: What each illumination-volume method hands IlluminatedVolume (the frame's cost depends on
#: the textures bound and the data's sigma_t, not on the illumination's values):
#: transmittance channels, scattered fluence.
KINDS = {
    "transmittance": (True, False),
    "convection-diffusion": (True, True),
    "photon density": (False, True),
    "many-lights fluence": (False, True),
}

#: The ambient-scattering OpenGL mapper (its own inputs, computed on the warp device).
AMBIENT = "ambient-scattering"


def gl_renderer(window) -> str:
    """The OpenGL renderer string (the GPU's name) of a window that has rendered."""
    import ctypes

    from vtkillum.mappers.gl_trace import gl_function

    get = gl_function("glGetString", ctypes.c_char_p, ctypes.c_uint)
    window.MakeCurrent()
    return (get(0x1F01) or b"?").decode()  # GL_RENDERER


def upsampled_ct(size: int):
    """A CT phantom of ``size``³ points: the phantom at ``min(size, 256)`` points, upsampled
    trilinearly (torch on the GPU where there is one; the procedural phantom takes minutes
    at 512³ in numpy)."""
    base = procedural.ct_phantom(min(size, 256))
    if size <= 256:
        return base
    import dataclasses

    try:
        import torch

        dev = "cuda" if torch.cuda.is_available() else "cpu"
        t = torch.from_numpy(np.ascontiguousarray(base.scalars))[None, None].to(dev)
        up = torch.nn.functional.interpolate(t, size=(size,) * 3, mode="trilinear",
                                             align_corners=True)[0, 0].cpu().numpy()
    except ImportError:
        from scipy.ndimage import zoom

        up = zoom(base.scalars, size / base.dims[0], order=1)
    spacing = base.spacing * (base.dims[0] - 1) / (size - 1)
    return dataclasses.replace(base, scalars=np.ascontiguousarray(up, np.float32),
                               spacing=spacing)


def synthetic_illumination(volume, kind: str, lights: int = 1, scale: float = 0.5,
                           seed: int = 0):
    """An IlluminationVolume of the shape ``kind`` produces (light grid ``scale`` times the
    data's points; ``lights`` transmittance channels), with smooth positive values."""
    from vtkillum.core.illumination import IlluminationVolume

    has_t, has_s = KINDS[kind]
    shape = tuple(max(2, round(n * scale)) for n in volume.dims)
    rng = np.random.default_rng(seed)
    x = np.linspace(0.05, 1.0, shape[0], dtype=np.float32)[:, None, None]
    base = np.broadcast_to(x, shape) * np.float32(0.9 + 0.1 * rng.random())
    t = np.repeat(np.ascontiguousarray(base)[None], lights, axis=0) if has_t else None
    phi = np.stack([base * 0.3, base * 0.2, base * 0.1], -1) if has_s else None
    return IlluminationVolume.for_volume(volume, transmittance=t, scattered=phi)


def on_device(illumination, device=None):
    """The grids of an IlluminationVolume as warp arrays on ``device`` (default the first
    GPU, else the CPU): what a light method computing on a GPU hands over."""
    import warp as wp

    from vtkillum.core.illumination import IlluminationVolume

    device = device or ("cuda:0" if wp.get_cuda_device_count() else "cpu")
    s, t = illumination.scattered, illumination.transmittance
    return IlluminationVolume(
        None if s is None else wp.array(s, dtype=wp.vec3, device=device),
        illumination.extent, None if t is None else wp.array(t, dtype=wp.float32, device=device))


def interactive_data(opts, size: int):
    """``(volume, scene)`` of the ``--interactive`` run: ``ct-like`` is
    ``bench_scaling.py``'s volume (made by a warp kernel on the device) and scene, the ones
    the warp ray caster's figures in ``docs/benchmarks.md`` use; ``phantom`` the CT phantom
    upsampled from 256³ and its default scene (the table of the module docstring)."""
    if opts.data == "ct-like":
        import bench_scaling
        import warp as wp

        from vtkillum.core.device import init_warp

        init_warp()
        device = opts.device or ("cuda:0" if wp.get_cuda_device_count() else "cpu")
        volume, _ = bench_scaling.device_volume(size, device)
        return volume, bench_scaling.make_scene(volume)
    volume = upsampled_ct(size)
    return volume, procedural.default_scene("ct", volume)


def opacity_scaled(scene, factor: float):
    """A copy of ``scene`` whose opacity transfer function is ``factor`` times its own."""
    import copy

    from vtkillum.core.transfer_function import TransferFunction

    tf = scene.transfer_function
    edited = copy.deepcopy(scene)
    edited.transfer_function = TransferFunction(tf.scalars,
                                                np.minimum(np.asarray(tf.opacity) * factor, 1.0),
                                                tf.colors)
    return edited


def device_upload_difference(actor, window, grids, device) -> float:
    """Largest 8-bit difference between the frame of ``grids`` written into VTK's textures
    from the warp device and the host path's frame of the same grids (unjittered, one
    frame each; nan where the write did not happen): the check that the direct write
    draws what the host path draws, on this GPU."""
    jitter, accumulate = actor.jitter, actor.accumulate
    actor.jitter, actor.accumulate = False, 1
    try:
        writes = actor.inputs.writer.writes
        actor.set_illumination(on_device(grids, device))
        window.Render()
        direct = _read(window).astype(np.int16)
        if actor.inputs.writer.writes == writes:
            return float("nan")
        actor.device_upload = False
        actor.set_illumination(grids)
        window.Render()
        return float(np.abs(_read(window).astype(np.int16) - direct).max())
    finally:
        actor.jitter, actor.accumulate = jitter, accumulate


def ambient_upload_difference(actor, window) -> float:
    """Largest 8-bit difference between the ambient mapper's frame drawn from textures
    written on the device (the last edit) and the host path's frame of the same scene."""
    window.Render()
    direct = _read(window).astype(np.int16)
    actor.device_upload = False  # the next update fills the images on the host
    window.Render()
    return float(np.abs(_read(window).astype(np.int16) - direct).max())


def interactive(opts) -> tuple[list, str]:
    """The ``--interactive`` table (see the module docstring)."""
    from vtkmodules.vtkRenderingUI import vtkGenericRenderWindowInteractor

    from vtkillum.mappers.gl_trace import GLCallCounter

    rows = []
    gpu = None
    for size in opts.sizes:
        volume, scene = interactive_data(opts, size)
        image = image_data_from_volume(volume)
        for kind in opts.kinds:
            window, renderer = window_for(opts.image)
            if kind == AMBIENT:
                actor = AmbientScatteringVolume(image, scene, exposure=4 * np.pi / 3,
                                                device=opts.device)
                light = None
            else:
                light = synthetic_illumination(volume, kind, len(scene.lights),
                                               scale=opts.grid_scale)
                actor = IlluminatedVolume(image, scene, illumination=light,
                                          exposure=4 * np.pi / 3)
            renderer.AddVolume(actor)
            apply_camera_to_vtk(scene.camera, renderer.GetActiveCamera())
            frames = Frames(window, renderer)
            gpu = gpu or gl_renderer(window)

            def timed(n, frames=frames):
                frames.frame(record=False)  # a changed setting's first frame is not timed
                frames.times = []
                for _ in range(n):
                    frames.frame()
                return statistics.median(frames.times)

            nan = float("nan")
            with GLCallCounter() as gl:
                still = timed(opts.frames)
            uploads = gl.volume_uploads / (opts.frames + 1)
            still_near0 = before = moving_near0 = moving_every = nan
            if kind != AMBIENT:
                actor.near_cells = 0.0
                still_near0 = timed(opts.frames)
                actor.near_cells = NEAR_CELLS
                if opts.history:  # before issue 35: float32 grids, no leaps
                    actor.skip_empty = False
                    actor.illumination_16bit = False
                    before = timed(opts.frames)
                    actor.skip_empty = True
                    actor.illumination_16bit = True
            # the same camera moves in an interactive window, as during a drag (the
            # interactor's update rate): interactive_step, interactive_image_sample_distance
            # (and interactive_near_cells 0)
            interactor = vtkGenericRenderWindowInteractor()
            interactor.SetRenderWindow(window)
            interactor.Initialize()
            window.SetDesiredUpdateRate(interactor.GetDesiredUpdateRate())
            moving = timed(opts.frames)
            actor.interactive_image_sample_distance = 1.0
            moving_every = timed(opts.frames)
            actor.interactive_image_sample_distance = INTERACTIVE_IMAGE_SAMPLE_DISTANCE
            if kind != AMBIENT:
                actor.interactive_near_cells = 0.0
                moving_near0 = timed(opts.frames)
                actor.interactive_near_cells = None
            window.SetDesiredUpdateRate(interactor.GetStillUpdateRate())
            window.SetInteractor(None)
            frames.frame(record=False)
            # TF edit to new frame: a new light volume (as a method hands it over, host
            # arrays, 16-bit textures) and a new transfer function, then the frame; the
            # ambient mapper recomputes its inputs on the device from the new opacity
            def edit_ms(new_light, k, actor=actor, kind=kind):
                """Milliseconds of a TF edit to the new frame (the grids given as made)."""
                t0 = time.perf_counter()
                if kind == AMBIENT:
                    actor.set_scene(opacity_scaled(scene, 1.0 + 0.1 * (k + 1)))
                else:
                    actor.set_illumination(new_light)
                    actor.set_scene(scene.copy() if hasattr(scene, "copy") else scene)
                window.Render()
                window.WaitForCompletion()
                return 1000.0 * (time.perf_counter() - t0)

            def grids(seed, kind=kind):
                return None if kind == AMBIENT else synthetic_illumination(
                    volume, kind, len(scene.lights), scale=opts.grid_scale, seed=seed)

            # through the host: numpy grids (as a method computing on the CPU hands them
            # over); the ambient mapper with device_upload off
            actor.device_upload = False
            edits = [edit_ms(grids(k + 1), k) for k in range(3 if opts.tf_edit else 0)]
            tf_ms = statistics.median(edits) if edits else nan
            # the same edits with the grids on the warp device (as a light method leaves
            # them; the ambient mapper's σ̃t and radiance cache) written straight into VTK's
            # textures (device_upload)
            direct_ms, direct_writes, direct_diff = nan, 0, nan
            if opts.tf_edit and opts.device_upload:
                actor.device_upload = True
                window.Render()  # a frame drawn with the writer watching: VTK's textures
                if kind == AMBIENT:
                    direct_ms = statistics.median(edit_ms(None, k + 3) for k in range(3))
                else:
                    direct_ms = statistics.median(
                        edit_ms(on_device(grids(k + 4), opts.device), k) for k in range(3))
                direct_writes = actor.inputs.writer.writes
                if actor.inputs.writer.last_error:
                    print(f"device upload: {actor.inputs.writer.last_error}", flush=True)
                if kind == AMBIENT:
                    direct_diff = ambient_upload_difference(actor, window)
                else:
                    direct_diff = device_upload_difference(actor, window, grids(9),
                                                           opts.device)
                actor.device_upload = False
            row = (size, kind, still, moving, moving_every, moving_near0, still_near0, before,
                   tf_ms, direct_ms, uploads)
            rows.append(row)
            print(f"| {size}^3 | {kind} | {still:.1f} | {moving:.1f} | {moving_every:.1f} | "
                  f"{moving_near0:.1f} | {still_near0:.1f} | {before:.1f} | {tf_ms:.0f} | "
                  f"{direct_ms:.0f} ({direct_writes} writes; picture vs host path: max "
                  f"{direct_diff:g}/255) | {uploads:g} |", flush=True)
            window.Finalize()
            del actor, light
    return rows, gpu


def interactive_main(opts) -> int:
    data = ("CT-like volume of bench_scaling.py (made on the device) and its scene (1 light)"
            if opts.data == "ct-like" else
            "CT phantom (upsampled from 256^3 above 256), default CT scene (2 lights)")
    print(f"window {vtkRenderWindow().GetClassName()}, image {opts.image}^2, {data}, median "
          f"of {opts.frames} camera moves of 1 degree; illumination grids at "
          f"{opts.grid_scale:g} x the data's points")
    print("| data | illumination | camera move ms (still: full quality) | moving in an "
          "interactive window (step x2, a ray per 2 x 2 pixels) | moving, every pixel | "
          "moving, interactive_near_cells 0 | still, near_cells 0 | before issue 35 (float32 "
          "grids, no leaps; --history) | TF edit to new frame ms (--tf-edit) | the same, "
          "grids on the device written into the textures (--device-upload) | 3D uploads "
          "per camera move |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    _, gpu = interactive(opts)
    print(f"GPU (GL_RENDERER): {gpu}")
    if opts.interop:
        try:
            interop_probe(opts)
        except Exception as err:  # noqa: BLE001  (report why, keep the table)
            print(f"interop probe failed: {type(err).__name__}: {err}")
    return 0


def interop_probe(opts) -> None:
    """CUDA -> OpenGL without the host: warp array -> registered pixel buffer -> 3D texture,
    against the host path (array to numpy, glTexSubImage3D from host memory)."""
    import ctypes

    import warp as wp

    from vtkillum.mappers.gl_trace import gl_function as fn

    wp.init()
    window, _renderer = window_for(64)
    window.Render()
    window.MakeCurrent()
    u, i, p, sz = ctypes.c_uint, ctypes.c_int, ctypes.c_void_p, ctypes.c_ssize_t
    gen_buffers = fn("glGenBuffers", None, i, p)
    bind_buffer = fn("glBindBuffer", None, u, u)
    buffer_data = fn("glBufferData", None, u, sz, p, u)
    gen_textures = fn("glGenTextures", None, i, p)
    bind_texture = fn("glBindTexture", None, u, u)
    tex_image = fn("glTexImage3D", None, u, i, i, i, i, i, i, u, u, p)
    tex_sub = fn("glTexSubImage3D", None, u, i, i, i, i, i, i, i, u, u, p)
    finish = fn("glFinish", None)
    get_error = fn("glGetError", u)
    for n in opts.interop_sizes:
        m = n // 2  # a light grid at half the points of an n^3 volume
        voxels = m ** 3
        nbytes = voxels * 4 * 2  # RGBA16
        src = wp.zeros(voxels * 4, dtype=wp.uint16, device="cuda:0")
        pbo = ctypes.c_uint()
        gen_buffers(1, ctypes.byref(pbo))
        bind_buffer(0x88EC, pbo.value)  # GL_PIXEL_UNPACK_BUFFER
        buffer_data(0x88EC, nbytes, None, 0x88E0)  # GL_STREAM_DRAW
        bind_buffer(0x88EC, 0)
        tex = ctypes.c_uint()
        gen_textures(1, ctypes.byref(tex))
        bind_texture(0x806F, tex.value)  # GL_TEXTURE_3D
        tex_image(0x806F, 0, 0x805B, m, m, m, 0, 0x1908, 0x1403, None)  # RGBA16, RGBA, ushort
        finish()
        try:
            reg = wp.RegisteredGLBuffer(pbo.value, "cuda:0",
                                        flags=wp.RegisteredGLBuffer.WRITE_DISCARD)
        except Exception as err:  # noqa: BLE001
            print(f"interop {n}^3: RegisteredGLBuffer failed: {err}")
            return
        times_gpu, times_host = [], []
        for _ in range(4):
            t0 = time.perf_counter()
            mapped = reg.map(dtype=wp.uint16, shape=(voxels * 4,))
            wp.copy(mapped, src)
            reg.unmap()
            bind_buffer(0x88EC, pbo.value)
            tex_sub(0x806F, 0, 0, 0, 0, m, m, m, 0x1908, 0x1403, None)
            bind_buffer(0x88EC, 0)
            finish()
            times_gpu.append(1000 * (time.perf_counter() - t0))
            t0 = time.perf_counter()
            host = src.numpy()
            tex_sub(0x806F, 0, 0, 0, 0, m, m, m, 0x1908, 0x1403,
                    host.ctypes.data_as(ctypes.c_void_p))
            finish()
            times_host.append(1000 * (time.perf_counter() - t0))
        print(f"interop: light grid {m}^3 RGBA16 ({nbytes / 1e6:.0f} MB): CUDA->PBO->texture "
              f"{statistics.median(times_gpu[1:]):.1f} ms, device->host->texture "
              f"{statistics.median(times_host[1:]):.1f} ms, GL error {get_error()}", flush=True)


# --- --profile: where the shader's time goes (feature toggles, ratios to VTK's composite) ----
def plain_composite(volume, scene, image_size):
    """:class:`Frames` for a plain ``vtkGPUVolumeRayCastMapper`` composite render of the same
    data, transfer function and step (no shading, no light): the floor of a frame."""
    mapper = vtk_mapper(volume, scene)
    prop = vtkVolumeProperty()
    apply_scene_to_volume_property(scene, volume, prop)
    prop.ShadeOff()
    actor = vtkVolume()
    actor.SetMapper(mapper)
    actor.SetProperty(prop)
    window, renderer = window_for(image_size)
    renderer.AddVolume(actor)
    apply_camera_to_vtk(scene.camera, renderer.GetActiveCamera())
    frames = Frames(window, renderer)
    frames.keep = (actor, mapper)  # the mapper holds its input image
    return frames


def profile_variants(scene):
    """``name -> (scene, IlluminatedVolume options, illumination kind or None, moving)``."""
    import copy

    phong = copy.deepcopy(scene)
    phong.shading = {**phong.shading, "ambient": 0.2, "diffuse": 0.7, "specular": 0.2}
    return {
        "no illumination (T = 1, no march)": (scene, {}, None, False),
        "scattered only (photon density)": (scene, {}, "photon density", False),
        "transmittance, near_cells 0": (scene, {"near_cells": 0.0}, "transmittance", False),
        "transmittance, near_cells 2": (scene, {}, "transmittance", False),
        "transmittance, near_cells 2, Phong": (phong, {}, "transmittance", False),
        "transmittance, near_cells 2, no leaps": (scene, {"skip_empty": False},
                                                  "transmittance", False),
        "transmittance, moving (interactive), every pixel": (
            scene, {"interactive_image_sample_distance": 1.0}, "transmittance", True),
        "transmittance, moving (interactive)": (scene, {}, "transmittance", True),
        "transmittance, moving, interactive_near_cells 0": (
            scene, {"interactive_near_cells": 0.0}, "transmittance", True),
        "scattered only, moving (interactive), every pixel": (
            scene, {"interactive_image_sample_distance": 1.0}, "photon density", True),
        "scattered only, moving (interactive)": (scene, {}, "photon density", True),
    }


def _mapper_module(path: str):
    """An illuminated_volume_mapper.py of another version (``--baseline``), as a module."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("baseline_illuminated_volume_mapper", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def profile(opts) -> int:
    """The ``--profile`` table: IlluminatedVolume with features toggled, against VTK's plain
    composite ray caster on the same data (the floor), frames taking turns. With
    ``--baseline FILE`` (another version of ``illuminated_volume_mapper.py``, e.g. from
    ``git show REV:vtkillum/mappers/illuminated_volume_mapper.py``) every variant also runs
    with that version's class, in the same rounds, and the table gives both."""
    from vtkmodules.vtkRenderingUI import vtkGenericRenderWindowInteractor

    volume, scene = interactive_data(opts, opts.size)
    floor = plain_composite(volume, scene, opts.image)
    classes = {"": IlluminatedVolume}
    if opts.baseline:
        classes["baseline: "] = _mapper_module(opts.baseline).IlluminatedVolume
    runs = {}
    lights = {}  # (kind, lights) -> the synthetic illumination, made once
    for name, (sc, options, kind, moving) in profile_variants(scene).items():
        if opts.variants and not any(v in name for v in opts.variants):
            continue
        for label, cls in classes.items():
            kwargs = dict(options)
            skip = kwargs.pop("skip_empty", True)
            if label and any(k.startswith("interactive_") and k != "interactive_step"
                             for k in kwargs):
                continue  # the baseline may not have this option
            window, renderer = window_for(opts.image)
            if kind is not None and (kind, len(sc.lights)) not in lights:
                lights[kind, len(sc.lights)] = synthetic_illumination(
                    volume, kind, len(sc.lights), scale=opts.grid_scale)
            light = None if kind is None else lights[kind, len(sc.lights)]
            actor = cls(image_data_from_volume(volume), sc, illumination=light,
                        exposure=4 * np.pi / 3, **kwargs)
            actor.skip_empty = skip
            renderer.AddVolume(actor)
            apply_camera_to_vtk(sc.camera, renderer.GetActiveCamera())
            if moving:
                interactor = vtkGenericRenderWindowInteractor()
                interactor.SetRenderWindow(window)
                interactor.Initialize()
            frames = Frames(window, renderer)
            frames.keep = (actor,)
            runs[label + name] = frames
    for _ in range(opts.frames):  # taking turns: load changes hit all alike
        floor.frame()
        for frames in runs.values():
            frames.frame()
    data = ("bench_scaling.py's CT-like volume and scene (1 light)" if opts.data == "ct-like"
            else "CT phantom, default CT scene (2 lights)")
    print(f"window {floor.window.GetClassName()} ({gl_renderer(floor.window)}), {data}, "
          f"{opts.size}^3, image {opts.image}^2, grids at "
          f"{opts.grid_scale:g} x the data's points, median of {opts.frames} camera moves; "
          "ratio: median over the rounds of the frame / VTK's plain composite frame")
    print("| variant | ms per frame | ratio to VTK composite |")
    print("|---|---|---|")
    print(f"| VTK composite (vtkGPUVolumeRayCastMapper, no shading) | "
          f"{statistics.median(floor.times):.1f} | 1 |")
    for name, frames in runs.items():
        ratio = statistics.median(a / b for a, b in zip(frames.times, floor.times))
        print(f"| IlluminatedVolume: {name} | {statistics.median(frames.times):.1f} | "
              f"{ratio:.2f} |", flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=128, help="volume points per axis")
    parser.add_argument("--image", type=int, default=512, help="window width and height")
    parser.add_argument("--frames", type=int, default=5, help="timed frames per renderer")
    parser.add_argument("--datasets", nargs="+", default=None,
                        help="ct, plume (default both); with --quality: head, mni, mni-half "
                             "(default all three)")
    parser.add_argument("--quality", action="store_true",
                        help="speckle/terraces of still pictures and ms per frame, before "
                             "and after the accumulation (see the module docstring)")
    parser.add_argument("--reference-frames", type=int, default=128,
                        help="--quality: frames accumulated for the reference picture")
    parser.add_argument("--reach", type=float, nargs="+", default=[0.1, 0.25, 0.5, 1.0],
                        help="VTK's GlobalIlluminationReach values to run")
    parser.add_argument("--blending", type=float, default=1.0,
                        help="VTK's VolumetricScatteringBlending (0 surface, 1 volumetric)")
    parser.add_argument("--save", help="folder for the last frame of each renderer (PNG)")
    parser.add_argument("--interactive", action="store_true",
                        help="camera move and TF edit per illumination kind and size, GPU "
                             "named (see the module docstring)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512],
                        help="--interactive: volume points per axis")
    parser.add_argument("--kinds", nargs="+", default=["transmittance", "photon density"],
                        help=f"--interactive: illumination kinds, of {list(KINDS)} (default "
                             "transmittance and photon density: a scattered fluence only)")
    parser.add_argument("--data", choices=["ct-like", "phantom"], default="ct-like",
                        help="--interactive, --profile: bench_scaling.py's CT-like volume and "
                             "scene (default) or the upsampled CT phantom")
    parser.add_argument("--device", help="--interactive --data ct-like: warp device making "
                                         "the volume (default cuda:0 where there is one)")
    parser.add_argument("--history", action="store_true",
                        help="--interactive: also time float32 grids without leaps")
    parser.add_argument("--device-upload", action="store_true",
                        help="with --tf-edit: also time edits whose grids are warp arrays "
                             "written straight into VTK's textures (IlluminatedVolume."
                             "device_upload)")
    parser.add_argument("--tf-edit", action="store_true",
                        help="--interactive: also time a TF edit to the new frame")
    parser.add_argument("--interop", action="store_true",
                        help="--interactive: also time CUDA->OpenGL through a registered "
                             "pixel buffer against the host path (warp on CUDA)")
    parser.add_argument("--interop-sizes", type=int, nargs="+", default=[256, 512])
    parser.add_argument("--profile", action="store_true",
                        help="IlluminatedVolume with features toggled against VTK's plain "
                             "composite (ratios; see the module docstring)")
    parser.add_argument("--grid-scale", type=float, default=1.0,
                        help="--profile, --interactive: light grid points per data point "
                             "(1: the methods' default light_volume_scale)")
    parser.add_argument("--variants", nargs="+", default=None,
                        help="--profile: only the variants whose name contains one of these")
    parser.add_argument("--baseline",
                        help="--profile: another version of illuminated_volume_mapper.py "
                             "to time alongside")
    opts = parser.parse_args(argv)
    if opts.profile:
        return profile(opts)
    if opts.interactive:
        return interactive_main(opts)
    if opts.quality:
        opts.datasets = opts.datasets or ["head", "mni", "mni-half"]
        return quality(opts)
    opts.datasets = opts.datasets or ["ct", "plume"]

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
