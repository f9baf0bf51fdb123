"""A scalar volume on a uniform grid, in the geometry of ``vtkImageData``.

Arrays are indexed ``[i, j, k]`` (x, y, z), i.e. VTK's point order reshaped with
``order='F'``. Samples are point-centred and interpolated trilinearly. Kernels
work in the volume's *local frame*: ``p_local = direction.T @ (p_world - origin)``,
in which the volume spans ``[0, (n - 1) * spacing]`` along each axis.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


class GridGeometry:
    """Geometry of a uniform grid from its ``dims``, ``spacing``, ``origin`` and ``direction``.

    Shared by :class:`Volume` and by light-weight stand-ins that describe a grid without
    holding its data (the mappers' ``GridSummary``).
    """

    @property
    def extent(self) -> np.ndarray:
        """Size of the grid in its local frame, ``(n - 1) * spacing``."""
        return (np.asarray(self.dims) - 1) * self.spacing

    @property
    def bounds(self) -> np.ndarray:
        """World-space axis-aligned bounds ``(xmin, xmax, ymin, ymax, zmin, zmax)``."""
        corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        world = (corners * self.extent) @ self.direction.T + self.origin
        return np.stack([world.min(0), world.max(0)], 1).reshape(-1)

    def mean_spacing(self) -> float:
        """Default opacity unit distance (VTK uses the mean spacing too)."""
        return float(self.spacing.mean())

    def to_local(self, points) -> np.ndarray:
        """World points ``(..., 3)`` to the local frame."""
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.direction

    def to_local_direction(self, vectors) -> np.ndarray:
        """World directions ``(..., 3)`` to the local frame."""
        return np.asarray(vectors, dtype=np.float64) @ self.direction


@dataclass
class Volume(GridGeometry):
    """Point-centred scalar field on a uniform grid.

    Parameters
    ----------
    scalars : ndarray (nx, ny, nz)
        One real value per grid point. Converted to float32.
    spacing : (3,) float
        Positive distance between grid points along x, y, z (world units).
    origin : (3,) float
        World position of point ``[0, 0, 0]``.
    direction : (3, 3) float
        Orthonormal direction matrix (columns: the grid axes in world space).
    nan_policy : {"raise", "fill"}
        What to do with NaN/Inf samples: raise, or replace them with the smallest
        finite value (they then render like the most transparent data).
        The masked samples of a numpy masked array count as NaN: with ``"fill"`` they
        render like the smallest value (transparent under the usual transfer functions
        that start at opacity 0); with ``"raise"`` the error says how many are masked.

    Notes
    -----
    A Volume is a value: its caches (:attr:`content_key`, :attr:`value_range`,
    :meth:`derived`) are computed once. So that they can never go stale, the Volume keeps
    its own copy of the data whenever it would otherwise share the caller's memory (a
    float32 C-ordered input), its arrays are read-only (``writeable=False``: an in-place
    edit raises ``ValueError``), and its fields cannot be reassigned. To change the data,
    make a new Volume, e.g. ``dataclasses.replace(v, scalars=edited)``.
    """

    scalars: np.ndarray
    spacing: np.ndarray = (1.0, 1.0, 1.0)
    origin: np.ndarray = (0.0, 0.0, 0.0)
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    nan_policy: str = "raise"

    def __post_init__(self) -> None:
        s = source = np.asarray(self.scalars)
        if s.dtype.kind == "c" or s.dtype.kind not in "biuf":
            raise ValueError(f"volume scalars must be real numbers, got dtype {s.dtype}")
        # np.asarray drops a mask and keeps whatever lies under it: masked samples are NaN.
        mask = np.ma.getmaskarray(self.scalars) if np.ma.isMaskedArray(self.scalars) else None
        masked = int(np.count_nonzero(mask)) if mask is not None else 0
        if masked:
            s = s.astype(np.float32)  # a copy: the caller's data stay as they are
            s[mask] = np.nan
        if s.ndim == 4 and s.shape[-1] == 1:
            s = s[..., 0]
        if s.ndim != 3:
            raise ValueError(
                f"volume scalars must be a 3D array (nx, ny, nz) with one component, got shape "
                f"{s.shape}; for multi-component data choose one component or the magnitude"
            )
        if min(s.shape) < 2:
            raise ValueError(
                f"volume dimensions {s.shape}: volume rendering needs at least 2 points along "
                "each axis (a 2D image or a single voxel has no thickness); resample or pad it"
            )
        s = s.astype(np.float32, copy=False)
        finite = np.isfinite(s)
        if not finite.all():
            bad = int((~finite).sum())
            if self.nan_policy == "fill":
                if not finite.any():
                    raise ValueError("volume scalars: every sample is NaN or Inf")
                s = np.where(finite, s, s[finite].min()).astype(np.float32)
            elif self.nan_policy == "raise":
                if masked:
                    raise ValueError(
                        f"volume scalars: {masked} sample(s) are masked (a numpy masked array; "
                        f"{bad} NaN/Inf in all, masked ones counted as NaN); pass "
                        "nan_policy='fill' to render them like the smallest value (transparent "
                        "under transfer functions that start at opacity 0), or fill them "
                        "yourself (array.filled(value))")
                raise ValueError(
                    f"volume scalars: {bad} sample(s) are NaN or Inf; clean them "
                    "(np.nan_to_num) or pass nan_policy='fill' to replace them with the minimum"
                )
            else:
                raise ValueError("nan_policy must be 'raise' or 'fill'")
        s = np.ascontiguousarray(s)
        if np.may_share_memory(s, source) and not _frozen(source):
            s = s.copy()  # the caller's array: its later edits must not reach this Volume
        s.flags.writeable = False
        self.scalars = s
        sp = np.array(self.spacing, dtype=np.float64).reshape(-1)
        if sp.shape != (3,) or not np.all(np.isfinite(sp)) or np.any(sp <= 0):
            raise ValueError(
                f"volume spacing must be three positive numbers, got {np.asarray(self.spacing)}; "
                "a negative spacing flips an axis: flip the array and move the origin instead"
            )
        sp.flags.writeable = False
        self.spacing = sp
        o = np.array(self.origin, dtype=np.float64).reshape(-1)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError("volume origin must be three finite numbers")
        o.flags.writeable = False
        self.origin = o
        d = np.array(self.direction, dtype=np.float64)
        if d.shape != (3, 3) or not np.allclose(d.T @ d, np.eye(3), atol=1e-6):
            raise ValueError("volume direction must be an orthonormal 3x3 matrix")
        d.flags.writeable = False
        self.direction = d
        self._derived = {}
        object.__setattr__(self, "_initialised", True)

    def __setattr__(self, name, value) -> None:
        if name in _DATA_FIELDS and getattr(self, "_initialised", False):
            raise AttributeError(
                f"Volume.{name} cannot be replaced: a Volume is a value whose caches are keyed "
                f"on its content; make a new one, e.g. dataclasses.replace(volume, {name}=...)"
            )
        object.__setattr__(self, name, value)

    @property
    def dims(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.scalars.shape)

    @cached_property
    def value_range(self) -> tuple[float, float]:
        """``(min, max)`` of the scalars, computed once (a full pass over large volumes).

        A Volume is a value: to change the data, make a new Volume rather than writing
        into ``scalars`` in place, or this and the caches keyed on it go stale.
        """
        return float(self.scalars.min()), float(self.scalars.max())

    @cached_property
    def content_key(self) -> str:
        """:func:`array_digest` of the scalars, computed once per Volume (see ``value_range``)."""
        return array_digest(self.scalars)

    def derived(self, name: str, key, make):
        """Data derived from this volume, kept with it: ``make()`` runs again only when ``key``
        differs from the one stored under ``name``.

        Renders that are called again and again with the same Volume (a camera moving in an
        interactive window, a benchmark) reuse the device copy of the scalars and camera-
        independent light volumes instead of recomputing them per frame. One entry per
        ``name``, so an edited transfer function replaces its predecessor; everything is
        freed with the Volume.
        """
        entry = self._derived.get(name)
        if entry is None or entry[0] != key:
            entry = (key, make())
            self._derived[name] = entry
        return entry[1]


_DATA_FIELDS = frozenset({"scalars", "spacing", "origin", "direction", "nan_policy"})


def _frozen(array: np.ndarray) -> bool:
    """An array nobody can write to: read-only and owning its memory (e.g. another Volume's)."""
    return not array.flags.writeable and array.base is None


def array_digest(array) -> str:
    """Content key of an array: a hash of every value, the shape and the dtype.

    Caches use it to recognise unchanged data in a new array object (e.g. a filter's
    fresh conversion of the same input).
    """
    a = np.ascontiguousarray(array)
    h = hashlib.blake2b(memoryview(a).cast("B"), digest_size=16)
    h.update(repr((a.shape, a.dtype.str)).encode())
    return h.hexdigest()
