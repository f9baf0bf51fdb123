"""Choice of the warp device (CUDA when present, else CPU).

The device is resolved in this order: an explicit ``device`` argument, the
``VTKILLUM_DEVICE`` environment variable, then ``"cuda"`` if warp sees a CUDA
device, else ``"cpu"``.
"""

from __future__ import annotations

import os
from functools import lru_cache

import warp as wp

ENV_VAR = "VTKILLUM_DEVICE"


@lru_cache(maxsize=1)
def init_warp() -> None:
    """Initialise warp once, quietly (no start-up banner)."""
    wp.config.quiet = True
    # warp >= 1.10 prints its banner through a logger with levels (30: warnings only).
    if isinstance(getattr(wp.config, "log_level", None), int):
        wp.config.log_level = max(wp.config.log_level, 30)
    wp.init()


def available_devices() -> list[str]:
    """Names of the warp devices on this machine, e.g. ``['cpu', 'cuda:0']``."""
    init_warp()
    return [str(d) for d in wp.get_devices()]


def resolve_device(device: str | None = None) -> str:
    """Return the warp device name to run on.

    Parameters
    ----------
    device : str, optional
        ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or ``None``/``"auto"`` for the default
        (the ``VTKILLUM_DEVICE`` environment variable, else CUDA when present).

    Raises
    ------
    ValueError
        If the device is unknown or not present on this machine.
    """
    init_warp()
    if device is None or str(device).lower() in ("", "auto"):
        device = os.environ.get(ENV_VAR, "auto")
    device = str(device).lower()
    names = available_devices()
    if device == "auto":
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if device == "cuda":
        device = "cuda:0"
    if device not in names:
        raise ValueError(
            f"device {device!r} is not available (this machine has {names}); "
            f"pass device='cpu' or unset {ENV_VAR}."
        )
    return device
