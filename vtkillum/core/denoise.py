"""Optional denoising of Monte Carlo pictures with Intel Open Image Denoise.

``pip install 'vtkillum[denoise]'`` brings ``pyoidn`` (Intel Open Image Denoise's Python
binding, CPU; Apache 2.0). ``vtkillum render ... --denoise -o picture.png`` then runs
its ``RT`` filter on the linear HDR radiance of ``path``, ``photon`` or ``many-lights``
before the tone map; ``.npy``/``.npz`` outputs keep the raw radiance (the estimate the
method computed, for measurements).

What it does and does not remove, on the MNI brain at 128² (reference: ``path`` 4096
spp, rel. RMSE): ``path`` 4 spp 0.39 → 0.10, 256 spp 0.046 → 0.030; the low-frequency
errors of the other two it leaves (photon kernel blur 0.116 → 0.113, a set of
virtual lights 0.211 → 0.210): it is trained on pixel noise. It takes colour only (no
albedo or normal buffers: a volume has no single surface to give them at).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: Methods whose pictures the command line denoises.
METHODS = ("path", "photon", "many-lights")
#: What to install.
INSTALL = "pip install 'vtkillum[denoise]'  (Intel Open Image Denoise: pyoidn)"


def available() -> bool:
    """Whether ``pyoidn`` can be imported."""
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return False
    return True


def denoise(radiance: np.ndarray) -> np.ndarray:
    """Denoised copy of linear HDR ``radiance`` (H, W, 3), float32, non-negative.

    Raises
    ------
    ImportError
        Without ``pyoidn`` (the message says what to install).
    """
    try:
        import pyoidn
    except ImportError as err:
        raise ImportError(f"denoising needs Intel Open Image Denoise: {INSTALL}") from err
    color = np.ascontiguousarray(np.maximum(np.asarray(radiance, np.float32), 0.0))
    if color.ndim != 3 or color.shape[2] != 3:
        raise ValueError(f"radiance must be (H, W, 3), got shape {color.shape}")
    return np.maximum(np.asarray(pyoidn.denoise(color, hdr=True), np.float32), 0.0)


def for_output(result, output, method: str, enabled: bool):
    """``result`` as the command line writes it to ``output``: with ``enabled``, a PNG of
    ``path``, ``photon`` or ``many-lights`` gets denoised radiance; other formats keep
    the raw one. Returns a new :class:`~vtkillum.core.render.RenderResult` (``info``
    ``denoised`` True) or ``result`` itself.

    Raises
    ------
    ValueError
        ``enabled`` for another method (nothing to denoise: no Monte Carlo noise).
    """
    if not enabled:
        return result
    if method not in METHODS:
        raise ValueError(f"--denoise applies to {', '.join(METHODS)} (Monte Carlo noise); "
                         f"{method!r} has none")
    if Path(output).suffix.lower() != ".png":
        return result
    from vtkillum.core.render import RenderResult

    return RenderResult(denoise(result.radiance), result.alpha,
                        dict(result.info, denoised=True))


class RequireDenoiser(argparse.Action):
    """The command line's ``--denoise`` flag: refused at once, before any render, when
    ``pyoidn`` is missing."""

    def __init__(self, option_strings, dest, **kwargs):
        kwargs.setdefault("default", False)
        super().__init__(option_strings, dest, nargs=0, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        if not available():
            parser.error(f"{option_string} needs Intel Open Image Denoise: {INSTALL}")
        setattr(namespace, self.dest, True)
