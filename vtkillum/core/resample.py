"""Trilinear resampling of point-centred grids onto another resolution of the same box."""

from __future__ import annotations

import numpy as np


def resample_points(array, shape) -> np.ndarray:
    """Trilinear values of a point-centred ``[i, j, k(, c)]`` array on a grid of ``shape`` points.

    The new grid covers the same box (same first and last points), as
    :func:`vtkillum.io.convert.image_like` lays out a resampled grid; its points are
    interpolated from the ``2 x 2 x 2`` old points around them, the way VTK and the kernels
    sample data. Linear interpolation between aligned grids is separable, so it runs axis
    by axis. float64 input stays float64, anything else becomes float32.
    """
    a = np.asarray(array)
    shape = tuple(int(n) for n in shape)
    if a.ndim not in (3, 4) or len(shape) != 3 or min(shape) < 2 or min(a.shape[:3]) < 2:
        raise ValueError(f"cannot resample an array of shape {a.shape} to {shape}: both need "
                         ">= 2 points per axis")
    out = a.astype(np.float64 if a.dtype == np.float64 else np.float32)
    for axis in range(3):
        n, m = out.shape[axis], shape[axis]
        if n == m:
            continue
        x = np.arange(m) * ((n - 1) / (m - 1))
        i0 = np.clip(np.floor(x).astype(np.int64), 0, n - 2)
        f = (x - i0).reshape((-1,) + (1,) * (out.ndim - axis - 1))
        lo, hi = np.take(out, i0, axis=axis), np.take(out, i0 + 1, axis=axis)
        out = lo + (hi - lo) * f.astype(out.dtype)
    return out


def scaled_shape(dims, scale: float) -> tuple[int, int, int]:
    """Points per axis of a grid at ``scale`` times the resolution of one with ``dims`` points.

    ``round((n - 1) * scale) + 1``, at least 2: the *cells* scale, so the coarse grid keeps
    the first and last points (the box) and ``scale = 0.5`` halves the spacing exactly when
    ``n - 1`` is even.
    """
    if not (0.0 < float(scale) <= 1.0):
        raise ValueError(f"a grid scale must lie in (0, 1], got {scale}")
    return tuple(int(max(2, round((int(n) - 1) * float(scale)) + 1)) for n in dims)
