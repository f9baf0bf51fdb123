"""The photon radius from the photon map: enough photons in every kernel that shows.

Eq. (8) averages the photons inside a sphere of radius ``r``; with few of them the
estimate is speckle: each photon shows as a disc of radius ``r``, in its colour. A
fixed ``r`` of 2 voxels held about 11 photons at the median on the MNI brain (200 000
photons, 40 000 of them scattered) and one or two in the dimly lit cerebellum, which
came out as orange and dark speckle at 256^2.

``radius = 0`` (automatic, the default) chooses ``r`` after the trace from where the
photons are: ``r`` such that a kernel around a photon holds ``kernel_photons`` photons
(the gathered ones, order >= 2 with exact direct light) at the :data:`PERCENTILE`-th
percentile of the photons' local density, i.e. three quarters of the photons sit where
a kernel holds more. The density is counted in cubic cells of side ``r`` (iterated to a
fixed point), so the choice follows the data's size, its optical depth and the lights:
a thin medium or one the light barely reaches scatters few photons and gets a large
kernel. More photons give a smaller radius (less kernel blur) at the same cost per
gather. Bounds: :data:`TARGET_RADIUS_VOXELS` (2, the old fixed radius) to
:data:`MAX_BOX` of the box's smallest side. Smaller kernels held enough photons on the
accuracy suite's small, dense scenes but were noisier there (photon weights vary too:
forward-scattering ball, 1 voxel: rel. RMSE 0.26 against 0.20 with 2 voxels), so the
automatic radius only ever grows the old one.
"""

from __future__ import annotations

import numpy as np

#: Percentile of the photon-weighted local density the radius is chosen for.
PERCENTILE = 25.0
#: Largest radius, as a fraction of the box's smallest side.
MAX_BOX = 0.125
#: Iterations of the cell size (the density counted in cells of the radius being chosen).
ITERATIONS = 4
#: Photons counted at most (a random subset of larger maps, with a fixed seed).
SUBSET = 1 << 20
#: The automatic photon count: photons of the pilot trace, the radius it aims at (voxels),
#: and its bounds.
PILOT_PHOTONS = 50_000
TARGET_RADIUS_VOXELS = 2.0
MIN_PHOTONS = 200_000
MAX_PHOTONS = 1_000_000


def auto_photons(positions: np.ndarray, pilot: int, extent, voxel: float,
                 kernel_photons: int) -> int:
    """Photons to trace so that :func:`auto_radius` comes out at
    :data:`TARGET_RADIUS_VOXELS` (the earlier fixed default), from a pilot map.

    The density of gathered photons grows with their number, so the radius shrinks as
    ``N^(-1/3)``: ``N = pilot (r_pilot / r_target)^3``, between :data:`MIN_PHOTONS` and
    :data:`MAX_PHOTONS` (a rounded count).

    Parameters
    ----------
    positions : ndarray (n, 3)
        Gathered photons of the pilot map (local frame).
    pilot : int
        Photon paths the pilot traced.
    extent, voxel, kernel_photons
        As in :func:`auto_radius`.
    """
    target = TARGET_RADIUS_VOXELS * float(voxel)
    if len(positions) == 0:
        return MIN_PHOTONS  # nothing scatters (twice): the count does not matter
    r = auto_radius(positions, extent, voxel, kernel_photons, lo=0.25 * float(voxel))
    want = pilot * (r / target) ** 3
    return int(np.clip(round(want, -4), MIN_PHOTONS, MAX_PHOTONS))


def auto_radius(positions: np.ndarray, extent, voxel: float, kernel_photons: int,
                lo: float | None = None) -> float:
    """Photon radius (world units) holding ``kernel_photons`` photons at the
    :data:`PERCENTILE`-th percentile of the photons' density (module docstring).

    Parameters
    ----------
    positions : ndarray (n, 3)
        The gathered photons' positions in the volume's local frame.
    extent : sequence of 3 floats
        The box ``[0, extent]`` (world units).
    voxel : float
        The mean voxel spacing (world units): the smallest radius.
    kernel_photons : int
        Photons a kernel should hold.
    lo : float, optional
        Smallest radius (world units); default :data:`TARGET_RADIUS_VOXELS` voxels.

    Returns
    -------
    float
        In ``[lo, max(lo, MAX_BOX * min(extent))]``; the largest when there are no
        photons.
    """
    extent = np.asarray(extent, np.float64)
    lo = TARGET_RADIUS_VOXELS * float(voxel) if lo is None else float(lo)
    hi = max(lo, MAX_BOX * float(np.min(extent)))
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return hi
    weight = 1.0
    if len(p) > SUBSET:
        keep = np.random.default_rng(0).choice(len(p), SUBSET, replace=False)
        weight = len(p) / SUBSET  # each counted photon stands for this many
        p = p[keep]
    r = float(np.clip(TARGET_RADIUS_VOXELS * voxel, lo, hi))
    for _ in range(ITERATIONS):
        cells = np.maximum(np.ceil(extent / r).astype(np.int64), 1)
        ijk = np.clip(np.floor(p / r).astype(np.int64), 0, cells - 1)
        key = ijk[:, 0] + cells[0] * (ijk[:, 1] + cells[1] * ijk[:, 2])
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        density = weight * counts[inverse.ravel()] / r**3  # photons per unit volume
        rho = float(np.percentile(density, PERCENTILE))
        new = float(np.clip((3.0 * kernel_photons / (4.0 * np.pi * rho)) ** (1.0 / 3.0),
                            lo, hi))
        if abs(new - r) <= 0.02 * r:
            return new
        r = new
    return r
