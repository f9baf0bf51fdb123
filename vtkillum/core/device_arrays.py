"""Arrays that stay on the device: transfer accounting and whole-array checks as reductions.

Interactive rendering at the sizes of real data (512³–1024³) is limited by what happens
*between* kernels: a 512³ float32 light grid is 512 MiB, which costs ~50 ms to copy over
PCIe each way and ~100 ms for each numpy pass over it on the host, against ~0.1 ms for a
kernel reading it on an H200. So illumination volumes are made, checked and consumed on
the device:

* :func:`array_stats` checks a whole array (non-finite count, minimum, maximum) in one
  launch whose threads each reduce a strided run and then combine with three atomics;
  only three numbers come back.
* :func:`scaled_nonnegative` makes the clamped, scaled copy a renderer reads, on the
  device.
* :data:`TRAFFIC` counts bytes uploaded and downloaded through :func:`upload` and
  :func:`download` (what the host-work test watches: across two renders with a moved
  camera, no volume-sized transfer may happen).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
import warp as wp

#: Threads of one :func:`array_stats` launch on a GPU: enough to saturate an H200's
#: bandwidth, few enough that the final atomics do not contend.
STATS_THREADS = {"cpu": 1, "cuda": 1 << 16}


@dataclass
class Traffic:
    """Bytes moved between host and device through :func:`upload` / :func:`download`."""

    uploads: int = 0
    upload_bytes: int = 0
    downloads: int = 0
    download_bytes: int = 0
    largest: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def record(self, kind: str, nbytes: int) -> None:
        with self._lock:
            if kind == "upload":
                self.uploads += 1
                self.upload_bytes += int(nbytes)
            else:
                self.downloads += 1
                self.download_bytes += int(nbytes)
            self.largest = max(self.largest, int(nbytes))

    def snapshot(self) -> dict:
        """The counters as a dict (compare two snapshots to see what a call moved)."""
        with self._lock:
            return {"uploads": self.uploads, "upload_bytes": self.upload_bytes,
                    "downloads": self.downloads, "download_bytes": self.download_bytes,
                    "largest": self.largest}

    def reset(self) -> None:
        with self._lock:
            self.uploads = self.upload_bytes = self.downloads = self.download_bytes = 0
            self.largest = 0


#: Process-wide transfer counters.
TRAFFIC = Traffic()


def upload(array: np.ndarray, dtype, device: str) -> wp.array:
    """Copy a numpy array to ``device`` (counted in :data:`TRAFFIC`), with a clear error when
    the device runs out of memory."""
    a = np.ascontiguousarray(array)
    try:
        out = wp.array(a, dtype=dtype, device=device)
    except Exception as err:  # warp raises RuntimeError on allocation failure
        raise MemoryError(
            f"could not allocate {a.nbytes / 2**20:.0f} MiB on {device} ({err}); downsample the "
            "volume (e.g. vtkImageResample), lower light_volume_scale, or render on device='cpu'"
        ) from err
    TRAFFIC.record("upload", a.nbytes)
    return out


def download(array: wp.array) -> np.ndarray:
    """``array.numpy()`` (a host copy for device arrays), counted in :data:`TRAFFIC`."""
    out = array.numpy()
    TRAFFIC.record("download", out.nbytes)
    return out


def flat_float(array: wp.array) -> wp.array:
    """A contiguous float32 warp array (any vector dtype) seen as a 2D float32 array
    ``(rows, columns)``: its last axis times the components, and the rest.

    Two axes, not one: a warp array axis indexes at most 2³¹ values, and a 1024³ grid of
    vec3 holds 3.2 billion floats. No copy: the result aliases ``array``'s memory without
    owning it, so the caller keeps ``array`` alive while using it."""
    if not array.is_contiguous:
        raise ValueError("flat_float needs a contiguous array")
    scalar = getattr(array.dtype, "_wp_scalar_type_", array.dtype)
    if scalar is not wp.float32:
        raise ValueError(f"expected float32 data, got {array.dtype}")
    columns = int(array.shape[-1]) * (wp.types.type_size_in_bytes(array.dtype) // 4)
    rows = int(array.size) // int(array.shape[-1])
    return wp.array(ptr=array.ptr, dtype=wp.float32, shape=(rows, columns),
                    device=array.device)


def array_stats(array: wp.array) -> tuple[int, float, float]:
    """``(non-finite count, min, max)`` of a float32 device array (finite values only), in
    one launch.

    Raises
    ------
    ValueError
        For an empty array.
    """
    if array.size == 0:
        raise ValueError("array_stats of an empty array")
    flat = flat_float(array)
    n = flat.shape[0] * flat.shape[1]
    device = str(array.device)
    threads = int(min(n, STATS_THREADS["cpu" if array.device.is_cpu else "cuda"]))
    out = wp.array(np.array([0.0, np.inf, -np.inf], np.float32), dtype=wp.float32,
                   device=device)
    wp.launch(stats_kernel, dim=threads, inputs=[flat, wp.int64(n), threads, out],
              device=device)
    bad, lo, hi = out.numpy()  # three numbers: not counted as traffic
    return int(bad), float(lo), float(hi)


def scaled_nonnegative(src: wp.array, scale: float, out: wp.array | None = None) -> wp.array:
    """``max(src, 0) * scale`` as a new (or the given) device array of ``src``'s shape and
    dtype, computed on ``src``'s device."""
    if out is None:
        out = wp.empty(src.shape, dtype=src.dtype, device=src.device)
    elif out.shape != src.shape or out.dtype != src.dtype:
        raise ValueError(f"out {out.shape}/{out.dtype} does not match src {src.shape}/{src.dtype}")
    a, b = flat_float(src), flat_float(out)
    wp.launch(scale_clamp_kernel, dim=a.shape, inputs=[a, float(scale), b],
              device=src.device)
    return out


