"""The warp renderers shown in a VTK window: the compute path.

:class:`ComputeVolumeRenderer` renders a volume with any method registered in
:data:`vtkillum.core.render.METHODS` (``emission``, ``single``, ``illumination``
with an illumination volume, ``path``, and whatever registers later, e.g. methods
that gather per sample) at the size and camera of a ``vtkRenderer``, and shows the
tone-mapped image as that renderer's textured background. It re-renders when
the camera or the viewport size changes (checked in the renderer's
``StartEvent``, so the new image is in the same frame). ``path`` and ``many-lights``
are progressive: each camera change restarts the image with one pass (a path-tracing
sample per pixel; one set of virtual lights, whose lights are kept across camera
moves), and :meth:`ComputeVolumeRenderer.refine` -- called by hand or by a
repeating interactor timer (:meth:`ComputeVolumeRenderer.start_refinement`) while the
camera rests -- adds passes up to ``spp`` / ``max_sets``.

Display: ``tonemap(exposure * radiance, alpha, background, gamma=gamma)`` with the
renderer's background colour, ``gamma = 1`` by default (linear, like VTK's own
ray caster writes its frame buffer). Other props of the renderer are drawn over
the image; they are not depth-composited with the volume.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from vtkmodules.util.numpy_support import numpy_to_vtk
from vtkmodules.vtkCommonCore import vtkCommand, vtkWeakReference
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkRenderingCore import vtkRenderer, vtkTexture

from vtkillum.core.device import resolve_device
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.render import METHODS, RenderResult, render
from vtkillum.core.scene import Scene
from vtkillum.core.tonemap import tonemap, tonemap_device
from vtkillum.core.volume import Volume
from vtkillum.io.convert import volume_from_image_data
from vtkillum.io.illumination_arrays import illumination_from_image, lights_from_field
from vtkillum.mappers.camera_bridge import camera_from_vtk
from vtkillum.mappers.inputs import check_covers

#: Methods rendered progressively: refined while the camera rests (``refine``).
PROGRESSIVE = ("path", "many-lights")


def _progressive_renderer(method: str, volume, scene, width: int, height: int, device,
                          options: dict):
    """The accumulating renderer of a progressive ``method`` and its pass limit.

    ``path``: a :class:`~vtkillum.core.pathtrace.PathTracer` (one sample per pixel per
    pass, up to ``spp``); ``many-lights``: a
    :class:`~vtkillum.core.many_lights.render.ManyLightsRenderer` (one set of virtual
    lights per pass, up to ``max_sets``). Both have ``width``, ``height``, ``passes``,
    ``reset(camera)``, ``run(passes)`` and ``result()``.
    """
    if method == "path":
        from vtkillum.core.pathtrace import PathTracer

        path = {**scene.options["path"], **options}
        tracer = PathTracer(volume, scene, width, height, device=device,
                            seed=int(path["seed"]), max_bounces=int(path["max_bounces"]))
        return tracer, int(path["spp"])
    from vtkillum.core.many_lights.render import ManyLightsRenderer

    tracer = ManyLightsRenderer(volume, scene, width, height, device=device, **options)
    return tracer, int(tracer.opts["max_sets"])


class ComputeVolumeRenderer:
    """Show a warp rendering of ``volume`` in ``renderer``, following its camera.

    Parameters
    ----------
    renderer : vtkRenderer
        Also ``pyvista.Plotter.renderer``. Its background becomes the rendered image.
    volume : Volume or vtkImageData
        The data (image data is converted with ``array_name``).
    scene : Scene, optional
        Optical model, lights, shading and method options; its camera is ignored (the
        renderer's is used). Default ``Scene()``.
    method : str
        A registered method name (see :data:`vtkillum.core.render.METHODS`).
    illumination : IlluminationVolume, ndarray or vtkImageData, optional
        The illumination volume for ``method="illumination"``: per-light transmittance
        (the direct light, shaded with the phase function) and scattered fluence; an
        ``(nx, ny, nz, 3)`` array is a scattered fluence; image data are read with
        :func:`vtkillum.io.illumination_arrays.illumination_from_image` (``transmittance``
        and ``scattered_fluence``, or only ``fluence``) and, when they carry the lights
        (field data ``vtkillum_lights``), are rendered with those lights instead of the
        scene's.
    device : str, optional
        Warp device.
    exposure, gamma : float
        Tone map of the display (see the module docstring).
    resolution_scale : float
        Render at this fraction of the viewport size (in (0, 1]); the texture is then
        interpolated up. Useful for the slower methods on a CPU.
    array_name : str, optional
        Point array of image data to render.
    **options
        Method options (e.g. ``step_size``, ``jitter`` for the ray casters; ``spp``,
        ``max_bounces``, ``seed`` for ``path``, where ``spp`` is the number of passes
        refinement stops at; default ``scene.options["path"]``).

    Notes
    -----
    The renderer's observer keeps this object alive (no need to hold a reference);
    this object refers to the renderer and the interactor only weakly, so nothing
    leaks when the window goes away. :meth:`detach` stops it.
    """

    def __init__(self, renderer: vtkRenderer, volume, scene: Scene | None = None,
                 method: str = "emission", illumination=None, device: str | None = None,
                 exposure: float = 1.0, gamma: float = 1.0, resolution_scale: float = 1.0,
                 array_name: str | None = None, **options) -> None:
        if not isinstance(renderer, vtkRenderer):
            raise TypeError(f"renderer must be a vtkRenderer, got {type(renderer).__name__}")
        self._renderer = vtkWeakReference()
        self._renderer.Set(renderer)
        self.device = resolve_device(device)
        self.volume = _as_volume(volume, array_name)
        self.scene = scene if scene is not None else Scene()
        if not isinstance(self.scene, Scene):
            raise TypeError(f"scene must be a vtkillum Scene, got {type(self.scene).__name__}")
        self.exposure = _positive(exposure, "exposure")
        self.gamma = _positive(gamma, "gamma")
        self.resolution_scale = float(resolution_scale)
        if not 0.0 < self.resolution_scale <= 1.0:
            raise ValueError(f"resolution_scale must lie in (0, 1], got {resolution_scale}")
        self.illumination = None
        self._illumination_lights = None
        self.set_illumination(illumination)
        self.method = None
        self.options: dict = {}
        self.set_method(method, **options)
        self.result: RenderResult | None = None
        self.refined = False  # whether the last refine() showed a new image
        self._tracer = None
        self._key = None  # (camera state, width, height) of the image shown
        self._timer = None  # (weak interactor, timer id, observer tag)

        self._image = vtkImageData()
        self.texture = vtkTexture()
        self.texture.SetInputData(self._image)
        self.texture.SetColorModeToDirectScalars()
        self.texture.SetInterpolate(self.resolution_scale < 1.0)
        self._saved_background = (renderer.GetTexturedBackground(), renderer.GetBackgroundTexture())
        renderer.SetBackgroundTexture(self.texture)
        renderer.TexturedBackgroundOn()
        # The observer holds this object; it holds the renderer weakly (no reference cycle).
        self._start_tag = renderer.AddObserver(vtkCommand.StartEvent,
                                               lambda caller, event: self.update())

    @property
    def renderer(self) -> vtkRenderer:
        """The renderer drawn into (``ValueError`` once it has been deleted)."""
        renderer = self._renderer.Get()
        if renderer is None:
            raise ValueError("the renderer of this ComputeVolumeRenderer has been deleted")
        return renderer

    # --- configuration --------------------------------------------------------------------------
    def set_method(self, method: str, **options) -> None:
        """Switch to a registered method with its options; the next render redraws."""
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r}; choose one of {sorted(METHODS)}")
        if method == "illumination" and self.illumination is None:
            raise ValueError(
                "method 'illumination' needs an illumination volume: pass illumination=... "
                "(an IlluminationVolume or an illumination filter's output image)"
            )
        self.method = method
        self.options = dict(options)
        self.invalidate()

    def set_scene(self, scene: Scene) -> None:
        """Use a new scene (optical model, lights, options); the next render redraws.

        ``many-lights`` keeps its virtual lights through an edit of the transfer function,
        the medium, the phase function or the lights when its options stay the same: the
        next render shows the paper's immediate response (contributions re-evaluated along
        the stored paths, section 4), and :meth:`refine` regenerates the stale paths a
        fraction per pass before it adds sets (section 4.2). Other edits start afresh.
        """
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a vtkillum Scene, got {type(scene).__name__}")
        old, self.scene = self.scene, scene
        if self.method == "many-lights" and self._tracer is not None and \
                self._same_many_light_options(old, scene):
            edited = copy.copy(scene)
            edited.camera = self._tracer.camera
            edited.lights = self.lights
            self._tracer.update(edited)
            self._key = None
            return
        self.invalidate()

    def _same_many_light_options(self, old: Scene, new: Scene) -> bool:
        """Whether ``many-lights`` resolves the same options for both scenes."""
        from vtkillum.core.many_lights.render import parse_options

        try:
            return bool(parse_options(self.options, self.volume, old)
                        == parse_options(self.options, self.volume, new))
        except (ValueError, TypeError):
            return False  # the render reports the bad option

    def set_illumination(self, illumination) -> None:
        """The illumination volume for ``illumination``: IlluminationVolume, array or image data.

        Image data that carry lights (``vtkillum_lights``) bring them along: they replace
        the scene's lights while this illumination is set (see :attr:`lights`).
        """
        lights = None
        if illumination is None:
            volume = None
        elif isinstance(illumination, IlluminationVolume):
            illumination.check_matches(self.volume)
            volume = illumination
        elif isinstance(illumination, np.ndarray):
            volume = IlluminationVolume.for_volume(self.volume, illumination)
        elif isinstance(illumination, vtkImageData):
            check_covers(illumination, self.volume)
            volume = illumination_from_image(illumination, self.volume)
            lights = lights_from_field(illumination)
            volume.check_matches(self.volume, lights)
        else:
            raise TypeError(
                "illumination must be an IlluminationVolume, an (nx, ny, nz, 3) array or image "
                "data with illumination arrays (transmittance / scattered_fluence or fluence), "
                f"got {type(illumination).__name__}"
            )
        self.illumination = volume
        self._illumination_lights = lights
        self.invalidate()

    @property
    def lights(self) -> list:
        """The lights rendered: the illumination image's when it carries them, else the scene's."""
        if self._illumination_lights:
            return list(self._illumination_lights)
        return list(self.scene.lights)

    def invalidate(self) -> None:
        """Forget the image shown: the next render of the renderer recomputes it."""
        self._key = None
        self._tracer = None

    def detach(self) -> None:
        """Stop drawing: remove the observers and restore the renderer's background."""
        self.stop_refinement()
        renderer = self._renderer.Get()
        if renderer is None:
            return
        if self._start_tag is not None:
            renderer.RemoveObserver(self._start_tag)
            self._start_tag = None
        textured, texture = self._saved_background
        renderer.SetBackgroundTexture(texture)
        renderer.SetTexturedBackground(textured)

    # --- rendering --------------------------------------------------------------------------
    def viewport_size(self) -> tuple[int, int]:
        """Image size ``(width, height)``: the renderer's size times ``resolution_scale``."""
        w, h = self.renderer.GetSize()
        s = self.resolution_scale
        return max(1, round(w * s)), max(1, round(h * s))

    def update(self) -> bool:
        """Re-render if the camera, the viewport size or the configuration changed.

        Returns True when a new image was computed. Called from the renderer's
        ``StartEvent``; call it by hand to render without a window render.
        """
        w, h = self.renderer.GetSize()
        if w < 1 or h < 1:
            return False
        width, height = self.viewport_size()
        camera = camera_from_vtk(self.renderer.GetActiveCamera(), aspect=width / height)
        key = (_camera_state(camera), width, height)
        if key == self._key:
            return False
        scene = copy.copy(self.scene)
        scene.camera = camera
        scene.lights = self.lights
        if self.method in PROGRESSIVE:
            if self._tracer is None or (self._tracer.width, self._tracer.height) != (width, height):
                self._tracer, self._limit = _progressive_renderer(
                    self.method, self.volume, scene, width, height, self.device, self.options)
            else:
                self._tracer.reset(camera)
            self._tracer.run(1)
            self.result = self._tracer.result()
        else:
            options = dict(self.options)
            if self.method == "illumination":
                options["illumination"] = self.illumination
            self.result = render(self.volume, scene, self.method, width, height, self.device,
                                 **options)
        self._key = key
        self._show(self.result)
        return True

    def refine(self, passes: int = 1) -> int:
        """Add ``passes`` passes of a progressive method and show the new mean.

        ``path``: samples per pixel, up to ``spp``; ``many-lights``: after an edit a step
        of the progressive regeneration per pass while paths are stale (the image shows
        set 0), then sets of virtual lights, up to ``max_sets``. Returns the number of
        passes accumulated; :attr:`refined` tells whether a new image was shown. Does not
        render the window: call ``render_window.Render()`` to see the result.
        """
        if self.method not in PROGRESSIVE:
            raise ValueError(f"refine() is for the progressive methods {PROGRESSIVE}, not "
                             f"{self.method!r}")
        self.refined = False
        if self._tracer is None:
            self.update()
            if self._tracer is None:
                return 0
        if self.method == "many-lights":
            # After an edit: regenerate stale paths first (the image is set 0), then add sets.
            for _ in range(int(passes)):
                if not self._tracer.state.stale and self._tracer.passes >= self._limit:
                    break
                self._tracer.frame()
                self.refined = True
        else:
            passes = min(int(passes), self._limit - self._tracer.passes)
            if passes > 0:
                self._tracer.run(passes)
                self.refined = True
        if self.refined:
            self.result = self._tracer.result()
            self._show(self.result)
        return self._tracer.passes

    def start_refinement(self, interactor=None, interval_ms: int = 30,
                         passes_per_tick: int = 1) -> None:
        """Refine ``path`` and ``many-lights`` images on a repeating timer while the camera rests.

        Each tick adds ``passes_per_tick`` passes when the camera has not moved since
        the image shown, then renders the window; a moved camera restarts the image
        at the window's next render (the renderer's ``StartEvent``).
        """
        self.stop_refinement()
        if interactor is None:
            window = self.renderer.GetRenderWindow()
            interactor = window.GetInteractor() if window is not None else None
        if interactor is None:
            raise ValueError("no interactor: pass interactor=... or call refine() yourself")

        def on_timer(caller, event):
            renderer = self._renderer.Get()
            if renderer is None or self.method not in PROGRESSIVE:
                return
            w, h = self.viewport_size()
            camera = camera_from_vtk(renderer.GetActiveCamera(), aspect=w / h)
            if self._key == (_camera_state(camera), w, h):  # resting
                self.refine(passes_per_tick)
                if not self.refined:
                    return  # converged: nothing new to show
            renderer.GetRenderWindow().Render()

        tag = interactor.AddObserver(vtkCommand.TimerEvent, on_timer)
        timer_id = interactor.CreateRepeatingTimer(int(interval_ms))
        weak = vtkWeakReference()
        weak.Set(interactor)
        self._timer = (weak, timer_id, tag)

    def stop_refinement(self) -> None:
        """Stop the refinement timer (if any)."""
        if self._timer is not None:
            weak, timer_id, tag = self._timer
            interactor = weak.Get()
            if interactor is not None:
                interactor.DestroyTimer(timer_id)
                interactor.RemoveObserver(tag)
            self._timer = None

    @property
    def passes(self) -> int:
        """Path-tracing passes in the image shown (0 for the other methods)."""
        return self._tracer.passes if self._tracer is not None else 0

    # --- display --------------------------------------------------------------------------------
    def display_image(self) -> np.ndarray:
        """The 8-bit RGB image shown, ``(H, W, 3)``, row 0 at the top."""
        if self.result is None:
            raise ValueError("nothing rendered yet: render the window or call update()")
        # exposure scales the volume's light, not the renderer's background: the background
        # goes in divided by it (no exposure * radiance temporary of the image's size)
        return self._tone_mapped(flip=False)

    def _tone_mapped(self, flip: bool) -> np.ndarray:
        """The 8-bit image, rows bottom-up with ``flip`` (VTK's order). An image kept on its
        device (:attr:`RenderResult.device`) is tone-mapped there: only the 8-bit pixels
        come to the host."""
        background = np.asarray(self.renderer.GetBackground(), np.float32) / self.exposure
        if self.result.device is not None:
            return tonemap_device(*self.result.device, background, exposure=self.exposure,
                                  gamma=self.gamma, flip=flip)
        rgb = tonemap(self.result.radiance, self.result.alpha, background,
                      exposure=self.exposure, gamma=self.gamma)
        return rgb[::-1] if flip else rgb

    def _show(self, result: RenderResult) -> None:
        rgb = self._tone_mapped(flip=True)
        h, w, _ = rgb.shape
        pixels = numpy_to_vtk(np.ascontiguousarray(rgb).reshape(-1, 3), deep=True)
        pixels.SetName("display")
        self._image.SetDimensions(w, h, 1)
        self._image.GetPointData().SetScalars(pixels)
        self._image.Modified()


def _camera_state(camera) -> tuple:
    return (tuple(camera.position), tuple(camera.focal_point), tuple(camera.view_up),
            camera.view_angle, camera.parallel_projection, camera.parallel_scale)


def _as_volume(volume, array_name):
    if isinstance(volume, Volume):
        return volume
    if isinstance(volume, vtkImageData):
        return volume_from_image_data(volume, array_name)
    raise TypeError(
        f"volume must be a vtkillum Volume or vtkImageData, got {type(volume).__name__}"
    )


def _positive(value, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value}")
    return value
