"""Animations of rendered frames: animated GIF and MP4, written all-or-nothing.

``.gif`` is written with Pillow (a dependency of vtkillum): each frame gets its own
256-colour palette, frames loop forever. ``.mp4`` (H.264, ``yuv420p``, which every
player shows) needs the optional extra ``animation`` (``pip install
'vtkillum[animation]'``: imageio and imageio-ffmpeg, which ships an ffmpeg binary);
without it :func:`check_animation_support` raises :class:`MissingDependencyError` naming
the extra, before anything is rendered. H.264 wants even image sides: a frame of odd
width or height gets its last column or row repeated.

Files are written under their final names in a hidden directory next to them and
renamed into place when complete (:func:`vtkillum.io.writers.write_staged`), so an
interrupted or failed write leaves the old file and nothing else.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from vtkillum.io.writers import write_staged

#: Animation formats (by extension, case-insensitive).
ANIMATION_FORMATS = (".gif", ".mp4")

#: The optional dependency group of pyproject.toml that writes ``.mp4``.
EXTRA = "animation"

#: Frames per second when none is given.
DEFAULT_FPS = 10.0


class MissingDependencyError(ImportError):
    """A format needs an optional dependency that is not installed; says which extra."""


def is_animation(path) -> bool:
    """True when ``path`` names an animation format (:data:`ANIMATION_FORMATS`)."""
    return Path(path).suffix.lower() in ANIMATION_FORMATS


def check_animation_support(path) -> None:
    """Raise :class:`MissingDependencyError` when writing ``path`` needs a missing extra.

    ``.gif`` needs only Pillow; ``.mp4`` needs imageio and imageio-ffmpeg.
    """
    if Path(path).suffix.lower() != ".mp4":
        return
    missing = [name for name in ("imageio", "imageio_ffmpeg")
               if importlib.util.find_spec(name) is None]
    if missing:
        raise MissingDependencyError(
            f"writing {Path(path).name} (.mp4) needs {' and '.join(missing)}, which are not "
            f"installed: pip install 'vtkillum[{EXTRA}]' (or write .gif or numbered .png "
            "pictures)")


def write_animation(path, frames, fps: float = DEFAULT_FPS) -> Path:
    """Write ``frames`` (each ``(H, W, 3)`` uint8 RGB, all one size) as ``.gif`` or ``.mp4``.

    Parameters
    ----------
    path : str or Path
        Output file; its extension picks the format (:data:`ANIMATION_FORMATS`).
    frames : sequence of ndarray
        At least one frame.
    fps : float
        Frames per second (positive; a GIF stores delays in 10 ms units).

    Returns
    -------
    Path
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ANIMATION_FORMATS:
        raise ValueError(f"{path}: an animation is one of {', '.join(ANIMATION_FORMATS)}")
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"frames per second must be a positive number, got {fps}")
    frames = [np.ascontiguousarray(f, dtype=np.uint8) for f in frames]
    if not frames:
        raise ValueError(f"{path}: no frames to write")
    if any(f.ndim != 3 or f.shape[2] != 3 or f.shape != frames[0].shape for f in frames):
        raise ValueError(f"{path}: frames must be (H, W, 3) RGB images of one size")
    check_animation_support(path)
    write = _write_gif if suffix == ".gif" else _write_mp4
    write_staged([path], lambda staged: write(staged[path], frames, fps))
    return path


def _write_gif(target: Path, frames, fps: float) -> None:
    from PIL import Image

    images = [Image.fromarray(f, "RGB") for f in frames]
    # Pillow merges identical consecutive frames (their delays add up): still fps frames/s.
    images[0].save(target, format="GIF", save_all=True, append_images=images[1:],
                   duration=max(10, int(round(1000.0 / fps / 10.0)) * 10), loop=0)


def _write_mp4(target: Path, frames, fps: float) -> None:
    import imageio.v2 as imageio

    height, width = frames[0].shape[:2]
    pad = ((0, height % 2), (0, width % 2), (0, 0))  # H.264 (yuv420p) wants even sides
    # macro_block_size=1: imageio would otherwise rescale to multiples of 16.
    with imageio.get_writer(target, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                            pixelformat="yuv420p", macro_block_size=1,
                            ffmpeg_log_level="error") as writer:
        for frame in frames:
            writer.append_data(np.pad(frame, pad, mode="edge") if any(p[1] for p in pad)
                               else frame)


__all__ = ["ANIMATION_FORMATS", "EXTRA", "MissingDependencyError", "check_animation_support",
           "is_animation", "write_animation"]
