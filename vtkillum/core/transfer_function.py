"""Piecewise-linear colour and opacity transfer functions and the optical model.

Conventions (``DESIGN.md``): extinction is grey,
``sigma_t(s) = -ln(1 - alpha(s)) / u`` with ``u`` the opacity unit distance and
``alpha`` clamped below 1; the scattering coefficient is
``sigma_s,c = albedo * color_c(s) * sigma_t``. Outside its control points a
transfer function is constant.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Largest opacity used when converting to extinction (alpha = 1 means infinite sigma_t).
MAX_ALPHA = 1.0 - 1e-6

#: Number of entries of the lookup tables handed to the kernels.
TABLE_SIZE = 4096

#: Bound of the tables' range: half the largest float32 (the kernels' precision), so that
#: even ``hi - lo`` is finite in float32.
TABLE_RANGE_MAX = float(np.finfo(np.float32).max) / 2.0


@dataclass
class TransferFunction:
    """Colour and opacity as piecewise-linear functions of the data value.

    Parameters
    ----------
    scalars : sequence of float
        Control points in data units, strictly increasing.
    opacity : sequence of float
        Opacity ``alpha`` in [0, 1] at each control point (per unit distance ``u``).
    colors : sequence of (3,) float, optional
        RGB in [0, 1] at each control point; white when omitted. Used as emission
        colour in the emission-absorption mode and as scattering colour elsewhere.
    """

    scalars: np.ndarray
    opacity: np.ndarray
    colors: np.ndarray = field(default=None)

    def __post_init__(self) -> None:
        for name in ("scalars", "opacity", "colors"):
            _check_numeric(getattr(self, name), name)
        s = np.asarray(self.scalars, dtype=np.float64).reshape(-1)
        a = np.asarray(self.opacity, dtype=np.float64).reshape(-1)
        if s.size == 0:
            raise ValueError("transfer_function.scalars: at least one control point is needed")
        if a.shape != s.shape:
            raise ValueError(
                f"transfer_function.opacity: {a.size} values for {s.size} control points; "
                "give one opacity per scalar control point"
            )
        _check_finite(s, "scalars")
        _check_finite(a, "opacity")
        with np.errstate(over="ignore"):  # points at ±1e308: the gap overflows, still > 0
            increasing = np.all(np.diff(s) > 0)
        if not increasing:
            raise ValueError(
                "transfer_function.scalars: control points must be strictly increasing "
                f"(got {s.tolist()}); sort them together with their opacities and colours"
            )
        if np.any(a < 0) or np.any(a > 1):
            raise ValueError("transfer_function.opacity: values must lie in [0, 1]")
        if self.colors is None:
            c = np.ones((s.size, 3))
        else:
            c = np.asarray(self.colors, dtype=np.float64)
            if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] != s.size:
                raise ValueError(
                    f"transfer_function.colors: expected {s.size} RGB triples, got shape {c.shape}"
                )
            _check_finite(c, "colors")
            if np.any(c < 0) or np.any(c > 1):
                raise ValueError("transfer_function.colors: RGB values must lie in [0, 1]")
        self.scalars, self.opacity, self.colors = s, a, c

    # --- evaluation -----------------------------------------------------------------
    def alpha(self, values) -> np.ndarray:
        """Opacity at ``values`` (piecewise linear, constant outside the control points)."""
        return _interp(np.asarray(values, dtype=np.float64), self.scalars, self.opacity)

    def color(self, values) -> np.ndarray:
        """RGB colour at ``values``, shape ``values.shape + (3,)``."""
        v = np.asarray(values, dtype=np.float64)
        return _interp(v, self.scalars, self.colors)

    def sigma_t(self, values, unit_distance: float) -> np.ndarray:
        """Extinction coefficient ``-ln(1 - alpha) / u`` in 1/world units."""
        check_unit_distance(unit_distance)
        return _sigma_from_alpha(self.alpha(values), unit_distance)

    def sigma_t_and_color(self, values, unit_distance: float):
        """``(sigma_t(values), color(values))`` with one search of the control points (the
        same bits as the two calls: the interpolation is column by column)."""
        check_unit_distance(unit_distance)
        v = np.asarray(values, dtype=np.float64)
        both = _interp(v, self.scalars, np.column_stack([self.opacity, self.colors]))
        return _sigma_from_alpha(both[..., 0], unit_distance), both[..., 1:]

    def domain(self) -> tuple[float, float]:
        """Range of the control points (a single point gives a zero-width range)."""
        return float(self.scalars[0]), float(self.scalars[-1])

    def lookup_tables(self, unit_distance: float, value_range=None, size: int = TABLE_SIZE):
        """Sample the model into tables the kernels interpolate linearly.

        Parameters
        ----------
        unit_distance : float
            Opacity unit distance ``u`` in world units.
        value_range : (float, float), optional
            Data range the table must cover (the kernels look up nothing else). The table
            spans the control points too, but at most one data-range width beyond the data
            on either side: control points far outside the data (say at ±1e30) would
            otherwise make the entries too coarse to resolve the function over the data,
            or overflow float32 (the kernels' precision).
        size : int
            Number of entries.

        Returns
        -------
        sigma_t : ndarray (size,) float32
            Extinction per entry (1/world units).
        color : ndarray (size, 3) float32
            Colour per entry.
        lo, hi : float
            Data values of the first and last entries (finite in float32, ``lo < hi``).
        """
        lo, hi = self.table_range(value_range)
        # Sample alpha (not sigma_t) linearly, as VTK's opacity table does, then convert.
        v = np.linspace(lo, hi, size)
        sigma, color = self.sigma_t_and_color(v, unit_distance)  # one search, same bits
        return sigma.astype(np.float32), color.astype(np.float32), lo, hi

    def table_range(self, value_range=None) -> tuple[float, float]:
        """Data values ``(lo, hi)`` of the first and last entries of :meth:`lookup_tables`."""
        lo, hi = self.domain()
        if value_range is not None:
            vlo, vhi = float(value_range[0]), float(value_range[1])
            lo, hi = min(lo, vlo), max(hi, vhi)
            width = vhi - vlo if vhi > vlo else max(1.0, abs(vlo))
            lo, hi = max(lo, vlo - width), min(hi, vhi + width)
        lo, hi = max(lo, -TABLE_RANGE_MAX), min(hi, TABLE_RANGE_MAX)
        if hi <= lo:
            hi = lo + max(1.0, abs(lo) * 1e-6)
        return lo, hi

    # --- (de)serialisation ---------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dictionary (the scene file's ``transfer_function`` field)."""
        return {
            "scalars": self.scalars.tolist(),
            "opacity": self.opacity.tolist(),
            "colors": self.colors.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "TransferFunction":
        """Inverse of :meth:`to_dict`; raises ``ValueError`` naming a bad field."""
        if not isinstance(d, dict):
            raise ValueError("transfer_function must be an object with scalars/opacity/colors")
        unknown = set(d) - {"scalars", "opacity", "colors"}
        if unknown:
            raise ValueError(f"transfer_function: unknown field(s) {sorted(unknown)}")
        for key in ("scalars", "opacity"):
            if key not in d:
                raise ValueError(f"transfer_function.{key} is missing")
        try:
            return cls(d["scalars"], d["opacity"], d.get("colors"))
        except (TypeError, ValueError) as err:
            if isinstance(err, ValueError) and str(err).startswith("transfer_function"):
                raise
            raise ValueError(f"transfer_function: {err}") from err

    @classmethod
    def ramp(cls, lo: float, hi: float, max_opacity: float = 0.5, color=(1.0, 1.0, 1.0)):
        """Linear opacity ramp from 0 at ``lo`` to ``max_opacity`` at ``hi``, uniform colour."""
        return cls([lo, hi], [0.0, max_opacity], [color, color])


def _sigma_from_alpha(a, unit_distance: float) -> np.ndarray:
    """``-ln(1 - min(a, MAX_ALPHA)) / u``."""
    return -np.log1p(-np.minimum(a, MAX_ALPHA)) / unit_distance


def _interp(x, xp, fp):
    """Piecewise-linear interpolation, constant outside ``xp`` (as ``np.interp``), robust at
    the float64 limits.

    Each value is the convex combination ``(1 - t) f_j + t f_(j+1)`` with
    ``t = (x - x_j) / (x_(j+1) - x_j)`` computed on halved values (exact, and no overflow for
    control points at ±1e308). ``np.interp`` uses slopes instead: across a gap of 1e308 the
    slope is a denormal with few significant bits, which moved values outside the range of
    their control points (negative colours from non-negative ones) or, when the gap
    overflowed, held each segment at its left value. Results stay within ``[min fp, max fp]``.
    ``fp`` may be ``(n, k)``: ``k`` functions of the same control points, column by column.
    """
    x = np.asarray(x, dtype=np.float64)
    xp = np.asarray(xp, dtype=np.float64)
    fp = np.asarray(fp, dtype=np.float64)
    if xp.size == 1:
        return np.full(x.shape + fp.shape[1:], fp[0])
    shape = x.shape
    x = x.reshape(-1)  # (0-d input: in-place operations need arrays)
    j = np.searchsorted(xp, x, side="right")
    j -= 1
    np.maximum(j, 0, out=j)  # (np.clip is several times slower on small arrays)
    np.minimum(j, xp.size - 2, out=j)
    # In place where it saves temporaries (tables of thousands of entries per edit); the
    # same operations, so the same bits, as the plain expressions.
    half = 0.5 * xp
    lo = half[j]
    t = 0.5 * x
    t -= lo
    t /= half[1:][j] - lo
    np.maximum(t, 0.0, out=t)
    np.minimum(t, 1.0, out=t)
    if fp.ndim > 1:  # several functions (columns of fp) at once: one search
        # Column by column, each a contiguous row of the transposed table: numpy broadcasts
        # over a short inner axis (the columns) several times slower. The same operations.
        cols = fp.reshape(fp.shape[0], -1).T
        out = (1.0 - t) * np.take(cols, j, axis=1)
        out += t * np.take(cols[:, 1:], j, axis=1)
        np.maximum(out, cols.min(axis=1)[:, None], out=out)
        np.minimum(out, cols.max(axis=1)[:, None], out=out)
        return np.ascontiguousarray(out.T).reshape(shape + fp.shape[1:])
    out = (1.0 - t) * np.take(fp, j)
    out += t * np.take(fp[1:], j)
    np.maximum(out, fp.min(), out=out)
    np.minimum(out, fp.max(), out=out)
    return out.reshape(shape)


def _check_numeric(values, name: str) -> None:
    """Refuse strings, booleans and other non-numbers (numpy would turn "0.5" into 0.5), and
    masked arrays with masked values (``np.asarray`` would keep whatever lies under the
    mask: a transfer function needs every value)."""
    if values is None:
        return
    masked = int(np.count_nonzero(np.ma.getmaskarray(values))) if np.ma.isMaskedArray(values) \
        else 0
    if masked:
        raise ValueError(f"transfer_function.{name} is a masked array with {masked} masked "
                         "value(s): a transfer function needs a value at every control point; "
                         "fill them (array.filled(value)) or leave those control points out")
    try:
        kind = np.asarray(values).dtype.kind
    except ValueError:  # ragged nested lists
        kind = "O"
    if kind not in "iuf":
        text = repr(values)
        text = text if len(text) <= 80 else text[:77] + "..."
        raise ValueError(f"transfer_function.{name} must hold numbers, got {text}")


def _check_finite(values: np.ndarray, name: str) -> None:
    """Refuse NaN and infinities, naming the first control point that holds one."""
    bad = ~np.isfinite(values)
    if bad.any():
        index = int(np.argwhere(bad)[0][0])
        value = values.reshape(values.shape[0], -1)[index]
        value = value[~np.isfinite(value)][0]
        raise ValueError(f"transfer_function.{name}: {value} at control point {index} "
                         f"({int(bad.reshape(bad.shape[0], -1).any(1).sum())} control point(s) "
                         "hold NaN or infinity); every value must be a finite number")


def check_unit_distance(u: float) -> float:
    """Validate the opacity unit distance (positive and finite)."""
    try:
        value = float(u)  # (np.isfinite refuses Python integers beyond 64 bits)
    except (TypeError, ValueError, OverflowError):
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        text = repr(u) if len(repr(u)) <= 80 else repr(u)[:50] + "..."
        raise ValueError(f"opacity_unit_distance must be positive and finite, got {text}")
    return value
