"""Progressive accumulation of jittered frames in a VTK renderer while its view rests.

A ray caster that samples a ray at ``t0 + (k + ξ) Δ`` shows, at a sharp surface, either
wood-grain terraces (one fixed ``ξ`` for every pixel) or noise (``ξ`` varying per pixel).
Both shrink only with more samples per pixel. :class:`FrameAccumulator` adds them over
time, as VTK's and ParaView's ray-traced views do: while nothing in a renderer changes,
each new render draws the volumes with the next offset of their sequence and the
renderer shows the mean of the frames so far; a change resets it.

Per renderer::

    frame 0    (after any change): drawn as is, nothing read back -- interaction costs
               what a render without accumulation costs
    frame k>=1 (nothing changed since frame k-1): the volumes sample with offset index k;
               the viewport is read back (RGBA, [0, 1]) and added to a float sum; the mean
               of frames 1..k is written back before the window shows it
    converged  (``accumulate`` frames summed, or a frame that moved the mean by at most
               :data:`SETTLED_LEVELS` anywhere: more frames would not change what 8 bits
               show; a view that the offsets hardly change, e.g. smooth smoke, stops after
               a few frames): the volumes draw nothing (their shader discards every
               fragment) and the stored mean is written back

"Nothing changed" compares, before and after each render, the camera (view matrix and
projection to 7 digits, without the clipping range, which moves with the bounds but
does not move any pixel), the viewport's size and background, each accumulating
volume's content (:meth:`~vtkillum.mappers.IlluminatedVolume.content_mtime`: data,
illumination, scene, exposure, ...) and every other visible prop's redraw time. A change seen only after a
render (a pipeline that executed during it, e.g. a new time step) restarts with that
frame as frame 0.

The frames are read back from the 8-bit frame buffer: the mean is an average of 8-bit
frames (each within half a level of its radiance; the varying offsets dither the sum),
written back rounded to 8 bits.

Volumes take part through duck typing: every prop of the renderer that has
``content_mtime()``, ``set_frame(index, hold, moving)`` (``moving``: frame 0 while an
interactor style moves the view, :func:`~vtkillum.mappers.interaction.window_interacting`,
where a volume may sample more coarsely: the still frame that ends the drag and the timer's
frames refine it), ``jitter`` and ``accumulate``
(:class:`~vtkillum.mappers.IlluminatedVolume`). A renderer accumulates when at least one
visible such prop has ``jitter`` on and ``accumulate > 0``; it sums up to the largest
``accumulate``. Renderers are attached by the volumes themselves (at their first render),
so ``renderer.AddVolume(volume)`` or pyvista's ``plotter.add_actor(volume)`` is enough.

Where the window has an initialised interactor, a one-shot timer renders the next frame
while the view rests, not during a drag (the accumulation then runs by itself in an
interactive window, starting with the still render that ends an interaction);
without one (off screen, scripts), each ``window.Render()`` adds a frame, and
:meth:`FrameAccumulator.refine` renders until the mean has converged.
"""

from __future__ import annotations

import numpy as np
from vtkmodules.util.misc import calldata_type
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
from vtkmodules.util.vtkConstants import VTK_INT
from vtkmodules.vtkCommonCore import vtkCommand, vtkFloatArray, vtkWeakReference

from vtkillum.mappers.interaction import window_interacting

#: Milliseconds between the frames an interactor's timer adds while the view rests.
REFINE_INTERVAL_MS = 10

#: A frame that moves the mean by at most this many 8-bit levels in every pixel and
#: channel ends the accumulation early (negative: never).
SETTLED_LEVELS = 0.5

# renderer address -> FrameAccumulator (removed when the renderer is deleted)
_ACCUMULATORS: dict[str, FrameAccumulator] = {}


def accumulator_for(renderer) -> FrameAccumulator:
    """The :class:`FrameAccumulator` of ``renderer`` (created and attached on first use)."""
    address = renderer.GetAddressAsString("vtkRenderer")
    acc = _ACCUMULATORS.get(address)
    if acc is None or acc.renderer is not renderer:
        if acc is not None:
            acc.detach()
        acc = FrameAccumulator(renderer)
        _ACCUMULATORS[address] = acc
    return acc


def existing_accumulator(renderer) -> FrameAccumulator | None:
    """``renderer``'s accumulator if one is attached, else None."""
    acc = _ACCUMULATORS.get(renderer.GetAddressAsString("vtkRenderer"))
    return acc if acc is not None and acc.renderer is renderer else None


