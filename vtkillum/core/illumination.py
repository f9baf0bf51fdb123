"""Illumination volumes: the RGB fluence grid that illumination methods hand to the ray caster.

Convention (project-wide)
-------------------------
An :class:`IlluminationVolume` holds the RGB *fluence*

    phi_c(x) = integral over the sphere of L_c(x, w) dw

at grid points covering a volume's local frame ``[0, extent]`` (trilinearly
interpolated, point-centred like the data). For one unattenuated directional
light of irradiance ``E`` the fluence is ``phi = E``; with shadowing it is
``phi = sum_l T_l(x) E_l`` over the lights, ``T_l`` the transmittance towards
light ``l``.

The ray caster (:func:`vtkillum.core.raycast.render_illuminated`) turns it into a
source term, following Zhang & Ma 2013, eq. 24 (``L_final = L (I_a + I_d + I_s)``)
written in the project's physical units::

    J_c(x) = sigma_s,c(x) * phi_c(x) / (4 pi) * S(x)

    S(x) = ka + kd * mean_l |n . l_l| + ks * mean_l max(n . h_l, 0) ** shininess

with ``sigma_s,c = albedo * color_c(s) * sigma_t`` (``DESIGN.md``), ``l_l`` the
unit direction towards light ``l``, ``h_l = normalize(l_l + v)`` the half vector
with ``v`` the direction towards the camera, and ``n`` the normalised scalar
gradient (central differences, one voxel apart) flipped to face the camera
(two-sided lighting, as VTK's default ``TwoSidedLighting``), so the sign
convention of the gradient does not matter. ``ka, kd, ks, shininess`` are the
scene's ``shading`` ``ambient, diffuse, specular, shininess`` (defaults 1, 0, 0,
32). With the defaults ``S = 1`` and the source term is exactly isotropic single
scattering (``1 / (4 pi)`` is the isotropic phase function) when
``phi = sum_l T_l E_l``.

Where the gradient vanishes (homogeneous regions, where no surface and hence no
normal exists) the sample is treated as facing every light without a highlight:
``S = ka + kd`` (diffuse factor 1, specular factor 0). This keeps uniform media
from turning dark when diffuse shading is switched on, and avoids a random
specular highlight from a normal of pure noise. "Vanishes" means that the data
change across one voxel is below ``GRADIENT_EPS`` times the data range.

Simplification vs. the paper: Zhang & Ma multiply their light-volume value by
Phong intensities whose light colours are already part of ``L``; here the light
colour lives only in ``phi`` and the Phong factor ``S`` is grey.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Relative data change across one voxel below which a sample has no usable normal.
GRADIENT_EPS = 1.0e-5


@dataclass
class IlluminationVolume:
    """RGB fluence on a regular grid covering ``[0, extent]`` of a volume's local frame.

    Parameters
    ----------
    fluence : ndarray (nx, ny, nz, 3)
        Non-negative RGB fluence ``phi`` (irradiance units: for one unshadowed
        directional light of irradiance ``E``, ``phi = E``), indexed ``[i, j, k, c]``
        along the local x, y, z axes. Any resolution with at least 2 points per axis;
        converted to float32.
    extent : (3,) float
        Size of the box it covers in the local frame (world units); equal to the
        rendered volume's ``extent``.
    """

    fluence: np.ndarray
    extent: np.ndarray

    def __post_init__(self) -> None:
        f = np.asarray(self.fluence)
        if f.dtype.kind not in "biuf":
            raise ValueError(f"illumination fluence must be real numbers, got dtype {f.dtype}")
        if f.ndim != 4 or f.shape[-1] != 3:
            raise ValueError(
                f"illumination fluence must have shape (nx, ny, nz, 3) (RGB per grid point), got "
                f"{f.shape}; for a grey fluence g of shape (nx, ny, nz) pass "
                "np.repeat(g[..., None], 3, axis=-1)"
            )
        if min(f.shape[:3]) < 2:
            raise ValueError(
                f"illumination fluence {f.shape}: at least 2 grid points are needed along each "
                "axis to interpolate it"
            )
        f = f.astype(np.float32, copy=False)
        if not np.all(np.isfinite(f)):
            raise ValueError(
                "illumination fluence contains NaN or Inf values; fix the solver output"
            )
        if np.any(f < 0):
            raise ValueError(
                f"illumination fluence must be non-negative (minimum {float(f.min()):g}); clamp "
                "it with np.maximum(fluence, 0) if these are round-off"
            )
        self.fluence = np.ascontiguousarray(f)
        e = np.asarray(self.extent, dtype=np.float64).reshape(-1)
        if e.shape != (3,) or not np.all(np.isfinite(e)) or np.any(e <= 0):
            raise ValueError(
                f"illumination extent must be three positive numbers, got {self.extent!r}"
            )
        self.extent = e

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid size ``(nx, ny, nz)``."""
        return tuple(int(n) for n in self.fluence.shape[:3])

    @classmethod
    def for_volume(cls, volume, fluence) -> "IlluminationVolume":
        """An illumination volume covering the same box as ``volume`` (any resolution).

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
        fluence : ndarray (nx, ny, nz, 3)
            See the class docstring.
        """
        return cls(fluence, volume.extent)

    def check_matches(self, volume) -> None:
        """Raise ``ValueError`` unless this covers the same local box as ``volume``."""
        if not np.allclose(self.extent, volume.extent, rtol=1e-5, atol=1e-9):
            raise ValueError(
                f"illumination volume covers extent {self.extent.tolist()} but the volume spans "
                f"{volume.extent.tolist()}; build it with IlluminationVolume.for_volume(volume, "
                "fluence)"
            )


def shading_terms(shading: dict) -> tuple[float, float, float, float]:
    """Validated ``(ka, kd, ks, shininess)`` from a scene's ``shading`` section."""
    try:
        ka, kd, ks, n = (float(shading[k]) for k in ("ambient", "diffuse", "specular", "shininess"))
    except KeyError as err:
        raise ValueError(f"shading: missing field {err}") from None
    for name, value in (("ambient", ka), ("diffuse", kd), ("specular", ks)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"shading.{name} must be a non-negative number, got {value}")
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"shading.shininess must be positive, got {n}")
    return ka, kd, ks, n


def gradient_threshold(volume) -> float:
    """:data:`GRADIENT_EPS` as a gradient magnitude for ``volume`` (data units per world unit).

    The data range times ``GRADIENT_EPS`` over one (smallest) voxel: below it a sample has
    no usable normal.
    """
    lo, hi = volume.value_range
    return GRADIENT_EPS * (hi - lo) / float(volume.spacing.min())
