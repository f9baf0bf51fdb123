"""Preintegration table ``L̃o(θ, σ̃t, g)`` of ambient scattering (Ament et al. 2013, section 4.1).

What the table holds
--------------------
A homogeneous sphere of radius 1, extinction ``σ̃t`` and albedo ``Λ`` is lit by a
distant light front travelling along ``+z`` (Fig. 4 of the paper). Entry
``L̃o(θ, σ̃t, g)`` is the radiance leaving the sphere at the surface point of polar
angle ``θ`` (measured from ``+z``, the light's travel direction) in the radial
direction, for a front of unit level. So ``θ = 0`` is light carried straight on
(transmission), ``θ = π`` light sent back towards the light.

The boundary condition on the sphere is eq. 11: radiance entering the sphere at
surface point ``xs`` travelling along ``ω`` is

    L̃s(xs, ω) = L̃f · exp(-d σ̃t) · p(ω · z; g)

with ``p`` the Henyey–Greenstein phase function normalised to 1 over the sphere
(``(1/4π) P_HG`` of eq. 10) and ``d = max(0, 2 zs)`` the distance the front
travels through the sphere before it reaches ``xs``. For ``σ̃t = 0`` nothing
scatters inside and ``L̃o(θ, 0, g) = p(cos θ; g)`` exactly, so the gather of
Algorithm 1 reduces to single scattering in optically thin regions.

Radius and extinction are not independent (section 4.1.1): a sphere of radius
``r`` is looked up at ``r σ̃t``. The paper's table is 256 θ in [0, π] × 256 σ̃t in
[0, 20] × 19 g in [-0.9, 0.9] at ``Λ = 0.9``, each axis uniformly sampled.

Estimator
---------
Unidirectional path tracing as in section 4.1.2: every path starts at the surface
point of angle ``θ`` (in the xz-plane) heading for the centre, samples free paths
``-ln ξ / σ̃t`` (importance sampling of the transmittance), ends by Russian
roulette at an interaction if ``ξ > Λ`` (absorption), otherwise scatters into a
direction sampled from the phase function, and when it reaches the surface picks
up the boundary condition above with weight 1. The per-entry standard error comes
from the running sum of squares. Paths are cut after ``MAX_EVENTS`` interactions
(probability ``Λ ** MAX_EVENTS``, 10⁻¹⁸⁷ at Λ = 0.9).

Front transmittance (for tube marching)
---------------------------------------
Eq. 16 carries the light front from sphere to sphere with ``L̃o(0, r σ̃t, g)``.
Taken literally that factor is not a transmittance: for ``σ̃t = 0`` it is
``p(1; g)`` (1/(4π) = 0.08 for g = 0, so light would fade by 12× per step
through empty space, and 15 for g = 0.9, so it would grow), and normalising it
by its ``σ̃t = 0`` value makes backward scattering amplify light (×118 per step
at g = -0.9, σ̃t = 1, because eq. 11 then sends strong back-scattered light in
from the far side) and forward scattering transmit *less* than isotropic
scattering (its sharp peak is blurred), the opposite of the translucency the
paper shows. So the same run also tabulates the **front transmittance**
``T̃(σ̃t, g)``: the fraction of the light entering the sphere at its south pole
along the axis (the centre line of the front, the path behind eq. 16's θ = 0
look-up) that leaves it through the far hemisphere (``z > 0``), traced forwards
with the same free paths, roulette and phase function. It is 1 for ``σ̃t = 0``,
decreases with ``σ̃t``, grows with ``g``, and for ``Λ = 0`` equals ``e^(-2σ̃t)``,
so for absorbing media tube marching with step ``2r`` is exactly Beer–Lambert. :mod:`~vtkillum.core.ambient.tube_march`
uses it in place of ``L̃o(0, ·)`` in eq. 16.

Scattered part (for the centred gather)
---------------------------------------
Paths that cross the sphere without an interaction contribute the analytic
``U(θ, σ̃t, g) = p(cos θ; g) exp(-(2 + max(0, -2 cos θ)) σ̃t)`` (:func:`unscattered`):
light of the boundary condition, scattered at the far side, carried back across the whole
sphere. :attr:`PreintegrationTable.scattered` is ``M = L̃o - U`` (clipped at 0 where
Monte-Carlo noise makes it negative; ``M = 0`` at ``σ̃t = 0``): the light that scattered
inside the sphere. The centred gather of :mod:`~vtkillum.core.ambient.gather` uses ``M``
and computes the unscattered light at the sphere's centre itself. Nothing is stored:
``M`` is derived from ``L̃o`` when a table is loaded.

Storage
-------
``.npz`` files hold the axes, the albedo, the sample count, the seed and
``FORMAT_VERSION``; the radiance is stored as float16 ``ln L̃o`` (relative
quantisation error ≤ 0.4 % down to ``L̃o ≈ e⁻¹⁶``, below the Monte-Carlo error of
a few thousand paths) and the relative standard error as float16.
:func:`load_table` finds, in this order: a table for exactly that albedo (the shipped
``Λ = 0.9`` one, ``vtkillum/data/ambient_table_a0.9.npz``, or one in the cache folder);
the **multi-albedo table** (:class:`AlbedoTables`, ``vtkillum/data/ambient_tables_albedo.npz``
or the cache folder), interpolated to the albedo asked for (no waiting); and only when
neither is there, a table generated on demand (minutes on a CPU, with a progress bar)
and cached.

Multi-albedo table
------------------
One file holds tables of the same axes at the albedos :data:`ALBEDO_NODES`
(``ln L̃o`` and the relative error as float16, ``T̃`` as float32, per albedo). Between two
albedos ``L̃o`` and ``T̃`` are interpolated geometrically (linearly in ``ln``, linearly in
``Λ``; linearly where an entry is 0); below the first albedo towards the exact table of
``Λ = 0`` (``L̃o = U``, ``T̃ = e^(-2σ̃t)``: nothing scatters). On test tables generated at
0.5 ... 1.0 this interpolation over gaps of 0.2 (at 0.6), 0.1 (at 0.8, 0.85) and 0.03
(0.975) left errors at the Monte-Carlo noise of the tables (L1 1-3 %), better than a
linear blend of ``L̃o`` (2-5 %) or interpolation in ``ln(1 - Λ)``.

Command line (prints the generation time and the Monte-Carlo error)::

    python -m vtkillum.core.ambient.table --device cuda --albedo 0.9 \\
        --theta 256 --sigma 256 --g 19 --samples 16384 --out table.npz
    # the multi-albedo file (8 albedos, 128 x 128 x 19, a few MiB):
    python -m vtkillum.core.ambient.table --device cuda --albedos default \\
        --out vtkillum/data/ambient_tables_albedo.npz

Generation runs in launches of at most :data:`PATHS_PER_LAUNCH` paths (about a second
on a CPU), so Ctrl-C stops it promptly (nothing is written then).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp, resolve_device
from vtkillum.core.warp_common import free_path, hg_phase, sample_hg, stream_seed, uniform

init_warp()

#: Version of the ``.npz`` layout; files of another version are refused with advice.
FORMAT_VERSION = 1
#: Upper end of the extinction axis of the paper's table (unit sphere).
SIGMA_MAX = 20.0
#: Largest |g| of the paper's table.
G_MAX = 0.9
#: The paper's table size (θ, σ̃t, g).
PAPER_SHAPE = (256, 256, 19)
#: Resolution and paths per entry of tables generated on demand (another albedo).
ON_DEMAND = {"n_theta": 64, "n_sigma": 64, "n_g": 19, "samples": 512}
#: Interactions after which a path is cut (see the module docstring).
MAX_EVENTS = 4096
#: Paths traced per kernel launch at most (one launch is one progress step; on the CPU
#: about a second, so that Ctrl-C, seen between launches, stops a generation promptly).
PATHS_PER_LAUNCH = {"cpu": 1 << 19, "cuda": 1 << 27}
#: The front transmittance of each (σ̃t, g) gets ``samples * ceil(n_theta / this)`` paths.
FRONT_THREAD_DIVISOR = 8
#: Salt of the per-launch seeds (see :func:`~vtkillum.core.warp_common.stream_seed`).
LAUNCH_SALT = 0x2545F491
#: Entries with L̃o below this are left out of the relative-error summary.
ERROR_FLOOR = 1.0e-4

DATA_DIR = Path(__file__).resolve().parents[2] / "data"
CACHE_ENV = "VTKILLUM_CACHE_DIR"

#: Albedos of the shipped multi-albedo file (:data:`ALBEDOS_FILENAME`): dense towards 1,
#: where multiple scattering grows fastest. Below the first, the table is interpolated
#: towards the exact albedo-0 table (:func:`albedo_zero_table`).
ALBEDO_NODES = (0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 1.0)
#: Resolution and paths per entry of each albedo of that file (a few MiB in all).
ALBEDOS_SHAPE = {"n_theta": 128, "n_sigma": 128, "n_g": 19, "samples": 131072}
#: File name of the multi-albedo table (in the package's data folder or the cache).
ALBEDOS_FILENAME = "ambient_tables_albedo.npz"
#: Version of the multi-albedo ``.npz`` layout.
ALBEDOS_FORMAT_VERSION = 1


@dataclass
class PreintegrationTable:
    """The table ``L̃o(θ, σ̃t, g)`` and how it was made.

    Attributes
    ----------
    radiance : ndarray (n_theta, n_sigma, n_g) float32
        ``L̃o`` per unit front level (1/sr), axes as below.
    rel_stderr : ndarray (n_theta, n_sigma, n_g) float32
        Monte-Carlo standard error of each entry relative to it (0 where ``L̃o = 0``).
    theta, sigma, g : ndarray float64
        Axis values: polar angle in radians from the light's travel direction,
        extinction of the unit sphere (``r σ̃t`` at lookup), HG anisotropy. Uniform.
    albedo : float
        Single-scattering albedo ``Λ`` inside the sphere.
    samples : int
        Paths per entry (the front transmittance uses ``samples * ceil(n_theta / 8)``
        per (σ̃t, g)).
    seed : int
        Random seed.
    transmittance : ndarray (n_sigma, n_g) float32
        Front transmittance ``T̃(σ̃t, g)`` (see the module docstring).
    transmittance_stderr : ndarray (n_sigma, n_g) float32
        Its Monte-Carlo standard error.
    info : dict
        Generation metadata (device, seconds, warp version, ...).
    """

    radiance: np.ndarray
    rel_stderr: np.ndarray
    theta: np.ndarray
    sigma: np.ndarray
    g: np.ndarray
    albedo: float
    samples: int
    transmittance: np.ndarray
    transmittance_stderr: np.ndarray
    seed: int = 0
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.radiance = np.asarray(self.radiance, dtype=np.float32)
        self.rel_stderr = np.asarray(self.rel_stderr, dtype=np.float32)
        self.theta = np.asarray(self.theta, dtype=np.float64)
        self.sigma = np.asarray(self.sigma, dtype=np.float64)
        self.g = np.asarray(self.g, dtype=np.float64)
        shape = (self.theta.size, self.sigma.size, self.g.size)
        if self.radiance.shape != shape or self.rel_stderr.shape != shape:
            raise ValueError(
                f"table arrays have shape {self.radiance.shape} / {self.rel_stderr.shape}, "
                f"the axes give {shape}"
            )
        self.transmittance = np.asarray(self.transmittance, dtype=np.float32)
        self.transmittance_stderr = np.asarray(self.transmittance_stderr, dtype=np.float32)
        if (self.transmittance.shape != shape[1:]
                or self.transmittance_stderr.shape != shape[1:]):
            raise ValueError(f"transmittance arrays must have shape {shape[1:]} (sigma, g), "
                             f"got {self.transmittance.shape}")
        for name, axis in (("theta", self.theta), ("sigma", self.sigma), ("g", self.g)):
            if axis.size >= 2 and not np.allclose(np.diff(axis), axis[1] - axis[0],
                                                  rtol=1e-6, atol=1e-9):
                raise ValueError(f"table axis {name} must be uniformly spaced")
        self.albedo = float(self.albedo)
        self.samples = int(self.samples)
        self.seed = int(self.seed)

    # --- derived quantities --------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.radiance.shape)

    @property
    def sigma_max(self) -> float:
        return float(self.sigma[-1])

    @property
    def stderr(self) -> np.ndarray:
        """Absolute Monte-Carlo standard error of each entry."""
        return self.rel_stderr * self.radiance

    def g_bracket(self, g: float) -> tuple[int, float]:
        """Tabulated slices around ``g``: ``(k, w)`` with ``g`` at fraction ``w`` from ``g[k]``
        towards ``g[k + 1]`` (``g`` clamped to the table's range; ``(0, 0.0)`` for one slice)."""
        g = float(np.clip(g, self.g[0], self.g[-1]))
        if self.g.size == 1:
            return 0, 0.0
        x = (g - self.g[0]) / (self.g[1] - self.g[0])
        k = int(min(max(math.floor(x), 0), self.g.size - 2))
        return k, float(x - k)

    def g_slice(self, g: float) -> np.ndarray:
        """The table at anisotropy ``g``: ``(n_theta, n_sigma)`` float32.

        Between two tabulated ``g`` the slices are interpolated geometrically
        (linearly in ``ln L̃o``), which follows the steep growth of the forward peak
        ``p(1; g) ∝ (1 + g) / (1 - g)²`` far better than a linear blend (at g = 0.85
        the error of the peak is 12 % instead of 43 %); where an entry is 0 the blend
        is linear. ``g`` outside the table's range is clamped to it.
        :class:`~vtkillum.core.ambient.device_table.DeviceTable` computes the same on a device.
        """
        return _blend_slices(self.radiance, *self.g_bracket(g))

    @property
    def scattered(self) -> np.ndarray:
        """The scattered part ``M = L̃o - U`` of every entry, ``(n_theta, n_sigma, n_g)``
        float32, clipped at 0 (Monte-Carlo noise), with ``M(θ, 0, g) = 0`` exactly.

        ``U`` is the unscattered term (:func:`unscattered`): light of the eq. 11 boundary
        that crosses the sphere without an interaction. The centred gather
        (:mod:`~vtkillum.core.ambient.gather`) uses ``M`` and computes the unscattered
        light itself, exactly, at the sphere's centre.
        """
        if getattr(self, "_scattered", None) is None:
            th, sg, gg = np.meshgrid(self.theta, self.sigma, self.g, indexing="ij")
            m = np.maximum(self.radiance.astype(np.float64) - unscattered(th, sg, gg), 0.0)
            m[:, 0, :] = 0.0
            self._scattered = m.astype(np.float32)
        return self._scattered

    def scattered_slice(self, g: float) -> np.ndarray:
        """:attr:`scattered` at anisotropy ``g``: ``(n_theta, n_sigma)`` float32, blended between
        the tabulated ``g`` as :meth:`g_slice` blends ``L̃o`` (geometric where both are > 0)."""
        return _blend_slices(self.scattered, *self.g_bracket(g))

    def transmittance_slice(self, g: float) -> np.ndarray:
        """Front transmittance ``T̃(σ̃t)`` at anisotropy ``g``: ``(n_sigma,)`` float32.

        Linear in ``g`` between tabulated values (``T̃`` is smooth in ``g``); ``g`` is
        clamped to the table's range.
        """
        k, w = self.g_bracket(g)
        if self.g.size == 1:
            return self.transmittance[:, 0].copy()
        t = (1 - w) * self.transmittance[:, k] + w * self.transmittance[:, k + 1]
        return t.astype(np.float32)

    def lookup(self, theta, sigma, g) -> np.ndarray:
        """``L̃o`` at arbitrary points: bilinear in (θ, σ̃t) of :meth:`g_slice`, clamped axes."""
        sl = self.g_slice(g)
        theta = np.asarray(theta, dtype=np.float64)
        sigma = np.asarray(sigma, dtype=np.float64)
        u = np.clip(theta / self.theta[-1] * (self.theta.size - 1), 0, self.theta.size - 1)
        v = np.clip(sigma / self.sigma[-1] * (self.sigma.size - 1), 0, self.sigma.size - 1)
        i = np.minimum(u.astype(int), self.theta.size - 2)
        j = np.minimum(v.astype(int), self.sigma.size - 2)
        fu, fv = u - i, v - j
        return ((1 - fu) * (1 - fv) * sl[i, j] + fu * (1 - fv) * sl[i + 1, j]
                + (1 - fu) * fv * sl[i, j + 1] + fu * fv * sl[i + 1, j + 1])

    def outgoing_energy(self) -> np.ndarray:
        """``2π ∫ L̃o sin θ dθ`` per (σ̃t, g), shape ``(n_sigma, n_g)`` (trapezoidal rule).

        This is the total radiance leaving the sphere integrated over the radial
        directions; it is 1 for ``σ̃t = 0`` (the phase function's normalisation).
        """
        w = np.sin(self.theta)
        return 2 * np.pi * np.trapezoid(self.radiance * w[:, None, None], self.theta, axis=0)

    def error_summary(self) -> dict:
        """Monte-Carlo error: absolute maximum and relative median / 95th percentile.

        The relative figures cover entries with ``L̃o >= ERROR_FLOOR`` (smaller
        values do not matter at rendering, where ``L̃o`` multiplies light levels).
        """
        se = self.stderr
        big = self.radiance >= ERROR_FLOOR
        rel = self.rel_stderr[big & (self.radiance > 0)]
        return {
            "max_abs_stderr": float(se.max()),
            "mean_abs_stderr": float(se.mean()),
            "median_rel_stderr": float(np.median(rel)) if rel.size else 0.0,
            "p95_rel_stderr": float(np.percentile(rel, 95)) if rel.size else 0.0,
            "max_rel_stderr": float(rel.max()) if rel.size else 0.0,
        }

    # --- files ---------------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write a compressed ``.npz`` (see the module docstring for the layout)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with np.errstate(divide="ignore"):
            log_l = np.log(self.radiance.astype(np.float64))
        np.savez_compressed(
            path,
            format_version=np.int32(FORMAT_VERSION),
            log_radiance=log_l.astype(np.float16),
            rel_stderr=self.rel_stderr.astype(np.float16),
            theta=self.theta, sigma=self.sigma, g=self.g,
            albedo=np.float64(self.albedo), samples=np.int64(self.samples),
            seed=np.int64(self.seed), info=np.array(json.dumps(self.info)),
            transmittance=self.transmittance.astype(np.float32),
            transmittance_stderr=self.transmittance_stderr.astype(np.float32),
        )
        return path

    @classmethod
    def load(cls, path) -> "PreintegrationTable":
        """Read a table file, checking its format version and contents."""
        path = Path(path)
        try:
            data = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise FileNotFoundError(f"ambient-scattering table {path} does not exist") from None
        except Exception as err:
            raise ValueError(f"{path} is not a readable .npz table ({err}); regenerate it with "
                             "python -m vtkillum.core.ambient.table --out FILE") from err
        with data:
            needed = {"format_version", "log_radiance", "rel_stderr", "theta", "sigma", "g",
                      "albedo", "samples", "seed", "info", "transmittance",
                      "transmittance_stderr"}
            missing = needed - set(data.files)
            if missing:
                raise ValueError(f"{path}: not an ambient-scattering table (missing "
                                 f"{sorted(missing)}); regenerate it with "
                                 "python -m vtkillum.core.ambient.table --out FILE")
            version = int(data["format_version"])
            if version != FORMAT_VERSION:
                raise ValueError(
                    f"{path}: table format version {version}, this vtkillum reads version "
                    f"{FORMAT_VERSION}; regenerate it with python -m vtkillum.core.ambient.table "
                    f"--albedo {float(data['albedo']):g} --out {path}"
                )
            radiance = np.exp(data["log_radiance"].astype(np.float64))
            return cls(radiance=radiance, rel_stderr=data["rel_stderr"].astype(np.float32),
                       theta=data["theta"], sigma=data["sigma"], g=data["g"],
                       albedo=float(data["albedo"]), samples=int(data["samples"]),
                       transmittance=data["transmittance"],
                       transmittance_stderr=data["transmittance_stderr"],
                       seed=int(data["seed"]), info=json.loads(str(data["info"])))


# --- several albedos ------------------------------------------------------------------------------
def albedo_zero_table(like: PreintegrationTable) -> PreintegrationTable:
    """The exact table of albedo 0 on ``like``'s axes: ``L̃o = U`` (:func:`unscattered`),
    ``T̃ = e^(-2σ̃t)``, no Monte-Carlo error."""
    th, sg, gg = np.meshgrid(like.theta, like.sigma, like.g, indexing="ij")
    radiance = unscattered(th, sg, gg)
    trans = np.broadcast_to(np.exp(-2.0 * like.sigma)[:, None], (like.sigma.size, like.g.size))
    return PreintegrationTable(radiance, np.zeros_like(radiance), like.theta, like.sigma,
                               like.g, 0.0, like.samples, trans, np.zeros_like(trans),
                               like.seed, {"exact": "albedo 0: unscattered light only"})


def _geometric(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
    """``a^(1-w) b^w`` where both are > 0, ``(1-w) a + w b`` elsewhere (float64)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = (1 - w) * a + w * b
    positive = (a > 0) & (b > 0)
    with np.errstate(divide="ignore"):
        geo = np.exp((1 - w) * np.log(np.where(positive, a, 1.0))
                     + w * np.log(np.where(positive, b, 1.0)))
    out[positive] = geo[positive]
    return out


def interpolate_albedo(lo: PreintegrationTable, hi: PreintegrationTable,
                       albedo: float) -> PreintegrationTable:
    """The table at ``albedo`` between two tables of the same axes (module docstring:
    geometric in ``L̃o`` and ``T̃``, linear in ``Λ``; errors blended linearly)."""
    if lo.shape != hi.shape or not (np.array_equal(lo.theta, hi.theta)
                                    and np.array_equal(lo.sigma, hi.sigma)
                                    and np.array_equal(lo.g, hi.g)):
        raise ValueError("tables of different axes cannot be interpolated")
    albedo = float(albedo)
    if hi.albedo == lo.albedo:
        w = 0.0
    else:
        w = float(np.clip((albedo - lo.albedo) / (hi.albedo - lo.albedo), 0.0, 1.0))
    if w == 0.0 and albedo == lo.albedo:
        return lo
    if w == 1.0 and albedo == hi.albedo:
        return hi
    radiance = _geometric(lo.radiance, hi.radiance, w)
    trans = _geometric(lo.transmittance, hi.transmittance, w)
    info = {"interpolated": f"albedo {albedo:g} between the tables of {lo.albedo:g} and "
                            f"{hi.albedo:g}", "sources": [lo.info, hi.info]}
    samples = min(t.samples for t in (lo, hi) if t.albedo > 0) if max(lo.albedo, hi.albedo) > 0 \
        else lo.samples
    return PreintegrationTable(
        radiance, (1 - w) * lo.rel_stderr + w * hi.rel_stderr, lo.theta, lo.sigma, lo.g,
        albedo, samples, trans,
        (1 - w) * lo.transmittance_stderr + w * hi.transmittance_stderr, lo.seed, info)


class AlbedoTables:
    """Preintegration tables of the same axes at several albedos, interpolated between.

    Parameters
    ----------
    tables : sequence of PreintegrationTable
        One per albedo (distinct albedos, the same θ, σ̃t and g axes).

    Examples
    --------
    >>> stack = AlbedoTables.load(DATA_DIR / ALBEDOS_FILENAME)   # doctest: +SKIP
    >>> stack.at(0.93).albedo                                    # doctest: +SKIP
    0.93
    """

    def __init__(self, tables) -> None:
        tables = sorted(tables, key=lambda t: t.albedo)
        if not tables:
            raise ValueError("AlbedoTables needs at least one table")
        first = tables[0]
        for t in tables[1:]:
            if t.shape != first.shape or not (np.allclose(t.theta, first.theta)
                                              and np.allclose(t.sigma, first.sigma)
                                              and np.allclose(t.g, first.g)):
                raise ValueError(f"the table of albedo {t.albedo:g} has other axes than the "
                                 f"one of albedo {first.albedo:g}")
        albedos = [t.albedo for t in tables]
        if len(set(albedos)) != len(albedos):
            raise ValueError(f"albedos must be distinct, got {albedos}")
        self.tables = tables

    @property
    def albedos(self) -> np.ndarray:
        return np.array([t.albedo for t in self.tables])

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.tables[0].shape

    def covers(self, albedo: float) -> bool:
        """Whether ``albedo`` lies in [0, the largest albedo] (below the first, the exact
        albedo-0 table is the other end of the interpolation)."""
        return 0.0 <= float(albedo) <= float(self.albedos[-1]) + 1e-9

    def at(self, albedo: float) -> PreintegrationTable:
        """The table at ``albedo`` (interpolated; a tabulated albedo is returned as is)."""
        albedo = float(albedo)
        if not self.covers(albedo):
            raise ValueError(f"albedo {albedo:g} is outside the tables' range [0, "
                             f"{self.albedos[-1]:g}]")
        a = self.albedos
        exact = np.flatnonzero(np.abs(a - albedo) <= 1e-9)
        if exact.size:
            return self.tables[int(exact[0])]
        if albedo < a[0]:
            return interpolate_albedo(albedo_zero_table(self.tables[0]), self.tables[0], albedo)
        k = int(np.searchsorted(a, albedo)) - 1
        return interpolate_albedo(self.tables[k], self.tables[k + 1], albedo)

    # --- files ---------------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write one compressed ``.npz``.

        Per albedo: ``ln L̃o`` as float16 (its low and high bytes stored apart, which
        deflate compresses a third better), the relative error in per mille as uint8
        (255: 25.5 % or more), ``T̃`` and its error as float32.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        radiance = np.stack([t.radiance for t in self.tables]).astype(np.float64)
        with np.errstate(divide="ignore"):
            log_l = np.log(radiance)
        first = self.tables[0]
        tmp = path.with_name(f".{path.name}.tmp.npz")
        rel = np.stack([t.rel_stderr for t in self.tables]).astype(np.float64)
        np.savez_compressed(
            tmp,
            albedos_format_version=np.int32(ALBEDOS_FORMAT_VERSION),
            albedos=self.albedos,
            log_radiance_bytes=_split_bytes(log_l.astype(np.float16)),
            rel_stderr_permille=np.clip(np.round(1000 * rel), 0, 255).astype(np.uint8),
            theta=first.theta, sigma=first.sigma, g=first.g,
            samples=np.array([t.samples for t in self.tables], np.int64),
            seeds=np.array([t.seed for t in self.tables], np.int64),
            info=np.array(json.dumps([t.info for t in self.tables])),
            transmittance=np.stack([t.transmittance for t in self.tables]).astype(np.float32),
            transmittance_stderr=np.stack([t.transmittance_stderr for t in self.tables])
            .astype(np.float32),
        )
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path) -> "AlbedoTables":
        """Read a multi-albedo file written by :meth:`save`."""
        path = Path(path)
        try:
            data = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise FileNotFoundError(f"multi-albedo table {path} does not exist") from None
        except Exception as err:
            raise ValueError(f"{path} is not a readable .npz table ({err})") from err
        with data:
            needed = {"albedos_format_version", "albedos", "log_radiance_bytes",
                      "rel_stderr_permille", "theta",
                      "sigma", "g", "samples", "seeds", "info", "transmittance",
                      "transmittance_stderr"}
            missing = needed - set(data.files)
            if missing:
                raise ValueError(f"{path}: not a multi-albedo ambient-scattering table (missing "
                                 f"{sorted(missing)})")
            version = int(data["albedos_format_version"])
            if version != ALBEDOS_FORMAT_VERSION:
                raise ValueError(f"{path}: multi-albedo format version {version}, this vtkillum "
                                 f"reads version {ALBEDOS_FORMAT_VERSION}; regenerate it with "
                                 f"python -m vtkillum.core.ambient.table --albedos default "
                                 f"--out {path}")
            infos = json.loads(str(data["info"]))
            log_l = _join_bytes(data["log_radiance_bytes"], np.float16)
            rel = data["rel_stderr_permille"].astype(np.float32) / 1000
            tables = []
            for n, albedo in enumerate(data["albedos"]):
                tables.append(PreintegrationTable(
                    radiance=np.exp(log_l[n].astype(np.float64)),
                    rel_stderr=rel[n],
                    theta=data["theta"], sigma=data["sigma"], g=data["g"],
                    albedo=float(albedo), samples=int(data["samples"][n]),
                    transmittance=data["transmittance"][n],
                    transmittance_stderr=data["transmittance_stderr"][n],
                    seed=int(data["seeds"][n]), info=dict(infos[n], file=str(path))))
        return cls(tables)


def _split_bytes(values: np.ndarray) -> np.ndarray:
    """``(itemsize,) + shape`` uint8: byte ``k`` of every value in plane ``k``."""
    v = np.ascontiguousarray(values)
    return np.moveaxis(v.view(np.uint8).reshape(v.shape + (v.dtype.itemsize,)), -1, 0).copy()


def _join_bytes(planes: np.ndarray, dtype) -> np.ndarray:
    """Inverse of :func:`_split_bytes`."""
    return np.ascontiguousarray(np.moveaxis(planes, 0, -1)).view(dtype)[..., 0]


def generate_albedo_tables(albedos=ALBEDO_NODES, progress=True, **kwargs) -> AlbedoTables:
    """:func:`generate_table` at each albedo (same axes, seed and samples)."""
    albedos = [float(a) for a in albedos]
    if not albedos:
        raise ValueError("albedos: give at least one albedo")
    return AlbedoTables([generate_table(albedo=a, progress=progress, **kwargs) for a in albedos])


# --- generation -----------------------------------------------------------------------------------
def table_axes(n_theta: int = 256, n_sigma: int = 256, n_g: int = 19,
               sigma_max: float = SIGMA_MAX, g_max: float = G_MAX):
    """Uniform axes as in the paper: θ in [0, π], σ̃t in [0, sigma_max], g in [-g_max, g_max]."""
    for name, n in (("n_theta", n_theta), ("n_sigma", n_sigma)):
        if int(n) < 2:
            raise ValueError(f"{name} must be at least 2, got {n}")
    if int(n_g) < 1:
        raise ValueError(f"n_g must be at least 1, got {n_g}")
    if not (sigma_max > 0 and np.isfinite(sigma_max)):
        raise ValueError(f"sigma_max must be positive, got {sigma_max}")
    if not (0 <= g_max < 1):
        raise ValueError(f"g_max must lie in [0, 1), got {g_max}")
    g = np.linspace(-g_max, g_max, int(n_g)) if int(n_g) > 1 else np.zeros(1)
    return (np.linspace(0.0, np.pi, int(n_theta)), np.linspace(0.0, sigma_max, int(n_sigma)), g)


def generate_table(albedo: float = 0.9, n_theta: int = 256, n_sigma: int = 256, n_g: int = 19,
                   samples: int = 1024, seed: int = 0, device: str | None = None,
                   progress=True, sigma_max: float = SIGMA_MAX, g_max: float = G_MAX,
                   theta=None, sigma=None, g=None, max_seconds: float | None = None
                   ) -> PreintegrationTable:
    """Path-trace the preintegration table (see the module docstring).

    Parameters
    ----------
    albedo : float
        ``Λ`` in [0, 1].
    n_theta, n_sigma, n_g : int
        Axis sizes (ignored for an axis given explicitly below).
    samples : int
        Paths per entry.
    seed : int
        Random seed; a fixed seed gives the same table on one device.
    device : str, optional
        Warp device.
    progress : bool or callable
        ``True``: a progress bar on stderr (tqdm when installed); a callable is
        called as ``progress(fraction_done)``; ``False``/``None``: silent.
    sigma_max, g_max : float
        Axis ranges.
    theta, sigma, g : array_like, optional
        Explicit axis values (uniform), e.g. one row of a larger table.
    max_seconds : float, optional
        Stop after the launch that passes this wall time; the table then records
        the number of paths actually traced.

    Returns
    -------
    PreintegrationTable
    """
    if not (0.0 <= float(albedo) <= 1.0):
        raise ValueError(f"albedo must lie in [0, 1], got {albedo}")
    if isinstance(samples, bool) or int(samples) < 2:
        raise ValueError(f"samples must be an integer >= 2 (needed for an error estimate), "
                         f"got {samples!r}")
    th, sg, gg = table_axes(n_theta, n_sigma, n_g, sigma_max, g_max)
    th = th if theta is None else np.atleast_1d(np.asarray(theta, dtype=np.float64))
    sg = sg if sigma is None else np.atleast_1d(np.asarray(sigma, dtype=np.float64))
    gg = gg if g is None else np.atleast_1d(np.asarray(g, dtype=np.float64))
    if np.any(th < 0) or np.any(th > np.pi) or np.any(sg < 0) or np.any(np.abs(gg) >= 1):
        raise ValueError("theta must lie in [0, pi], sigma >= 0 and |g| < 1")
    device = resolve_device(device)
    samples = int(samples)
    n_entries = th.size * sg.size * gg.size
    n_front = sg.size * gg.size  # transmittance entries, each traced by `reps` threads
    reps = max(1, -(-th.size // FRONT_THREAD_DIVISOR))

    d_theta = wp.array(th.astype(np.float32), dtype=wp.float32, device=device)
    d_sigma = wp.array(sg.astype(np.float32), dtype=wp.float32, device=device)
    d_g = wp.array(gg.astype(np.float32), dtype=wp.float32, device=device)
    d_sum = wp.zeros(n_entries, dtype=wp.float64, device=device)
    d_sq = wp.zeros(n_entries, dtype=wp.float64, device=device)
    d_passed = wp.zeros(n_front * reps, dtype=wp.float64, device=device)

    # Launches are bounded to PATHS_PER_LAUNCH paths: a pass of `per_launch` paths per
    # entry is split into chunks of entries, so that on the CPU one launch takes about a
    # second and Ctrl-C (seen between launches) stops the generation promptly. Entry e
    # of pass k always uses rand_init(stream_seed(seed, k), e): chunking does not change
    # the table.
    budget = PATHS_PER_LAUNCH["cpu" if device == "cpu" else "cuda"]
    per_launch = int(max(1, min(samples, budget // max(n_entries, 1))))
    n_passes = (samples + per_launch - 1) // per_launch
    chunk = max(1, budget // per_launch)
    entry_chunks = [(a, min(a + chunk, n_entries)) for a in range(0, n_entries, chunk)]
    n_threads = n_front * reps
    front_chunks = [(a, min(a + chunk, n_threads)) for a in range(0, n_threads, chunk)]
    n_launches = n_passes * (len(entry_chunks) + len(front_chunks))
    report = _progress_reporter(progress, n_launches, f"ambient table (albedo {albedo:g})")
    t0 = time.perf_counter()
    done = 0
    launched = 0
    for launch in range(n_passes):
        paths = min(per_launch, samples - done)
        launch_seed = stream_seed(seed, launch, LAUNCH_SALT)
        for a, b in entry_chunks:
            wp.launch(preintegration_kernel, dim=b - a,
                      inputs=[d_theta, d_sigma, d_g, float(albedo), launch_seed, paths,
                              MAX_EVENTS, a, d_sum, d_sq], device=device)
            wp.synchronize_device(device)
            launched += 1
            report(launched)
        for a, b in front_chunks:
            wp.launch(front_transmittance_kernel, dim=b - a,
                      inputs=[d_sigma, d_g, reps, float(albedo), launch_seed ^ 0x5BD1E995, paths,
                              MAX_EVENTS, a, d_passed], device=device)
            wp.synchronize_device(device)
            launched += 1
            report(launched)
        done += paths
        if max_seconds is not None and time.perf_counter() - t0 > max_seconds and done >= 2:
            break
    report(None)
    seconds = time.perf_counter() - t0

    total = d_sum.numpy().reshape(gg.size, sg.size, th.size).transpose(2, 1, 0)
    sq = d_sq.numpy().reshape(gg.size, sg.size, th.size).transpose(2, 1, 0)
    mean = total / done
    var = np.maximum(sq / done - mean * mean, 0.0) * done / (done - 1)
    se = np.sqrt(var / done)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(mean > 0, se / mean, 0.0)
    n_front_paths = done * reps
    passed = d_passed.numpy().reshape(gg.size, sg.size, reps).sum(axis=2).T / n_front_paths
    passed_se = np.sqrt(passed * (1 - passed) / max(n_front_paths - 1, 1))
    info = {
        "device": device,
        "seconds": seconds,
        "paths": int(done) * (n_entries + n_front * reps),
        "paths_per_second": int(done) * (n_entries + n_front * reps) / max(seconds, 1e-9),
        "warp_version": wp.config.version,
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "max_events": MAX_EVENTS,
    }
    return PreintegrationTable(mean, rel, th, sg, gg, float(albedo), int(done), passed,
                               passed_se, int(seed), info)


def unscattered(theta, sigma, g):
    """The unscattered term ``U`` of ``L̃o``: eq. 11's boundary radiance carried across the
    unit sphere without an interaction.

    The path from the surface point at ``θ`` through the centre leaves at the antipode
    ``xs`` (``zs = -cos θ``) after a chord of 2, where the boundary condition is
    ``exp(-d σ̃t) p(cos θ; g)`` with ``d = max(0, 2 zs)``:
    ``U = p(cos θ; g) exp(-(2 + max(0, -2 cos θ)) σ̃t)``. Arrays broadcast.
    """
    theta = np.asarray(theta, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    c = np.cos(theta)
    denom = 1.0 + g * g - 2.0 * g * c
    phase = (1.0 - g * g) / (4.0 * np.pi * denom * np.sqrt(denom))
    return phase * np.exp(-(2.0 + np.maximum(0.0, -2.0 * c)) * sigma)


def _blend_slices(values: np.ndarray, k: int, w: float) -> np.ndarray:
    """Slices ``k`` and ``k + 1`` of ``values (n_theta, n_sigma, n_g)`` blended at fraction ``w``
    (geometric where both entries are > 0, linear elsewhere), float32."""
    if values.shape[2] == 1:
        return values[:, :, 0].astype(np.float32)
    a = values[:, :, k].astype(np.float64)
    b = values[:, :, k + 1].astype(np.float64)
    if w <= 0.0:
        return a.astype(np.float32)
    if w >= 1.0:
        return b.astype(np.float32)
    positive = (a > 0) & (b > 0)
    out = (1 - w) * a + w * b
    with np.errstate(divide="ignore"):
        geo = np.exp((1 - w) * np.log(np.where(positive, a, 1.0))
                     + w * np.log(np.where(positive, b, 1.0)))
    out[positive] = geo[positive]
    return out.astype(np.float32)


def _progress_reporter(progress, total: int, label: str):
    """A function ``report(done)`` (``None`` closes it) for ``progress`` as in generate_table."""
    if callable(progress):
        return lambda done: progress(1.0 if done is None else done / total)
    if not progress:
        return lambda done: None
    try:
        from tqdm import tqdm
    except ImportError:  # the GPU machine has numpy + warp only
        state = {"last": -1}

        def report(done):
            if done is None:
                sys.stderr.write("\n")
                return
            pct = int(100 * done / total)
            if pct != state["last"]:
                state["last"] = pct
                sys.stderr.write(f"\r{label}: {pct:3d}%")
                sys.stderr.flush()
        return report
    bar = tqdm(total=total, desc=label, unit="launch", leave=False)

    def report(done):
        if done is None:
            bar.close()
        else:
            bar.update(done - bar.n)
    return report


# --- loading --------------------------------------------------------------------------------------
def table_filename(albedo: float) -> str:
    """File name of the table for ``albedo``: ``ambient_table_a0.9.npz``."""
    return f"ambient_table_a{float(albedo):g}.npz"


def cache_dir() -> Path:
    """Where tables generated on demand are kept (``$VTKILLUM_CACHE_DIR`` or ~/.cache)."""
    return Path(os.environ.get(CACHE_ENV, Path.home() / ".cache" / "vtkillum"))


_LOADED: dict = {}


def albedo_tables_paths() -> list[Path]:
    """Where a multi-albedo file is looked for: the package's data folder, then the cache."""
    return [DATA_DIR / ALBEDOS_FILENAME, cache_dir() / ALBEDOS_FILENAME]


def load_albedo_tables() -> AlbedoTables | None:
    """The multi-albedo tables (shipped, else cached), or ``None`` when there is none."""
    for candidate in albedo_tables_paths():
        if candidate.exists():
            key = ("albedos", str(candidate.resolve()))
            if key not in _LOADED:
                _LOADED[key] = AlbedoTables.load(candidate)
            return _LOADED[key]
    return None


def load_table(albedo: float = 0.9, path=None, generate: bool = True, device: str | None = None,
               progress=True) -> PreintegrationTable:
    """The table for ``albedo``: its own file, interpolated from the multi-albedo file,
    or (only when neither exists) generated now and cached.

    Parameters
    ----------
    albedo : float
        ``Λ`` of the table wanted (matched to 1e-6).
    path : str or Path, optional
        Load exactly this file instead (its albedo is not checked against ``albedo``).
    generate : bool
        Generate a table that is neither shipped, cached nor covered by the multi-albedo
        file (``ON_DEMAND`` resolution and paths) and store it in :func:`cache_dir`;
        otherwise that raises ``FileNotFoundError``.
    device, progress
        As for :func:`generate_table`.
    """
    if path is not None:
        key = ("path", str(Path(path).resolve()))
        if key not in _LOADED:
            _LOADED[key] = PreintegrationTable.load(path)
        return _LOADED[key]
    albedo = float(albedo)
    if not (0.0 <= albedo <= 1.0):
        raise ValueError(f"albedo must lie in [0, 1], got {albedo}")
    key = ("albedo", round(albedo, 6))
    if key in _LOADED:
        return _LOADED[key]
    for folder in (DATA_DIR, cache_dir()):
        candidate = folder / table_filename(albedo)
        if candidate.exists():
            table = PreintegrationTable.load(candidate)
            if abs(table.albedo - albedo) > 1e-6:
                raise ValueError(f"{candidate} holds albedo {table.albedo}, not {albedo}; "
                                 "delete it so that it is regenerated")
            _LOADED[key] = table
            return table
    stack = load_albedo_tables()
    if stack is not None and stack.covers(albedo):
        table = _LOADED[key] = stack.at(albedo)
        return table
    command = (f"python -m vtkillum.core.ambient.table --albedo {albedo:g} "
               f"--out {cache_dir() / table_filename(albedo)}")
    if not generate:
        raise FileNotFoundError(
            f"no ambient-scattering table for albedo {albedo:g} in {DATA_DIR} or {cache_dir()} "
            f"(neither its own file nor {ALBEDOS_FILENAME}); generate one with {command}")
    sys.stderr.write(f"vtkillum: generating the ambient-scattering table for albedo {albedo:g} "
                     f"(once; cached in {cache_dir()}; no {ALBEDOS_FILENAME} is installed to "
                     "interpolate from)\n")
    try:
        table = generate_table(albedo=albedo, device=device, progress=progress, **ON_DEMAND)
    except KeyboardInterrupt:
        sys.stderr.write("vtkillum: table generation interrupted; nothing cached\n")
        raise
    try:
        # reloaded so that this session sees the same (float16-stored) values as later ones
        table = PreintegrationTable.load(table.save(cache_dir() / table_filename(albedo)))
    except OSError as err:  # read-only home: keep it in memory only
        sys.stderr.write(f"vtkillum: could not cache the table ({err})\n")
    _LOADED[key] = table
    return table


def describe_tables() -> list[str]:
    """One line per table file found (what ``vtkillum info`` prints)."""
    lines = []
    for folder, where in ((DATA_DIR, "shipped"), (cache_dir(), "cached")):
        for f in sorted(folder.glob("ambient_table_a*.npz")) if folder.exists() else []:
            lines.append(f"albedo {f.name[len('ambient_table_a'):-4]}: {f} ({where})")
        stack_file = folder / ALBEDOS_FILENAME
        if stack_file.exists():
            try:
                stack = AlbedoTables.load(stack_file)
                albedos = ", ".join(f"{a:g}" for a in stack.albedos)
                lines.append(f"albedos {albedos} ({'x'.join(map(str, stack.shape))}), any "
                             f"albedo in [0, {stack.albedos[-1]:g}] interpolated: {stack_file} "
                             f"({where})")
            except (OSError, ValueError) as err:
                lines.append(f"{stack_file}: unreadable ({err})")
    if not any("albedos" in line for line in lines):
        lines.append(f"no multi-albedo table ({ALBEDOS_FILENAME}): albedos without their own "
                     "table are generated on first use (minutes on a CPU)")
    return lines


# --- kernels --------------------------------------------------------------------------------------
@wp.func
def unit_sphere_exit(p: wp.vec3, d: wp.vec3):
    """Distance along unit ``d`` from ``p`` (inside or on the unit sphere) to the sphere."""
    # |p + t d| = 1 with |p| <= 1, |d| = 1: the larger root.
    b = wp.dot(p, d)
    c = wp.dot(p, p) - 1.0
    return -b + wp.sqrt(wp.max(b * b - c, 0.0))


@wp.func
def absorb_or_scatter(d: wp.vec3, g: float, albedo: float, state: wp.uint32):
    """One interaction: absorption or an HG-scattered direction around ``d``.

    Absorbed with probability ``1 - albedo`` (Russian roulette with survival probability
    ``Λ``). Returns ``(survived, direction, state)``.
    """
    u, state = uniform(state)
    if u >= albedo:
        return False, d, state
    u1, state = uniform(state)
    u2, state = uniform(state)
    return True, sample_hg(d, g, u1, u2), state


@wp.kernel
def preintegration_kernel(theta: wp.array(dtype=wp.float32), sigma: wp.array(dtype=wp.float32),
                          g: wp.array(dtype=wp.float32), albedo: float, seed: int, paths: int,
                          max_events: int, first: int, total: wp.array(dtype=wp.float64),
                          total_sq: wp.array(dtype=wp.float64)):
    """Trace ``paths`` paths for one table entry and add their sum and sum of squares.

    ``first + wp.tid()`` indexes the entries with θ fastest: ``tid = (ig * n_sigma + isig)
    * n_theta + it`` (a launch covers a chunk of entries starting at ``first``). Units: the
    sphere has radius 1, ``sigma`` is its extinction (1/radius).
    """
    tid = first + wp.tid()
    n_t = theta.shape[0]
    n_s = sigma.shape[0]
    it = tid % n_t
    isg = (tid // n_t) % n_s
    ig = tid // (n_t * n_s)
    th = theta[it]
    st = sigma[isg]
    gg = g[ig]
    state = wp.rand_init(seed, tid)
    start = wp.vec3(wp.sin(th), 0.0, wp.cos(th))
    acc = wp.float64(0.0)
    acc_sq = wp.float64(0.0)
    for n in range(paths):
        p = start
        d = -start
        value = float(0.0)
        for e in range(max_events):
            t_exit = unit_sphere_exit(p, d)
            t_free, state = free_path(st, state)
            if t_free >= t_exit:
                xs = p + t_exit * d
                # Light arriving at xs travels along -d; the front reached xs after max(0, 2 zs).
                wi = -d
                dist = wp.max(0.0, 2.0 * xs[2])
                value = wp.exp(-dist * st) * hg_phase(wi[2], gg)
                break
            p = p + t_free * d
            # Backward tracing with a symmetric phase function: the new path direction has
            # density p(d . d') around the old one.
            alive, d, state = absorb_or_scatter(d, gg, albedo, state)
            if not alive:
                break
        v = wp.float64(value)
        acc += v
        acc_sq += v * v
    total[tid] = total[tid] + acc
    total_sq[tid] = total_sq[tid] + acc_sq


@wp.kernel
def front_transmittance_kernel(sigma: wp.array(dtype=wp.float32), g: wp.array(dtype=wp.float32),
                               threads_per_entry: int, albedo: float, seed: int, paths: int,
                               max_events: int, first: int, passed: wp.array(dtype=wp.float64)):
    """Trace ``paths`` photons along the unit sphere's axis; count those leaving through z > 0.

    ``first + wp.tid()`` indexes ``(ig * n_sigma + isig) * threads_per_entry + rep`` (a
    launch covers a chunk of threads starting at ``first``): each (σ̃t, g)
    entry is shared by ``threads_per_entry`` threads whose counts the host adds up.
    Photons enter at the south pole ``(0, 0, -1)`` travelling along ``+z`` (the front's
    centre line, the path of eq. 16's θ = 0 look-up); one counts 1 when it leaves the
    sphere through the far hemisphere.
    """
    tid = first + wp.tid()
    n_s = sigma.shape[0]
    entry = tid // threads_per_entry
    isg = entry % n_s
    ig = entry // n_s
    st = sigma[isg]
    gg = g[ig]
    state = wp.rand_init(seed, tid)
    count = wp.float64(0.0)
    for n in range(paths):
        p = wp.vec3(0.0, 0.0, -1.0)
        d = wp.vec3(0.0, 0.0, 1.0)
        for e in range(max_events):
            t_exit = unit_sphere_exit(p, d)
            t_free, state = free_path(st, state)
            if t_free >= t_exit:
                if p[2] + t_exit * d[2] > 0.0:
                    count += wp.float64(1.0)
                break
            p = p + t_free * d
            alive, d, state = absorb_or_scatter(d, gg, albedo, state)
            if not alive:
                break
    passed[tid] = passed[tid] + count


# --- command line ---------------------------------------------------------------------------------
def main(argv=None) -> int:
    """``python -m vtkillum.core.ambient.table``: generate a table, print time and MC error."""
    ap = argparse.ArgumentParser(
        prog="python -m vtkillum.core.ambient.table",
        description="Path-trace the ambient-scattering preintegration table L~o(theta, sigma, g) "
                    "(Ament et al. 2013, section 4.1) and write it as .npz.")
    ap.add_argument("--device", default=None, help="warp device: cpu, cuda, cuda:N (default auto)")
    ap.add_argument("--albedo", type=float, default=0.9, help="albedo inside the sphere")
    ap.add_argument("--albedos", default=None,
                    help="write a multi-albedo file instead: comma-separated albedos, or "
                         f"'default' ({', '.join(f'{a:g}' for a in ALBEDO_NODES)} at "
                         f"{ALBEDOS_SHAPE['n_theta']} theta x {ALBEDOS_SHAPE['n_sigma']} sigma "
                         f"x {ALBEDOS_SHAPE['n_g']} g, {ALBEDOS_SHAPE['samples']} paths per "
                         "entry, unless --theta/--sigma/--g/--samples are given)")
    ap.add_argument("--theta", type=int, default=None,
                    help=f"theta samples in [0, pi] (default {PAPER_SHAPE[0]})")
    ap.add_argument("--sigma", type=int, default=None,
                    help=f"extinction samples in [0, sigma-max] (default {PAPER_SHAPE[1]})")
    ap.add_argument("--g", type=int, default=None,
                    help=f"g samples in [-g-max, g-max] (default {PAPER_SHAPE[2]})")
    ap.add_argument("--sigma-max", type=float, default=SIGMA_MAX)
    ap.add_argument("--g-max", type=float, default=G_MAX)
    ap.add_argument("--samples", type=int, default=None, help="paths per entry (default 1024)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-seconds", type=float, default=None,
                    help="stop early after this wall time (records the paths traced)")
    ap.add_argument("--out", default=None, help="output .npz (default: the cache directory)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    device = resolve_device(args.device)
    name = wp.get_device(device).name if device != "cpu" else "cpu"
    if args.albedos is not None:
        return _main_albedos(args, device, name)
    try:
        table = generate_table(albedo=args.albedo, n_theta=args.theta or PAPER_SHAPE[0],
                               n_sigma=args.sigma or PAPER_SHAPE[1],
                               n_g=args.g or PAPER_SHAPE[2], samples=args.samples or 1024,
                               seed=args.seed, device=device, progress=not args.quiet,
                               sigma_max=args.sigma_max, g_max=args.g_max,
                               max_seconds=args.max_seconds)
    except KeyboardInterrupt:
        print("interrupted: no table written (--max-seconds stops early with a usable table)",
              file=sys.stderr)
        return 130
    table.info["device_name"] = name
    out = Path(args.out) if args.out else cache_dir() / table_filename(args.albedo)
    table.save(out)
    err = table.error_summary()
    energy = table.outgoing_energy()
    print(f"table {table.shape[0]} theta x {table.shape[1]} sigma x {table.shape[2]} g, "
          f"albedo {table.albedo:g}, {table.samples} paths/entry, seed {table.seed}")
    print(f"device {device} ({name}): {table.info['seconds']:.2f} s, "
          f"{table.info['paths_per_second']:.3g} paths/s")
    print(f"Monte-Carlo error: max abs {err['max_abs_stderr']:.3g}, mean abs "
          f"{err['mean_abs_stderr']:.3g}; relative (entries >= {ERROR_FLOOR:g}) median "
          f"{100 * err['median_rel_stderr']:.2f} %, 95th pct {100 * err['p95_rel_stderr']:.2f} %, "
          f"max {100 * err['max_rel_stderr']:.1f} %")
    print(f"outgoing energy: {energy.max():.4f} max, at sigma_max {energy[-1].min():.4f}"
          f"-{energy[-1].max():.4f}; front transmittance stderr max "
          f"{table.transmittance_stderr.max():.2g}")
    print(f"wrote {out} ({out.stat().st_size / 2**20:.2f} MiB)")
    return 0


def _main_albedos(args, device, name) -> int:
    """``--albedos``: generate and write a multi-albedo file."""
    if args.albedos.strip().lower() == "default":
        albedos = list(ALBEDO_NODES)
    else:
        try:
            albedos = [float(a) for a in args.albedos.split(",") if a.strip()]
        except ValueError:
            print(f"--albedos: expected comma-separated numbers or 'default', got "
                  f"{args.albedos!r}", file=sys.stderr)
            return 2
    shape = dict(ALBEDOS_SHAPE)
    for key, value in (("n_theta", args.theta), ("n_sigma", args.sigma), ("n_g", args.g),
                       ("samples", args.samples)):
        if value is not None:
            shape[key] = value
    start = time.perf_counter()
    try:
        stack = generate_albedo_tables(albedos, progress=not args.quiet, seed=args.seed,
                                       device=device, sigma_max=args.sigma_max,
                                       g_max=args.g_max, max_seconds=args.max_seconds,
                                       **shape)
    except KeyboardInterrupt:
        print("interrupted: no table written", file=sys.stderr)
        return 130
    for table in stack.tables:
        table.info["device_name"] = name
    out = Path(args.out) if args.out else cache_dir() / ALBEDOS_FILENAME
    stack.save(out)
    print(f"tables {' x '.join(map(str, stack.shape))} (theta x sigma x g) at albedos "
          f"{', '.join(f'{a:g}' for a in stack.albedos)}")
    for table in stack.tables:
        err = table.error_summary()
        print(f"  albedo {table.albedo:g}: {table.samples} paths/entry, "
              f"{table.info['seconds']:.1f} s, relative error median "
              f"{100 * err['median_rel_stderr']:.2f} %, 95th pct "
              f"{100 * err['p95_rel_stderr']:.2f} %")
    print(f"device {device} ({name}): {time.perf_counter() - start:.1f} s in all")
    print(f"wrote {out} ({out.stat().st_size / 2**20:.2f} MiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