class FrameAccumulator:
    """The mean of a renderer's jittered frames while its view rests (see the module).

    Parameters
    ----------
    renderer : vtkRenderer
        Observed through its ``StartEvent`` (choose the frame's offset index) and
        ``EndEvent`` (read back, sum, write the mean back). Use
        :func:`accumulator_for` rather than this constructor: one accumulator per renderer.

    Attributes
    ----------
    frame : int
        Renders since the last change (0: the first render after it).
    count : int
        Frames in the mean shown (0 while the mean is not in use: frame 0, or no
        accumulating volume).
    converged : bool
        The mean is complete (``limit`` frames, or settled early): later renders show it
        and the volumes draw nothing.
    """

    def __init__(self, renderer) -> None:
        self._renderer = vtkWeakReference()
        self._renderer.Set(renderer)
        self.frame = 0
        self.count = 0
        self.limit = 0
        self.converged = False
        self._sum = None
        self._key = None
        self._hold = False
        self._timer = None  # (weak interactor, timer id, observer tag)
        self._tags = [renderer.AddObserver(vtkCommand.StartEvent, self._on_start),
                      renderer.AddObserver(vtkCommand.EndEvent, self._on_end),
                      renderer.AddObserver(vtkCommand.DeleteEvent, self._on_delete)]

    @property
    def renderer(self):
        """The renderer (None once it was deleted)."""
        return self._renderer.Get()

    def reset(self) -> None:
        """Forget the frames: the next render is frame 0."""
        self.frame = 0
        self.count = 0
        self.converged = False
        self._sum = None
        self._key = None
        self._hold = False

    def detach(self) -> None:
        """Remove the observers and the timer."""
        self._stop_timer()
        renderer = self.renderer
        if renderer is not None:
            for tag in self._tags:
                renderer.RemoveObserver(tag)
            address = renderer.GetAddressAsString("vtkRenderer")
            if _ACCUMULATORS.get(address) is self:
                del _ACCUMULATORS[address]
        self._tags = []

    def refine(self, frames: int | None = None) -> int:
        """Render the window until ``frames`` frames are in the mean, or it converged.

        Returns the number of frames in the mean. Renders stop early when the view keeps
        changing between renders (nothing can accumulate then).
        """
        renderer = self.renderer
        window = renderer.GetRenderWindow() if renderer is not None else None
        if window is None:
            raise ValueError("the renderer is in no render window")
        window.Render()  # brings limit and key up to date (a first render is frame 0)
        target = self.limit if frames is None else min(int(frames), self.limit)
        budget = target + 2  # frame 0 and one restart
        while self.count < target and not self.converged and budget > 0:
            window.Render()
            budget -= 1
        return self.count

    # --- observers ----------------------------------------------------------------------------
    def _props(self, renderer) -> tuple[list, list]:
        """(accumulating props, other visible props) of ``renderer``."""
        ours, others = [], []
        props = renderer.GetViewProps()
        for i in range(props.GetNumberOfItems()):
            prop = props.GetItemAsObject(i)
            if not prop.GetVisibility():
                continue
            if hasattr(prop, "set_frame") and hasattr(prop, "content_mtime"):
                ours.append(prop)
            else:
                others.append(prop)
        return ours, others

    def _view_key(self, renderer, ours, others) -> tuple:
        camera = renderer.GetActiveCamera()
        view = camera.GetViewTransformMatrix()
        aspect = renderer.GetTiledAspectRatio()
        projection = camera.GetProjectionTransformMatrix(aspect, -1.0, 1.0)
        # 7 significant digits: a screenshot filter re-rendering the same view moves the
        # projection by rounding errors (1e-8), which must not restart the mean.
        matrices = tuple(f"{view.GetElement(i, j):.7g}" for i in range(4) for j in range(4)) + \
            tuple(f"{projection.GetElement(i, j):.7g}" for i in (0, 1, 3) for j in range(4))
        window = renderer.GetRenderWindow()
        return (matrices, tuple(renderer.GetSize()), tuple(renderer.GetOrigin()),
                tuple(window.GetSize()) if window is not None else None,
                tuple(renderer.GetBackground()), renderer.GetBackgroundAlpha(),
                tuple((_address(p), p.content_mtime()) for p in ours),
                tuple((_address(p), p.GetRedrawMTime()) for p in others))

    def _on_start(self, renderer, event) -> None:
        ours, others = self._props(renderer)
        active = [p for p in ours if p.jitter and p.accumulate > 0]
        self.limit = max((int(p.accumulate) for p in active), default=0)
        if not active:
            self.reset()
            for prop in ours:
                prop.set_frame(0, False)
            return
        key = self._view_key(renderer, ours, others)
        if key == self._key:
            self.frame += 1
        else:
            self.reset()
        if self._sum is not None and self.count >= self.limit:
            self.converged = True
        self._hold = self.converged
        moving = self.frame == 0 and window_interacting(renderer.GetRenderWindow())
        for prop in ours:
            prop.set_frame(self.frame, self._hold, moving)
        self._key = self._view_key(renderer, ours, others)

    def _on_end(self, renderer, event) -> None:
        if self.limit == 0:
            return
        ours, others = self._props(renderer)
        key = self._view_key(renderer, ours, others)
        if key != self._key:  # changed during the render (a pipeline executed): frame 0
            self.reset()
            self._key = key
            self._schedule(renderer)
            return
        if self.frame == 0:
            self._schedule(renderer)
            return
        if self._hold:
            self._write(renderer, self._sum / self.count)
            return
        rgba = self._read(renderer)
        if self._sum is None:
            self._sum = rgba
            self.count = 1
        else:
            # the mean moves by (frame - previous mean) / count
            step = np.abs(rgba - self._sum / self.count).max() / (self.count + 1)
            self._sum += rgba
            self.count += 1
            self._write(renderer, self._sum / self.count)
            self.converged = step <= SETTLED_LEVELS / 255.0
        if self.count < self.limit and not self.converged:
            self._schedule(renderer)

    def _on_delete(self, renderer, event) -> None:
        self._stop_timer()
        for address, acc in list(_ACCUMULATORS.items()):
            if acc is self:
                del _ACCUMULATORS[address]

    # --- pixels -------------------------------------------------------------------------------
    @staticmethod
    def _viewport(renderer) -> tuple[int, int, int, int]:
        x0, y0 = renderer.GetOrigin()
        w, h = renderer.GetSize()
        return int(x0), int(y0), int(w), int(h)

    def _read(self, renderer) -> np.ndarray:
        x0, y0, w, h = self._viewport(renderer)
        pixels = vtkFloatArray()
        renderer.GetRenderWindow().GetRGBAPixelData(x0, y0, x0 + w - 1, y0 + h - 1, 0, pixels, 0)
        return vtk_to_numpy(pixels).astype(np.float64).reshape(h, w, 4)

    def _write(self, renderer, rgba: np.ndarray) -> None:
        x0, y0, w, h = self._viewport(renderer)
        if rgba.shape[:2] != (h, w):  # cannot happen with an unchanged key; be safe
            self.reset()
            return
        pixels = numpy_to_vtk(np.ascontiguousarray(rgba, dtype=np.float32).reshape(-1, 4),
                              deep=True)
        renderer.GetRenderWindow().SetRGBAPixelData(x0, y0, x0 + w - 1, y0 + h - 1, pixels,
                                                    0, 0, 0)

    # --- interactive refinement ---------------------------------------------------------------
    def _schedule(self, renderer) -> None:
        """With an initialised interactor: render the next frame from a one-shot timer."""
        window = renderer.GetRenderWindow()
        interactor = window.GetInteractor() if window is not None else None
        if interactor is None or not interactor.GetInitialized() or self._timer is not None:
            return
        weak = vtkWeakReference()
        weak.Set(interactor)
        timer_id = None

        @calldata_type(VTK_INT)
        def on_timer(caller, event, fired=None):
            # The fired timer's id comes as call data (some interactors also set it as
            # TimerEventId); other timers of the interactor are not ours.
            if self._timer is None or timer_id not in (fired, caller.GetTimerEventId()):
                return
            self._stop_timer()
            style = caller.GetInteractorStyle()
            if style is not None and style.IsA("vtkInteractorStyle") and style.GetState() != 0:
                return  # a drag is under way; the style's still render at its end resumes
            if self.renderer is not None and caller.GetEnableRender():
                caller.Render()

        tag = interactor.AddObserver(vtkCommand.TimerEvent, on_timer)
        timer_id = interactor.CreateOneShotTimer(REFINE_INTERVAL_MS)
        self._timer = (weak, timer_id, tag)

    def _stop_timer(self) -> None:
        if self._timer is None:
            return
        weak, timer_id, tag = self._timer
        self._timer = None
        interactor = weak.Get()
        if interactor is not None:
            interactor.DestroyTimer(timer_id)
            interactor.RemoveObserver(tag)


def _address(prop) -> str:
    # not id(): a prop's Python wrapper may be re-created between renders
    return prop.GetAddressAsString("vtkObject")


__all__ = ["REFINE_INTERVAL_MS", "SETTLED_LEVELS", "FrameAccumulator", "accumulator_for", "existing_accumulator"]
