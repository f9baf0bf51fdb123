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


#: Lines that warp's native library prints on a machine without an NVIDIA driver; they are
#: expected there (the CPU is used) and dropped. ``vtkillum info`` says which devices exist.
_EXPECTED_NATIVE_MESSAGES = ("Could not find or load the NVIDIA CUDA driver",)


@lru_cache(maxsize=1)
def init_warp() -> None:
    """Initialise warp once, quietly.

    No start-up banner (``wp.config.log_level``), and no "Warp CUDA warning: Could not
    find or load the NVIDIA CUDA driver" on a machine without one: warp's native library
    prints it straight to file descriptor 2 while it initialises, so that descriptor is
    captured for the duration of ``wp.init()`` and everything else it printed is passed on.
    """
    wp.config.quiet = True
    # warp >= 1.10 prints its banner through a logger with levels (30: warnings only).
    if isinstance(getattr(wp.config, "log_level", None), int):
        wp.config.log_level = max(wp.config.log_level, 30)
    with _native_stderr_filtered(_EXPECTED_NATIVE_MESSAGES):
        wp.init()


class _native_stderr_filtered:
    """Capture file descriptor 2 (C-level stderr) and re-emit it without the given lines.

    Falls back to doing nothing where descriptor 2 cannot be duplicated (no stderr).
    """

    def __init__(self, drop):
        self.drop, self.saved, self.capture = tuple(drop), None, None

    def __enter__(self):
        import sys
        import tempfile

        try:
            sys.stderr.flush()
        except (AttributeError, ValueError, OSError):
            pass
        try:
            self.saved = os.dup(2)
        except OSError:
            return self
        self.capture = tempfile.TemporaryFile()
        os.dup2(self.capture.fileno(), 2)
        return self

    def __exit__(self, *exc):
        if self.saved is None:
            return False
        import sys

        os.dup2(self.saved, 2)
        os.close(self.saved)
        self.capture.seek(0)
        text = self.capture.read().decode("utf-8", "replace")
        self.capture.close()
        kept = [line for line in text.splitlines(keepends=True)
                if not any(d in line for d in self.drop)]
        if kept:
            try:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()
            except (AttributeError, ValueError, OSError):
                pass
        return False


def available_devices() -> list[str]:
    """Names of the warp devices on this machine, e.g. ``['cpu', 'cuda:0']``."""
    init_warp()
    return [str(d) for d in wp.get_devices()]


def describe_devices() -> list[str]:
    """One line per warp device (name, model, memory), plus why CUDA is absent if it is.

    What ``vtkillum info`` prints; the default device is marked.
    """
    init_warp()
    default = resolve_device(None) if not os.environ.get(ENV_VAR, "").strip() else None
    lines = []
    for d in wp.get_devices():
        name = str(d)
        if d.is_cuda:
            what = f"{d.name}, {d.total_memory / 2**30:.0f} GiB"
        else:
            import platform

            what = f"{platform.processor() or platform.machine() or 'CPU'}, {os.cpu_count()} " \
                   "logical cores (warp runs kernels on one)"
        mark = " (default)" if name == default else ""
        lines.append(f"{name}{mark}: {what}")
    if not wp.is_cuda_available():
        try:
            driver = wp.get_cuda_driver_version()
        except Exception:  # noqa: BLE001 - only a detail of the message
            driver = None
        why = "no NVIDIA CUDA driver found" if not driver else "no CUDA device visible"
        lines.append(f"cuda: not available ({why}); rendering runs on the CPU")
    return lines


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
