"""The refractive optical model: refractive index η_tf(s) and medium colour m_tf(s).

Magnus & Bruckner 2017, section 4.1, add two transfer functions to colour and
opacity (the Oddy–Willis pigment/medium model):

``η_tf(s)``
    Refractive index (dimensionless, > 0). Rays bend along its gradient
    (:mod:`vtkillum.core.refraction.ray_equation`); only differences of η matter,
    so any constant (the default 1) means straight rays.
``m_tf(s)``
    Colour of the transmissive medium that carries the pigment particles, RGB in
    [0, 1]: the fraction of each channel a path of one opacity unit distance ``u``
    transmits (as ``α`` is the opacity per ``u``). It filters light and view rays
    without reflecting anything: ``M = exp(-∫ κ ds)`` with the medium absorption
    ``κ_c(s) = -ln m_c(s) / u``. White (the default) gives ``κ = 0``: the
    standard Porter–Duff model.

With the defaults every method renders exactly as without them. In the scene
file both live under ``transfer_function``, either with one value per colour /
opacity control point (``scalars``) or with control points of their own::

    "transfer_function": {
      "scalars": [0, 1, 2], "opacity": [0, 0.02, 0.05],
      "refractive_index": [1.0, 1.5, 1.33],                     // per control point
      "medium_color": {"scalars": [0, 0.5, 1, 2],              // or own points
                       "colors": [[1,1,1], [1,1,1], [0.9,1,0.9], [0.95,0.7,0.3]]}
    }

Both are piecewise linear between their control points and constant outside them,
like :class:`~vtkillum.core.transfer_function.TransferFunction`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Smallest medium transmittance used for the absorption ``-ln m / u`` (m = 0 is opaque).
MIN_MEDIUM = 1.0e-6

#: Refractive indices outside this range are refused (float32 ray directions carry |v| = η).
ETA_RANGE = (1.0e-3, 1.0e3)

#: Scene-file keys under ``transfer_function`` that belong to this model.
KEYS = ("refractive_index", "medium_color")


@dataclass
class RefractiveOptics:
    """Refractive-index and medium-colour transfer functions.

    Parameters
    ----------
    eta_scalars : sequence of float
        Control points of ``η_tf`` (data units, strictly increasing).
    eta : sequence of float
        Refractive index at each control point (> 0).
    medium_scalars : sequence of float
        Control points of ``m_tf`` (data units, strictly increasing).
    medium_color : sequence of (3,) float
        Medium colour (RGB transmitted per opacity unit distance) in [0, 1].

    Examples
    --------
    >>> optics = RefractiveOptics([0.0, 1.0], [1.0, 1.5], [0.0, 1.0], [[1, 1, 1], [0.9, 0.6, 0.3]])
    >>> float(optics.eta_at(0.5)), optics.is_identity
    (1.25, False)
    """

    eta_scalars: np.ndarray = (0.0,)
    eta: np.ndarray = (1.0,)
    medium_scalars: np.ndarray = (0.0,)
    medium_color: np.ndarray = ((1.0, 1.0, 1.0),)

    def __post_init__(self) -> None:
        self.eta_scalars, self.eta = _points("refractive_index", self.eta_scalars, self.eta, 1)
        if not np.all(self.eta > 0):
            raise ValueError(
                f"refractive_index: values must be > 0 (1 is vacuum/air, 1.33 water, 1.5 glass), "
                f"got {self.eta.tolist()}")
        if np.any(self.eta < ETA_RANGE[0]) or np.any(self.eta > ETA_RANGE[1]):
            raise ValueError(f"refractive_index: values must lie in [{ETA_RANGE[0]:g}, "
                             f"{ETA_RANGE[1]:g}], got {self.eta.tolist()}")
        self.medium_scalars, self.medium_color = _points(
            "medium_color", self.medium_scalars, self.medium_color, 3)
        if np.any(self.medium_color < 0) or np.any(self.medium_color > 1):
            raise ValueError("medium_color: RGB values must lie in [0, 1] (1 transmits a channel "
                             "fully, 0 absorbs it)")

    # --- construction -----------------------------------------------------------------------
    @classmethod
    def identity(cls) -> RefractiveOptics:
        """η ≡ 1 and m ≡ white: the ordinary (non-refractive, Porter–Duff) model."""
        return cls()

    # --- evaluation -----------------------------------------------------------------------------
    def eta_at(self, values) -> np.ndarray:
        """Refractive index at ``values`` (piecewise linear, constant outside the points)."""
        return np.interp(np.asarray(values, dtype=np.float64), self.eta_scalars, self.eta)

    def medium_at(self, values) -> np.ndarray:
        """Medium colour at ``values``, shape ``values.shape + (3,)``."""
        v = np.asarray(values, dtype=np.float64)
        return np.stack([np.interp(v, self.medium_scalars, self.medium_color[:, c])
                         for c in range(3)], -1)

    def kappa(self, values, unit_distance: float) -> np.ndarray:
        """Medium absorption ``κ = -ln(m) / u`` per channel (1/world units)."""
        if not (np.isfinite(unit_distance) and unit_distance > 0):
            raise ValueError(f"opacity_unit_distance must be positive, got {unit_distance}")
        m = np.maximum(self.medium_at(values), MIN_MEDIUM)
        return -np.log(m) / float(unit_distance)

    @property
    def eta_constant(self) -> bool:
        """Whether η is the same everywhere (rays stay straight, no Fresnel reflection)."""
        return bool(np.all(self.eta == self.eta[0]))

    @property
    def medium_white(self) -> bool:
        """Whether the medium transmits everything (``m ≡ 1``)."""
        return bool(np.all(self.medium_color == 1.0))

    @property
    def is_identity(self) -> bool:
        """η constant and m white: renders exactly like the model without refraction."""
        return self.eta_constant and self.medium_white

    def domain(self) -> tuple[float, float]:
        """Range covered by the control points of both functions."""
        lo = min(self.eta_scalars[0], self.medium_scalars[0])
        hi = max(self.eta_scalars[-1], self.medium_scalars[-1])
        return float(lo), float(hi)

    def tables(self, lo: float, hi: float, size: int, unit_distance: float):
        """``(eta, kappa)`` sampled at ``size`` points over ``[lo, hi]`` (float32)."""
        v = np.linspace(lo, hi, int(size))
        return (self.eta_at(v).astype(np.float32),
                self.kappa(v, unit_distance).astype(np.float32))

    def key(self) -> bytes:
        """Bytes identifying the functions (cache keys)."""
        return b"".join(a.tobytes() for a in (self.eta_scalars, self.eta, self.medium_scalars,
                                               self.medium_color))

    # --- (de)serialisation ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        """``{"refractive_index": {...}, "medium_color": {...}}`` with own control points."""
        return {
            "refractive_index": {"scalars": self.eta_scalars.tolist(), "values": self.eta.tolist()},
            "medium_color": {"scalars": self.medium_scalars.tolist(),
                             "colors": self.medium_color.tolist()},
        }

    @classmethod
    def from_dict(cls, d: dict, scalars=None) -> RefractiveOptics:
        """Parse the ``refractive_index`` / ``medium_color`` fields of a scene's transfer function.

        Parameters
        ----------
        d : dict
            May hold ``refractive_index`` (a list with one value per ``scalars`` control
            point, or ``{"scalars": [...], "values": [...]}``) and ``medium_color`` (a list
            of RGB triples per control point, or ``{"scalars": [...], "colors": [...]}``).
            Missing ones take the defaults (η ≡ 1, m ≡ white).
        scalars : sequence of float, optional
            The transfer function's own control points (for the list forms).
        """
        if not isinstance(d, dict):
            raise ValueError("transfer_function must be an object")
        kw = {}
        if "refractive_index" in d:
            kw["eta_scalars"], kw["eta"] = _parse_field(d["refractive_index"], "refractive_index",
                                                        "values", scalars)
        if "medium_color" in d:
            kw["medium_scalars"], kw["medium_color"] = _parse_field(
                d["medium_color"], "medium_color", "colors", scalars)
        try:
            return cls(**kw)
        except (TypeError, ValueError) as err:
            msg = str(err)
            raise ValueError(msg if msg.startswith(KEYS) else f"transfer_function: {msg}") from err


def split_transfer_function(d: dict):
    """Split a scene's ``transfer_function`` object into its colour/opacity part and the optics.

    Returns
    -------
    tf_dict : dict
        ``d`` without the ``refractive_index`` and ``medium_color`` fields (for
        :meth:`TransferFunction.from_dict`).
    optics : RefractiveOptics or None
        ``None`` when neither field is present.
    """
    if not isinstance(d, dict):
        return d, None
    present = [k for k in KEYS if k in d]
    if not present:
        return d, None
    rest = {k: v for k, v in d.items() if k not in KEYS}
    return rest, RefractiveOptics.from_dict({k: d[k] for k in present}, d.get("scalars"))


def _parse_field(value, name: str, values_key: str, scalars):
    if isinstance(value, dict):
        unknown = set(value) - {"scalars", values_key}
        if unknown:
            raise ValueError(f"{name}: unknown field(s) {sorted(unknown)}; expected 'scalars' and "
                             f"'{values_key}'")
        for key in ("scalars", values_key):
            if key not in value:
                raise ValueError(f"{name}.{key} is missing")
        return value["scalars"], value[values_key]
    if isinstance(value, list):
        if scalars is None:
            raise ValueError(f"{name}: a list needs the transfer function's 'scalars' (one value "
                             f"per control point); or give {{'scalars': [...], '{values_key}': "
                             "[...]}")
        return scalars, value
    raise ValueError(f"{name}: expected a list (one entry per control point) or an object with "
                     f"'scalars' and '{values_key}', got {value!r}")


def _points(name: str, scalars, values, width: int):
    try:
        s = np.asarray(scalars, dtype=np.float64).reshape(-1)
        v = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name}: control points and values must be numbers ({err})") from None
    v = v.reshape(-1) if width == 1 else v
    if s.size == 0:
        raise ValueError(f"{name}: at least one control point is needed")
    expected = (s.size,) if width == 1 else (s.size, width)
    if v.shape != expected:
        what = "values" if width == 1 else "RGB triples"
        raise ValueError(f"{name}: expected {s.size} {what} for {s.size} control points, "
                         f"got shape {v.shape}")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(v))):
        raise ValueError(f"{name}: control points and values must be finite")
    if np.any(np.diff(s) <= 0):
        raise ValueError(f"{name}: control points must be strictly increasing, got {s.tolist()}")
    return s, v
