"""Coarser frames while the view moves in an interactive window.

VTK's GPU ray caster can cast one ray per ``d × d`` pixels (``ImageSampleDistance``,
``d ≥ 1``) and scale the picture up. The OpenGL mappers here use it for the frames drawn
while the view moves (``interactive_image_sample_distance``, default
:data:`INTERACTIVE_IMAGE_SAMPLE_DISTANCE`), with samples :data:`INTERACTIVE_STEP` times
farther apart (``interactive_step``), and cast every ray at the scene's step at rest:

* :class:`~vtkillum.mappers.IlluminatedVolume` for the frames of a drag
  (:mod:`vtkillum.mappers.accumulation`'s frame 0 while :func:`window_interacting`);
* :class:`~vtkillum.mappers.AmbientScatteringVolume` likewise (:func:`interacting`).

Both decide by the window's desired update rate, which VTK's interactor styles (and
pyvista's, built on them) raise while the user drags and set back to the still rate, with
one more render, when the drag ends: that frame and every frame a script renders (a
screenshot, a camera path) cast every ray.

Why: a GPU's fragment shaders may run on a few of its multiprocessors. On an NVIDIA H200
(data-centre Hopper), VTK's own composite ray casting of 512³ data into a 1024² window
takes 60 ms, 26 times the 2.3 ms of the same emission–absorption march as a CUDA kernel
(``benchmarks/bench_opengl.py --profile``; ``docs/benchmarks.md``), so no shading on top of
it can move the camera in 20 ms at every pixel; a quarter of the rays can.
"""

from __future__ import annotations

import math

#: Default image sample distance while the view moves (rays are cast for every second pixel
#: along x and y, and VTK scales the picture up).
INTERACTIVE_IMAGE_SAMPLE_DISTANCE = 2.0

#: Default sample-distance factor while the view moves (samples along a ray twice as far
#: apart).
INTERACTIVE_STEP = 2.0

#: Largest image sample distance accepted (VTK's own limit for its automatic adjustment is
#: of this order; beyond it a frame is a few blocks).
MAX_IMAGE_SAMPLE_DISTANCE = 32.0


def image_sample_distance(value) -> float:
    """``value`` as an image sample distance (a number in ``[1, 32]``), or a ``ValueError``
    naming ``interactive_image_sample_distance``."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"interactive_image_sample_distance must be a number in [1, "
                         f"{MAX_IMAGE_SAMPLE_DISTANCE:g}], got {value!r}") from None
    if not (math.isfinite(value) and 1.0 <= value <= MAX_IMAGE_SAMPLE_DISTANCE):
        raise ValueError(f"interactive_image_sample_distance must be a number in [1, "
                         f"{MAX_IMAGE_SAMPLE_DISTANCE:g}], got {value}")
    return value


def interactive_step(value) -> float:
    """``value`` as a sample-distance factor (a number >= 1), or a ``ValueError`` naming
    ``interactive_step``."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"interactive_step must be a number >= 1, got {value!r}") from None
    if not (math.isfinite(value) and value >= 1.0):
        raise ValueError(f"interactive_step must be a number >= 1, got {value}")
    return value


def window_interacting(window) -> bool:
    """Whether an interactor style is moving the view of ``window``: its interactor is
    initialised and the window's desired update rate is above the interactor's still rate
    (VTK's styles raise it to the interactor's desired rate while a button is down or the
    wheel turns, and set it back, rendering once more, when the interaction ends). Scripts
    that move the camera and render, with or without an interactor, draw still frames."""
    interactor = window.GetInteractor() if window is not None else None
    if interactor is None or not interactor.GetInitialized():
        return False
    return window.GetDesiredUpdateRate() > interactor.GetStillUpdateRate()


def interacting(prop) -> bool:
    """Whether a renderer showing ``prop`` is in a window an interactor style is moving
    (:func:`window_interacting`)."""
    if prop is None:
        return False
    for i in range(prop.GetNumberOfConsumers()):
        renderer = prop.GetConsumer(i)
        if renderer is not None and renderer.IsA("vtkRenderer") and \
                window_interacting(renderer.GetRenderWindow()):
            return True
    return False


class InteractiveSampling:
    """The two coarsenings of a drag, as properties of an OpenGL volume (a mixin).

    :attr:`interactive_image_sample_distance` and :attr:`interactive_step` (checked by
    :func:`image_sample_distance` and :func:`interactive_step`); the volume calls
    :meth:`sample_for` before each render with whether the view is moving. It needs a
    ``mapper`` (VTK's GPU ray caster) and a shader that scales its step by the uniform
    ``il_stepScale``.
    """

    _interactive_isd = 1.0
    _interactive_step = 1.0

    @property
    def interactive_image_sample_distance(self) -> float:
        """Pixels per ray along x and y while an interactor style moves the view (VTK's
        ``ImageSampleDistance``: the ray caster draws into a buffer this many times smaller
        along each axis and scales it up; default :data:`INTERACTIVE_IMAGE_SAMPLE_DISTANCE`,
        1: every pixel). Frames drawn at rest, the one that ends a drag and every frame a
        script renders cast a ray for every pixel (the module docstring says why)."""
        return self._interactive_isd

    @interactive_image_sample_distance.setter
    def interactive_image_sample_distance(self, value: float) -> None:
        self._interactive_isd = image_sample_distance(value)

    @property
    def interactive_step(self) -> float:
        """Sample-distance factor while an interactor style moves the view (default
        :data:`INTERACTIVE_STEP`; 1: the scene's step). Frames drawn at rest, the one that
        ends a drag and every frame a script renders sample at the scene's step."""
        return self._interactive_step

    @interactive_step.setter
    def interactive_step(self, value: float) -> None:
        self._interactive_step = interactive_step(value)

    def sample_for(self, moving: bool, uniforms) -> None:
        """Set this frame's image sample distance and step factor (``uniforms``: the
        shader's custom uniforms) for a moving or resting view. VTK's setter modifies the
        mapper only when the value changes."""
        uniforms.SetUniformf("il_stepScale", float(self._interactive_step) if moving else 1.0)
        self.mapper.SetImageSampleDistance(float(self._interactive_isd) if moving else 1.0)
