"""Scattering functions: Henyey–Greenstein, or a BRDF where the data mark a surface.

Jönsson et al. (section 3.1) "enable s(x, ω', ω_o) to shift between phase function and
BRDF depending on the material given by the TF", with a microfacet BRDF for specular
materials (blood vessels in their Fig. 6). Here, as an option (off by default; the path
tracer and every other method know the Henyey–Greenstein phase only):

* a sample is **surface-like** when its data value lies in ``surface_range`` and the
  data gradient is at least ``surface_gradient × (data range) / (mean spacing)``; both
  depend on the data alone, not on the transfer function, so Historygrams need no bins
  for them (changing the options recomputes everything);
* there the scattering function is a diffuse plus a normalised Phong lobe times the
  incident cosine, on the lit side of the surface (normal ``n`` = the data gradient,
  two-sided; the DVR habit of shading with ``n·l``):

      s(ω_in → ω_out) = (n·l) [k_d / (2π) + k_s (m + 1) / (2π) max(0, r·ω_out)^m],
      n·ω_out > 0,

  with ``l = -ω_in`` (towards where the light came from), ``r = 2 (n·l) n - l`` its
  mirror direction and ``m`` the shininess. Each lobe integrates to at most 1 over the
  outgoing hemisphere, so ``∫ s dω_out <= (n·l)(k_d + k_s) <= 1`` for ``k_d + k_s <= 1``
  (Lambert: exactly ``(n·l) k_d``); the rest is absorbed. (The paper names the
  Ashikhmin–Shirley microfacet BRDF; this simpler lobe keeps the energy bound exact.);
* photons scattering at a surface-like interaction leave uniformly over the lit
  hemisphere with weight ``2π s`` (unbiased; the Blinn–Phong lobe is not importance
  sampled, so shiny materials are noisier).

Elsewhere ``s`` is the Henyey–Greenstein phase ``p(ω_in · ω_out)``, evaluated and sampled
exactly as in :mod:`vtkillum.core.warp_common`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.warp_common import Medium, hg_phase, orthonormal_basis, sample_hg, scalar_gradient

init_warp()

#: Defaults of the surface options (``surface_range`` [0, 0]: off).
SURFACE_DEFAULTS = {"surface_range": [0.0, 0.0], "surface_gradient": 0.02,
                    "surface_diffuse": 0.6, "surface_specular": 0.4, "surface_shininess": 40.0}


@wp.struct
class SurfaceParams:
    """``enabled`` (0/1); data values ``[lo, hi]`` that may be surface-like; ``grad_min``
    (data units per world unit); BRDF ``kd``, ``ks``, ``shininess``."""

    enabled: int
    lo: float
    hi: float
    grad_min: float
    kd: float
    ks: float
    shininess: float


def make_surface(options: dict, volume) -> SurfaceParams:
    """:class:`SurfaceParams` from the ``surface_*`` options (validated) for ``volume``."""
    opts = {**SURFACE_DEFAULTS, **{k: v for k, v in options.items() if k in SURFACE_DEFAULTS}}
    rng = np.asarray(opts["surface_range"], dtype=np.float64).reshape(-1)
    if rng.shape != (2,) or not np.all(np.isfinite(rng)):
        raise ValueError(f"photon.surface_range must be two data values [lo, hi], got "
                         f"{opts['surface_range']!r}")
    kd, ks, m, gmin = (float(opts[k]) for k in ("surface_diffuse", "surface_specular",
                                               "surface_shininess", "surface_gradient"))
    if not (kd >= 0 and ks >= 0 and kd + ks <= 1.0 + 1e-9):
        raise ValueError(f"photon.surface_diffuse and surface_specular must be >= 0 with a sum "
                         f"<= 1 (energy conservation), got {kd}, {ks}")
    if not (np.isfinite(m) and m > 0) or not (np.isfinite(gmin) and gmin >= 0):
        raise ValueError("photon.surface_shininess must be > 0 and surface_gradient >= 0")
    lo_v, hi_v = volume.value_range
    sp = SurfaceParams()
    sp.enabled = int(rng[1] > rng[0])
    sp.lo, sp.hi = float(rng[0]), float(rng[1])
    sp.grad_min = float(gmin * (hi_v - lo_v) / volume.mean_spacing())
    sp.kd, sp.ks, sp.shininess = kd, ks, m
    return sp


def no_surface() -> SurfaceParams:
    """:class:`SurfaceParams` that turn the BRDF off (Henyey–Greenstein everywhere)."""
    sp = SurfaceParams()
    sp.enabled = 0
    sp.lo = sp.hi = sp.grad_min = sp.kd = sp.ks = 0.0
    sp.shininess = 1.0
    return sp


def surface_key(options: dict) -> tuple:
    """The surface options as a hashable key (for caches)."""
    opts = {**SURFACE_DEFAULTS, **{k: v for k, v in options.items() if k in SURFACE_DEFAULTS}}
    return tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in sorted(opts.items()))


@wp.func
def surface_normal(m: Medium, sp: SurfaceParams, p: wp.vec3, s: float):
    """``(1, unit normal)`` where the sample at ``p`` with value ``s`` is surface-like, else
    ``(0, 0)``."""
    if sp.enabled == 0 or s < sp.lo or s > sp.hi:
        return 0, wp.vec3(0.0)
    grad = scalar_gradient(m.scalars, m.inv_spacing, p)
    glen = wp.length(grad)
    if glen < sp.grad_min or glen <= 0.0:
        return 0, wp.vec3(0.0)
    return 1, grad / glen


@wp.func
def brdf_lobe(w_in: wp.vec3, w_out: wp.vec3, n: wp.vec3, sp: SurfaceParams):
    """``s(w_in → w_out)`` of a surface-like sample (see the module docstring)."""
    l = -w_in
    nn = n
    if wp.dot(nn, l) < 0.0:
        nn = -nn
    cl = wp.dot(nn, l)
    cv = wp.dot(nn, w_out)
    if cl <= 0.0 or cv <= 0.0:
        return 0.0
    r = 2.0 * cl * nn - l
    spec = (sp.shininess + 1.0) / (2.0 * wp.pi) * wp.pow(wp.max(wp.dot(r, w_out), 0.0),
                                                         sp.shininess)
    return cl * (sp.kd / (2.0 * wp.pi) + sp.ks * spec)


@wp.func
def scattering(w_in: wp.vec3, w_out: wp.vec3, g: float, surface: int, n: wp.vec3,
               sp: SurfaceParams):
    """Scattering function from travel direction ``w_in`` into ``w_out``: HG, or the BRDF
    lobe where ``surface != 0``."""
    if surface != 0:
        return brdf_lobe(w_in, w_out, n, sp)
    return hg_phase(wp.dot(w_in, w_out), g)


@wp.func
def sample_scattering(w_in: wp.vec3, g: float, surface: int, n: wp.vec3, sp: SurfaceParams,
                      u1: float, u2: float):
    """A new travel direction and its weight ``s / pdf``: HG importance sampling (weight 1),
    or uniform over the lit hemisphere of a surface-like sample (weight ``2π s``)."""
    if surface == 0:
        return sample_hg(w_in, g, u1, u2), 1.0
    nn = n
    if wp.dot(nn, w_in) > 0.0:
        nn = -nn  # the lit side faces where the photon came from
    cos_t = u1
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * wp.pi * u2
    t, b = orthonormal_basis(nn)
    w_out = wp.normalize(sin_t * wp.cos(phi) * t + sin_t * wp.sin(phi) * b + cos_t * nn)
    return w_out, 2.0 * wp.pi * brdf_lobe(w_in, w_out, n, sp)
