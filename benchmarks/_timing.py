"""What the benchmarks share: the device's name, the GPU/kernel time a method reports in
``result.info``, and the peak device memory of a stretch of work.

Kernel time (:func:`kernel_seconds`): every method times its own device stages and
reports them under its own keys; this reads them all in one place. The ray caster
(``emission``, ``single`` and the ray-cast stage of ``transmittance`` and
``convection-diffusion``) reports ``render_s``; ``transmittance`` adds ``light_volume_s``
when it computed its light volume; ``convection-diffusion`` adds its solver's stage
times (``info["convection_diffusion"]["ms"]``); ``path`` ``ms_per_pass`` × ``passes``;
``ambient-scattering`` and ``photon`` ``timings_ms`` (per stage, device synchronised);
``many-lights`` ``setup_ms`` + ``render_ms``; ``refraction`` ``sweep_s``. A method that
reports none gives ``None`` (printed "–").

Peak memory (:class:`MemoryProbe`): on CUDA the high-water mark of warp's memory pool
(``wp.get_mempool_used_mem_high``), reset between rows through the CUDA driver
(``cuMemPoolSetAttribute(USED_MEM_HIGH, 0)``; where that fails the mark counts from the
start of the run and the probe says so); on the CPU the bytes held by warp's allocator
(:func:`vtkillum.core.memory.track_allocations`). Neither counts CUDA texture arrays.
"""

from __future__ import annotations

import ctypes

import numpy as np


def device_name(device: str) -> str:
    """``"NVIDIA H200"`` or ``"cpu (x86_64)"``."""
    import warp as wp

    d = wp.get_device(device)
    return d.name if d.is_cuda else f"cpu ({d.name})"


def kernel_seconds(info: dict) -> float | None:
    """Device time of a render's stages from its ``result.info``, seconds, or ``None``."""
    total, found = 0.0, False
    if "render_s" in info:
        total += float(info["render_s"])
        found = True
    if "light_volume_s" in info:  # transmittance: light volume (0 when cached)
        total += float(info["light_volume_s"])
    cd = info.get("convection_diffusion")
    if isinstance(cd, dict) and isinstance(cd.get("ms"), dict):
        ms = {k: float(np.sum(v)) for k, v in cd["ms"].items()
              if isinstance(v, (int, float, np.floating, list, tuple))}
        total += 1e-3 * float(ms["total"] if "total" in ms else sum(ms.values()))
        found = True
    if "ms_per_pass" in info and "passes" in info:
        total += 1e-3 * float(info["ms_per_pass"]) * int(info["passes"])
        found = True
    if "sweep_s" in info:
        total += float(info["sweep_s"])
        found = True
    if "setup_ms" in info and "render_ms" in info:
        total += 1e-3 * (float(info["setup_ms"]) + float(info["render_ms"]))
        found = True
    elif isinstance(info.get("timings_ms"), dict) and not found:
        total += 1e-3 * sum(float(v) for v in info["timings_ms"].values()
                            if isinstance(v, (int, float, np.floating)))
        found = True
    return total if found else None


def fmt_ms(seconds: float | None, digits: int = 1) -> str:
    """Milliseconds with ``digits`` decimals, or "–"."""
    return "–" if seconds is None else f"{1e3 * seconds:.{digits}f}"


class MemoryProbe:
    """Peak device bytes between :meth:`reset` and :meth:`peak` (see the module docstring).

    Use as a context manager around the whole benchmark (on the CPU it installs the
    allocation counter).
    """

    def __init__(self, device: str) -> None:
        import warp as wp

        self.device = device
        self.cuda = wp.get_device(device).is_cuda
        self.pool = self.cuda and wp.is_mempool_enabled(device)
        self.resettable = False
        self._counter = None
        self._context = None
        self._driver = None

    def __enter__(self):
        if not self.cuda:
            from vtkillum.core.memory import track_allocations

            self._context = track_allocations(self.device)
            self._counter = self._context.__enter__()
        elif self.pool:
            self._driver = _mempool_resetter(self.device)
            self.resettable = self._driver is not None
        return self

    def __exit__(self, *exc):
        if self._context is not None:
            self._context.__exit__(*exc)
        return False

    def reset(self) -> None:
        """Start a new high-water mark at what is held now."""
        import warp as wp

        if self._counter is not None:
            self._counter.reset()
        elif self.pool:
            wp.synchronize_device(self.device)
            if self._driver is not None:
                self.resettable = self._driver()

    def peak(self) -> int | None:
        """High-water bytes since :meth:`reset` (CUDA without a reset: since the start)."""
        import warp as wp

        if self._counter is not None:
            return int(self._counter.high)
        if self.pool:
            wp.synchronize_device(self.device)
            return int(wp.get_mempool_used_mem_high(self.device))
        return None

    def free(self) -> int | None:
        """Bytes free on the device now (CUDA), ``None`` on the CPU."""
        import warp as wp

        return int(wp.get_device(self.device).free_memory) if self.cuda else None

    def total(self) -> int | None:
        import warp as wp

        return int(wp.get_device(self.device).total_memory) if self.cuda else None


def _mempool_resetter(device: str):
    """A function that zeroes the device memory pool's used-memory high-water mark (CUDA
    driver API), or ``None`` when the driver cannot be reached."""
    import warp as wp

    try:
        lib = ctypes.CDLL("libcuda.so.1")
        dev = ctypes.c_int()
        if lib.cuDeviceGet(ctypes.byref(dev), ctypes.c_int(wp.get_device(device).ordinal)):
            return None
        pool = ctypes.c_void_p()
        if lib.cuDeviceGetMemPool(ctypes.byref(pool), dev):
            return None
    except (OSError, AttributeError):
        return None
    used_mem_high = 8  # CU_MEMPOOL_ATTR_USED_MEM_HIGH

    def reset() -> bool:
        zero = ctypes.c_uint64(0)
        return lib.cuMemPoolSetAttribute(pool, ctypes.c_int(used_mem_high),
                                         ctypes.byref(zero)) == 0

    return reset