def clamp_max(array: wp.array, hi: float) -> wp.array:
    """A copy of ``array`` with values above ``hi`` set to ``hi``, on its device."""
    out = wp.empty(array.shape, dtype=array.dtype, device=array.device)
    a, b = flat_float(array), flat_float(out)
    wp.launch(clamp_max_kernel, dim=a.shape, inputs=[a, float(hi), b], device=array.device)
    return out


@wp.kernel
def stats_kernel(a: wp.array2d(dtype=wp.float32), n: wp.int64, threads: int,
                 out: wp.array(dtype=wp.float32)):
    """Thread ``wp.tid()`` reduces elements ``tid, tid + threads, ...`` of ``a`` in C order
    (unitless; a 64-bit count: more than 2³¹ elements at 1024³), then adds its non-finite
    count to ``out[0]`` and folds its extremes into ``out[1]`` (min) and ``out[2]`` (max)."""
    t = wp.tid()
    bad = float(0.0)
    lo = float(3.0e38)
    hi = float(-3.0e38)
    columns = wp.int64(a.shape[1])
    i = wp.int64(t)
    while i < n:
        v = a[wp.int32(i / columns), wp.int32(i % columns)]
        if wp.isfinite(v):
            lo = wp.min(lo, v)
            hi = wp.max(hi, v)
        else:
            bad += 1.0
        i += wp.int64(threads)
    if bad > 0.0:
        wp.atomic_add(out, 0, bad)
    wp.atomic_min(out, 1, lo)
    wp.atomic_max(out, 2, hi)


@wp.kernel
def scale_clamp_kernel(a: wp.array2d(dtype=wp.float32), scale: float,
                       out: wp.array2d(dtype=wp.float32)):
    """``wp.tid()`` = element ``(row, column)``: ``out = max(a, 0) * scale``."""
    i, j = wp.tid()
    out[i, j] = wp.max(a[i, j], 0.0) * scale


@wp.kernel
def clamp_max_kernel(a: wp.array2d(dtype=wp.float32), hi: float,
                     out: wp.array2d(dtype=wp.float32)):
    """``wp.tid()`` = element ``(row, column)``: ``out = min(a, hi)``."""
    i, j = wp.tid()
    out[i, j] = wp.min(a[i, j], hi)
