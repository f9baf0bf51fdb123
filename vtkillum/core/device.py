"""Choice of the warp device (CUDA when present, else CPU).

The device is resolved in this order: an explicit ``device`` argument, the
``VTKILLUM_DEVICE`` environment variable (unset, empty or ``auto``: automatic), then
``"cuda"`` if warp sees a CUDA device, else ``"cpu"``.
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
    if device is None or str(device).strip().lower() in ("", "auto"):
        device = os.environ.get(ENV_VAR, "").strip() or "auto"
    device = str(device).strip().lower()
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


def available_memory(device: str | None = None) -> tuple[int | None, int | None]:
    """Bytes that a new allocation can still get: ``(host, device)``, ``None`` where unknown.

    Host: the smallest of the memory the kernel reports available (``MemAvailable``), the
    room left under the process's address-space and data limits (``ulimit -v`` / ``-d``)
    and under its cgroup's ``memory.max``. Device: the free memory of a CUDA device
    (``None`` for the CPU, whose arrays live in host memory). Linux only; elsewhere the
    host figure is ``None``.
    """
    host = _host_available()
    gpu = None
    if device is not None and str(device).startswith("cuda"):
        try:
            free = int(wp.get_device(device).free_memory)
            gpu = free if free > 0 else None
        except Exception:  # noqa: BLE001 - no figure is better than a failed render
            gpu = None
    return host, gpu


def _host_available() -> int | None:
    candidates = []
    meminfo = _read_kib("/proc/meminfo", "MemAvailable:")
    if meminfo is not None:
        candidates.append(meminfo)
    try:
        import resource

        for limit, used_key in ((resource.RLIMIT_AS, "VmSize:"),
                                (resource.RLIMIT_DATA, "VmData:")):
            soft = resource.getrlimit(limit)[0]
            used = _read_kib("/proc/self/status", used_key)
            if soft != resource.RLIM_INFINITY and soft > 0 and used is not None:
                candidates.append(max(0, soft - used))
    except (ImportError, OSError, ValueError):
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            cap = f.read().strip()
        with open("/sys/fs/cgroup/memory.current") as f:
            current = int(f.read().strip())
        if cap != "max":
            candidates.append(max(0, int(cap) - current))
    except (OSError, ValueError):
        pass
    return min(candidates) if candidates else None


def _read_kib(path: str, key: str) -> int | None:
    """Bytes of a ``key: N kB`` line of a /proc file, or ``None``."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None
