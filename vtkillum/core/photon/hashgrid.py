"""The spatial hash of the photon map (Jönsson et al. 2012, section 5).

"We use a hash function which maps the location into uniformly distributed bins with
the bin size equal to the photon radius. [...] The list can then be efficiently sorted
on the GPU, based on bin index using radix sort. The start and end of each bin are
then found [...]. Since the photon radius is used for the bin width, all photons
within the given radius can be found by querying the 27 surrounding bins."

:func:`build_photon_grid` does exactly that on the device:

1. one key per stored interaction that the density estimate uses (scattering order
   ``>= min_order``): the linear index of its cell ``floor(x / cell)`` on a dense grid
   of cells covering the volume's box (a perfect hash; interactions that do not take
   part get the key ``2**31 - 1`` and sort to the end);
2. ``warp.utils.radix_sort_pairs`` of (key, interaction index) — stable, so photons in a
   cell stay in buffer order and the sums below are reproducible;
3. the gathered photons in sorted order (position, incoming direction, flux), for
   coherent reads during the gather;
4. cell start/end tables from the sorted keys.

The cell size is the photon radius, enlarged only where the dense table would exceed
:data:`MAX_CELLS` cells (a larger cell still holds every photon within the radius in
the 27 cells around a query). The table is rebuilt after every photon update (the
paper re-sorts too, moving invalid photons to their new bins).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.storage import Interactions
from vtkillum.core.photon.material import SurfaceParams, scattering

init_warp()

#: Largest number of cells of the dense bin table (8 bytes each).
MAX_CELLS = 1 << 24
#: Key of interactions left out of the estimate (sorts last).
UNUSED_KEY = wp.constant(2**31 - 1)


@wp.struct
class PhotonGrid:
    """Photons sorted by cell, with the cell tables: what the density estimate reads.

    ``pos``, ``dir``, ``power``: position (local frame), incoming travel direction and
    flux ``Φ`` (RGB) of the ``count`` photons, sorted by cell; ``cell_start[c]``, ``cell_end[c]``: the range of cell ``c``
    (``c = i + dims.x (j + dims.y k)``); ``cell``: cell size; ``radius`` and
    ``inv_volume = 1 / (4/3 π radius³)``: the kernel of eq. (8).
    """

    pos: wp.array(dtype=wp.vec3)
    dir: wp.array(dtype=wp.vec3)
    power: wp.array(dtype=wp.vec3)
    cell_start: wp.array(dtype=wp.int32)
    cell_end: wp.array(dtype=wp.int32)
    dims: wp.vec3i
    cell: float
    radius: float
    inv_volume: float
    count: int


def grid_dims(extent, radius: float) -> tuple[float, tuple[int, int, int]]:
    """Cell size and cells per axis for a box ``extent`` and photon ``radius``."""
    extent = np.asarray(extent, np.float64)
    cell = float(radius)
    while True:
        dims = tuple(int(np.floor(e / cell)) + 1 for e in extent)
        if int(np.prod(dims, dtype=np.int64)) <= MAX_CELLS:
            return cell, dims
        cell *= 1.25


def build_photon_grid(interactions: Interactions, total: int, extent, radius: float,
                      min_order: int, device: str) -> PhotonGrid:
    """Sort the photon map's interactions into cells (see the module docstring).

    Parameters
    ----------
    interactions : Interactions
        The photon map's buffer (:class:`~vtkillum.core.photon.tracing.PhotonMap`).
    total : int
        Interactions stored.
    extent : (3,) float
        The volume's box in the local frame.
    radius : float
        Photon radius of the density estimate (world units, > 0).
    min_order : int
        Smallest scattering order used (1: all photons; 2: scattered light only).
    device : str
    """
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"the photon radius must be positive, got {radius!r}")
    cell, dims = grid_dims(extent, radius)
    n_cells = int(np.prod(dims))
    grid = PhotonGrid()
    grid.dims = wp.vec3i(*dims)
    grid.cell = float(cell)
    grid.radius = float(radius)
    grid.inv_volume = float(1.0 / (4.0 / 3.0 * np.pi * radius ** 3))
    grid.cell_start = wp.zeros(n_cells, dtype=wp.int32, device=device)
    grid.cell_end = wp.zeros(n_cells, dtype=wp.int32, device=device)
    n = int(total)
    used = wp.zeros(1, dtype=wp.int32, device=device)
    keys = wp.empty(max(2 * n, 2), dtype=wp.int32, device=device)
    values = wp.empty(max(2 * n, 2), dtype=wp.int32, device=device)
    if n > 0:
        wp.launch(cell_keys_kernel, dim=n,
                  inputs=[interactions, grid.dims, float(cell), int(min_order), keys, values,
                          used], device=device)
        wp.utils.radix_sort_pairs(keys, values, n)
    count = int(used.numpy()[0])
    grid.count = count
    grid.pos = wp.empty(max(count, 1), dtype=wp.vec3, device=device)
    grid.dir = wp.empty(max(count, 1), dtype=wp.vec3, device=device)
    grid.power = wp.zeros(max(count, 1), dtype=wp.vec3, device=device)
    if count > 0:
        wp.launch(sorted_photons_kernel, dim=count,
                  inputs=[interactions, keys, values, count, grid.pos, grid.dir,
                          grid.power, grid.cell_start, grid.cell_end], device=device)
    return grid


@wp.func
def cell_coord(grid: PhotonGrid, p: wp.vec3):
    """Cell of local position ``p`` (clamped to the table)."""
    return wp.vec3i(wp.clamp(int(wp.floor(p[0] / grid.cell)), 0, grid.dims[0] - 1),
                    wp.clamp(int(wp.floor(p[1] / grid.cell)), 0, grid.dims[1] - 1),
                    wp.clamp(int(wp.floor(p[2] / grid.cell)), 0, grid.dims[2] - 1))


@wp.func
def gather_phase_flux(grid: PhotonGrid, x: wp.vec3, wo: wp.vec3, g: float, surface: int,
                      n: wp.vec3, sp: SurfaceParams):
    """``Σ s(ω_p → wo) Φ_p`` over photons within the radius of ``x``, divided by the kernel
    volume (``wo``: unit direction towards the viewer; ``ω_p``: the photon's travel
    direction; ``s`` the HG phase, or the BRDF lobe of a surface-like sample, see
    :mod:`~vtkillum.core.photon.material`): ``σt L_i`` of eq. (8)."""
    acc = wp.vec3(0.0)
    if grid.count == 0:
        return acc
    c = cell_coord(grid, x)
    r2 = grid.radius * grid.radius
    for dz in range(-1, 2):
        k = c[2] + dz
        if k < 0 or k >= grid.dims[2]:
            continue
        for dy in range(-1, 2):
            j = c[1] + dy
            if j < 0 or j >= grid.dims[1]:
                continue
            for dx in range(-1, 2):
                i = c[0] + dx
                if i < 0 or i >= grid.dims[0]:
                    continue
                key = i + grid.dims[0] * (j + grid.dims[1] * k)
                for r in range(grid.cell_start[key], grid.cell_end[key]):
                    v = grid.pos[r] - x
                    if wp.dot(v, v) <= r2:
                        acc += scattering(grid.dir[r], wo, g, surface, n, sp) * grid.power[r]
    return acc * grid.inv_volume


@wp.func
def gather_flux(grid: PhotonGrid, x: wp.vec3):
    """``Σ Φ_p`` over photons within the radius of ``x`` over the kernel volume: the
    interaction density ``σt φ``."""
    acc = wp.vec3(0.0)
    if grid.count == 0:
        return acc
    c = cell_coord(grid, x)
    r2 = grid.radius * grid.radius
    for dz in range(-1, 2):
        k = c[2] + dz
        if k < 0 or k >= grid.dims[2]:
            continue
        for dy in range(-1, 2):
            j = c[1] + dy
            if j < 0 or j >= grid.dims[1]:
                continue
            for dx in range(-1, 2):
                i = c[0] + dx
                if i < 0 or i >= grid.dims[0]:
                    continue
                key = i + grid.dims[0] * (j + grid.dims[1] * k)
                for r in range(grid.cell_start[key], grid.cell_end[key]):
                    v = grid.pos[r] - x
                    if wp.dot(v, v) <= r2:
                        acc += grid.power[r]
    return acc * grid.inv_volume


@wp.kernel
def cell_keys_kernel(it: Interactions, dims: wp.vec3i, cell: float, min_order: int,
                     keys: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.int32),
                     used: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes interactions: key = linear cell index (``UNUSED_KEY`` for orders
    below ``min_order``), value = the interaction's index; counts the used ones."""
    i = wp.tid()
    values[i] = i
    if it.order[i] < min_order:
        keys[i] = UNUSED_KEY
        return
    p = it.pos[i]
    ci = wp.clamp(int(wp.floor(p[0] / cell)), 0, dims[0] - 1)
    cj = wp.clamp(int(wp.floor(p[1] / cell)), 0, dims[1] - 1)
    ck = wp.clamp(int(wp.floor(p[2] / cell)), 0, dims[2] - 1)
    keys[i] = ci + dims[0] * (cj + dims[1] * ck)
    wp.atomic_add(used, 0, 1)


@wp.kernel
def sorted_photons_kernel(it: Interactions, keys: wp.array(dtype=wp.int32),
                          values: wp.array(dtype=wp.int32), count: int,
                          pos: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                          power: wp.array(dtype=wp.vec3), cell_start: wp.array(dtype=wp.int32),
                          cell_end: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes the sorted used photons: copy them in cell order and mark where
    each cell's run starts and ends."""
    r = wp.tid()
    i = values[r]
    pos[r] = it.pos[i]
    dirs[r] = it.dir[i]
    power[r] = it.flux[i]
    key = keys[r]
    if r == 0 or keys[r - 1] != key:
        cell_start[key] = r
    if r == count - 1 or keys[r + 1] != key:
        cell_end[key] = r + 1
