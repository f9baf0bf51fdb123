"""Show a VTK render window, or save it where there is no screen.

::

    from vtkillum.mappers.window import show
    show(window, screenshot="picture.png")

On a machine with a display, :func:`show` renders the window, writes the screenshot
(when asked) and starts an interactor; headless (no ``DISPLAY``/``WAYLAND_DISPLAY`` on
Linux, ``VTKILLUM_HEADLESS=1``, or an off-screen window class such as
``vtkOSOpenGLRenderWindow``/``vtkEGLRenderWindow``, which
``VTK_DEFAULT_OPENGL_WINDOW`` selects) it renders off screen and only writes the
screenshot. So the same script runs on a laptop and on a server.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

#: Window classes that never open a window on a screen.
OFFSCREEN_WINDOWS = ("vtkOSOpenGLRenderWindow", "vtkEGLRenderWindow")


def has_display(window=None) -> bool:
    """Whether ``window`` (a ``vtkRenderWindow``) can be shown on a screen."""
    if os.environ.get("VTKILLUM_HEADLESS", "").strip().lower() in ("1", "true", "yes"):
        return False
    if window is not None and window.GetClassName() in OFFSCREEN_WINDOWS:
        return False
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def save_screenshot(window, path) -> Path:
    """Write what ``window`` shows as a PNG (RGB, back buffer)."""
    from vtkmodules.vtkIOImage import vtkPNGWriter
    from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

    grab = vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.Update()
    writer = vtkPNGWriter()
    writer.SetFileName(str(path))
    writer.SetInputConnection(grab.GetOutputPort())
    writer.Write()
    return Path(path)


def show(window, screenshot=None, interact: bool | None = None, refine: bool = True):
    """Render ``window``; write ``screenshot`` (a .png path) if given; interact if possible.

    Parameters
    ----------
    window : vtkRenderWindow
        With its renderers (their cameras' clipping ranges are reset).
    screenshot : str or Path, optional
        PNG written after the first render.
    interact : bool, optional
        Start an interactor (default: when :func:`has_display`).
    refine : bool
        Before the screenshot, render until the mean of the accumulating volumes'
        jittered frames has converged (:mod:`vtkillum.mappers.accumulation`; a still
        picture without speckle). An interactive window refines by itself.

    Returns
    -------
    Path or None
        The screenshot written.
    """
    interact = has_display(window) if interact is None else bool(interact)
    if not interact:
        window.SetOffScreenRendering(1)
    renderers = window.GetRenderers()
    renderers.InitTraversal()
    for _ in range(renderers.GetNumberOfItems()):
        renderers.GetNextItem().ResetCameraClippingRange()
    window.Render()
    if refine and screenshot is not None:
        from vtkillum.mappers.accumulation import existing_accumulator

        renderers.InitTraversal()
        for _ in range(renderers.GetNumberOfItems()):
            accumulator = existing_accumulator(renderers.GetNextItem())
            if accumulator is not None:
                accumulator.refine()
    written = save_screenshot(window, screenshot) if screenshot is not None else None
    if interact:
        import vtkmodules.vtkInteractionStyle  # noqa: F401  (the default interactor style)
        from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor

        interactor = window.GetInteractor() or vtkRenderWindowInteractor()
        interactor.SetRenderWindow(window)
        interactor.Initialize()
        interactor.Start()
    return written
