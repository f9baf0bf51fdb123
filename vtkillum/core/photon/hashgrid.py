"""The spatial hash of the photon map (Jönsson et al. 2012, section 5).

"We use a hash function which maps the location into uniformly distributed bins with
the bin size equal to the photon radius. [...] The list can then be efficiently sorted
on the GPU, based on bin index using radix sort. The start and end of each bin are
then found [...]. Since the photon radius is used for the bin width, all photons
within the given radius can be found by querying the 27 surrounding bins."

:func:`build_photon_grid` does this on the device, with bins of **half** the radius:

1. one key per stored interaction that the density estimate uses (scattering order
   ``>= min_order``): the linear index ``i + nx (j + ny k)`` of its cell
   ``floor(x * (1 / cell))`` on a dense grid of cells covering the volume's box (a perfect
   hash; interactions that do not take part get the key ``2**31 - 1`` and sort to the
   end), and a histogram of the keys;
2. ``warp.utils.radix_sort_pairs`` of (key, interaction index) over the bits that hold a
   cell index — stable, so photons in a cell stay in buffer order and the sums below are
   reproducible;
3. the gathered photons in sorted order (position, incoming direction, flux), for
   coherent reads during the gather;
4. the table ``cell_start`` (``n_cells + 1`` entries): the exclusive prefix sum of the
   histogram, so cell ``c`` holds photons ``[cell_start[c], cell_start[c + 1])`` and a
   run of cells along x (one row) is one contiguous range.

A query (:func:`gather_phase_flux`, :func:`gather_flux`) walks the rows of cells that
meet the sphere: for each slab ``k`` and row ``j`` within reach it clips the row to the
chord of the sphere at the row's nearest point and reads that one range. With cells of
half the radius the photons read are about 2.5 times those within the radius (27 times
the sphere's volume over 4.19 with the paper's 27 bins of the radius): in the dense
layers where photons pile up (a wall next to a point light holds thousands per bin)
the gather reads a third of what 27 bins would, and in sparse media about 20 ranges
replace 27 bins. The photons summed, and the test ``|x_p - x| <= r``, are the paper's;
only the order of the sum differs. With an isotropic phase (``g = 0``, no surface-like
sample) every photon in reach adds the same phase times its flux, and its direction is
not read.

After a trace whose count of interactions is still on the device, the hash is built
without waiting for it (``stored``, ``defer``): the slots the trace may have filled are
sorted, those past the count as unused, and the number of photons in the grid is read
with the trace's counts.

The cell size is half the radius, enlarged only where the dense table would exceed
:data:`MAX_CELLS` cells (the rows clip to the sphere whatever the cell size). The table
is rebuilt after every photon update (the paper re-sorts too, moving invalid photons to
their new bins).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.material import SurfaceParams, scattering
from vtkillum.core.photon.storage import Interactions
from vtkillum.core.warp_common import hg_phase

init_warp()

#: Largest number of cells of the dense bin table (4 bytes each).
MAX_CELLS = 1 << 25
#: Cells per photon radius along each axis (the paper's bins: 1).
CELLS_PER_RADIUS = 2
#: Key of interactions left out of the estimate (sorts last).
UNUSED_KEY = wp.constant(2**31 - 1)


@wp.struct
class PhotonGrid:
    """Photons sorted by cell, with the cell table: what the density estimate reads.

    ``pos``, ``dir``, ``power``: position (local frame), incoming travel direction and
    flux ``Φ`` (RGB) of the ``count`` photons, sorted by cell; cell ``c = i + dims.x (j +
    dims.y k)`` holds ``[cell_start[c], cell_start[c + 1])``; ``cell``: cell size;
    ``radius`` and ``inv_volume = 1 / (4/3 π radius³)``: the kernel of eq. (8); ``reach``:
    the radius plus a rounding margin, for choosing the cells (the photons summed are
    those within ``radius``).
    """

    pos: wp.array(dtype=wp.vec3)
    dir: wp.array(dtype=wp.vec3)
    power: wp.array(dtype=wp.vec3)
    cell_start: wp.array(dtype=wp.int32)
    dims: wp.vec3i
    cell: float
    inv_cell: float
    radius: float
    reach: float
    inv_volume: float
    count: int


def grid_dims(extent, radius: float) -> tuple[float, tuple[int, int, int]]:
    """Cell size and cells per axis for a box ``extent`` and photon ``radius``."""
    extent = np.asarray(extent, np.float64)
    cell = float(radius) / CELLS_PER_RADIUS
    while True:
        dims = tuple(int(np.floor(e / cell)) + 1 for e in extent)
        if int(np.prod(dims, dtype=np.int64)) <= MAX_CELLS:
            return cell, dims
        cell *= 1.25


def build_photon_grid(interactions: Interactions, total: int, extent, radius: float,
                      min_order: int, device: str, stored: wp.array | None = None,
                      defer: bool = False):
    """Sort the photon map's interactions into cells (see the module docstring).

    Parameters
    ----------
    interactions : Interactions
        The photon map's buffer (:class:`~vtkillum.core.photon.tracing.PhotonMap`).
    total : int
        Interactions stored; with ``stored``, the slots that may hold them.
    extent : (3,) float
        The volume's box in the local frame.
    radius : float
        Photon radius of the density estimate (world units, > 0).
    min_order : int
        Smallest scattering order used (1: all photons; 2: scattered light only).
    device : str
    stored : wp.array(int32), optional
        The number of interactions stored, on the device, as its last entry (a trace
        whose count has not been read yet): the first ``total`` slots are sorted, those
        past the count as unused.
    defer : bool
        Queue the work without waiting for the device: returns ``(grid, count)`` with
        ``count`` the device array whose entry ``0`` is the number of photons in the
        grid; ``grid.count`` must be set from it before the grid is read.
    """
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"the photon radius must be positive, got {radius!r}")
    cell, dims = grid_dims(extent, radius)
    n_cells = int(np.prod(dims))
    grid = PhotonGrid()
    grid.dims = wp.vec3i(*dims)
    grid.cell = float(cell)
    grid.inv_cell = float(1.0 / cell)
    grid.radius = float(radius)
    # Cells are chosen for a sphere a little larger than the radius, so that rounding in
    # floor(x / cell) never drops a photon within it (a few ulp of the box's coordinates).
    grid.reach = float(radius * (1.0 + 1e-4) + 1e-6 * float(np.max(extent)))
    grid.inv_volume = float(1.0 / (4.0 / 3.0 * np.pi * radius ** 3))
    n = int(total)
    counts = wp.zeros(n_cells + 1, dtype=wp.int32, device=device)
    grid.cell_start = wp.empty(n_cells + 1, dtype=wp.int32, device=device)
    keys = wp.empty(max(2 * n, 2), dtype=wp.int32, device=device)
    values = wp.empty(max(2 * n, 2), dtype=wp.int32, device=device)
    if stored is None:
        stored, at = counts, -1
    else:
        at = int(stored.shape[0]) - 1
    if n > 0:
        wp.launch(cell_keys_kernel, dim=n,
                  inputs=[interactions, grid.dims, grid.inv_cell, int(min_order), stored, at,
                          keys, values, counts], device=device)
        # Keys are cell indices (< n_cells) or UNUSED_KEY: sorting only the low bits that
        # hold n_cells keeps the order (UNUSED_KEY's low bits are all ones, more than any
        # cell index below 2**bits - 1) with fewer passes.
        try:
            wp.utils.radix_sort_pairs(keys, values, n, 0, int(n_cells).bit_length())
        except TypeError:  # a warp without bit ranges
            wp.utils.radix_sort_pairs(keys, values, n)
    wp.utils.array_scan(counts, grid.cell_start, inclusive=False)
    count_view = grid.cell_start[n_cells:n_cells + 1]
    if defer:
        size = n  # the photons in the grid are at most the slots sorted
    else:
        size = int(count_view.numpy()[0])
    grid.count = size
    grid.pos = wp.empty(max(size, 1), dtype=wp.vec3, device=device)
    grid.dir = wp.empty(max(size, 1), dtype=wp.vec3, device=device)
    grid.power = wp.zeros(max(size, 1), dtype=wp.vec3, device=device)
    if size > 0:
        wp.launch(sorted_photons_kernel, dim=size,
                  inputs=[interactions, values, grid.cell_start, n_cells, grid.pos, grid.dir,
                          grid.power], device=device)
    return (grid, count_view) if defer else grid


@wp.func
def cell_index(x: float, inv_cell: float, n: int):
    """Cell of coordinate ``x`` along an axis of ``n`` cells (clamped to the table).

    ``x * inv_cell``, not ``x / cell``: a division costs several instructions and the
    gather finds cells many times per sample; any monotonic map gathers the same photons
    as long as the keys and the queries use the same one."""
    return wp.clamp(int(wp.floor(x * inv_cell)), 0, n - 1)


@wp.func
def slab_gap(x: float, c: int, cell: float):
    """Distance from ``x`` to the slab ``[c cell, (c + 1) cell]`` (0 inside)."""
    return wp.max(wp.max(float(c) * cell - x, x - float(c + 1) * cell), 0.0)


@wp.func
def slab_range(grid: PhotonGrid, x: wp.vec3):
    """The z slabs of cells within the reach of ``x``."""
    return (cell_index(x[2] - grid.reach, grid.inv_cell, grid.dims[2]),
            cell_index(x[2] + grid.reach, grid.inv_cell, grid.dims[2]))


@wp.func
def row_range(grid: PhotonGrid, x: wp.vec3, k: int):
    """The rows ``j0 .. j1`` of slab ``k`` within the reach of ``x`` (none: ``j1 < j0``) and
    the squared reach left in that slab."""
    gz = slab_gap(x[2], k, grid.cell)
    rz2 = grid.reach * grid.reach - gz * gz
    if rz2 < 0.0:
        return 0, -1, rz2
    ry = wp.sqrt(rz2)
    return (cell_index(x[1] - ry, grid.inv_cell, grid.dims[1]),
            cell_index(x[1] + ry, grid.inv_cell, grid.dims[1]), rz2)


@wp.func
def row_photons(grid: PhotonGrid, x: wp.vec3, j: int, k: int, rz2: float):
    """The photon range ``[a, b)`` of row ``(j, k)`` clipped to the chord of the reach
    (``cell_start`` is a prefix sum: a row's clipped cells are one range)."""
    gy = slab_gap(x[1], j, grid.cell)
    ry2 = rz2 - gy * gy
    if ry2 < 0.0:
        return 0, 0
    rx = wp.sqrt(ry2)
    base = grid.dims[0] * (j + grid.dims[1] * k)
    return (grid.cell_start[base + cell_index(x[0] - rx, grid.inv_cell, grid.dims[0])],
            grid.cell_start[base + cell_index(x[0] + rx, grid.inv_cell, grid.dims[0]) + 1])


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
    r2 = grid.radius * grid.radius
    # Isotropic HG (g = 0, no surface): the phase is the same for every photon (the HG
    # formula gives these bits for any angle), so the photons' directions are not read.
    iso = surface == 0 and g == 0.0
    phase0 = hg_phase(0.0, g)
    k0, k1 = slab_range(grid, x)
    for k in range(k0, k1 + 1):
        j0, j1, rz2 = row_range(grid, x, k)
        for j in range(j0, j1 + 1):
            a, b = row_photons(grid, x, j, k, rz2)
            for r in range(a, b):
                v = grid.pos[r] - x
                if wp.dot(v, v) <= r2:
                    if iso:
                        acc += phase0 * grid.power[r]
                    else:
                        acc += scattering(grid.dir[r], wo, g, surface, n, sp) * grid.power[r]
    return acc * grid.inv_volume


@wp.func
def gather_flux(grid: PhotonGrid, x: wp.vec3):
    """``Σ Φ_p`` over photons within the radius of ``x`` over the kernel volume: the
    interaction density ``σt φ``."""
    acc = wp.vec3(0.0)
    if grid.count == 0:
        return acc
    r2 = grid.radius * grid.radius
    k0, k1 = slab_range(grid, x)
    for k in range(k0, k1 + 1):
        j0, j1, rz2 = row_range(grid, x, k)
        for j in range(j0, j1 + 1):
            a, b = row_photons(grid, x, j, k, rz2)
            for r in range(a, b):
                v = grid.pos[r] - x
                if wp.dot(v, v) <= r2:
                    acc += grid.power[r]
    return acc * grid.inv_volume


@wp.kernel
def cell_keys_kernel(it: Interactions, dims: wp.vec3i, inv_cell: float, min_order: int,
                     stored: wp.array(dtype=wp.int32), at: int,
                     keys: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.int32),
                     counts: wp.array(dtype=wp.int32)):
    """``wp.tid()`` indexes interaction slots: key = linear cell index (``UNUSED_KEY`` for
    orders below ``min_order``, and for slots from ``stored[at]`` on when ``at >= 0``),
    value = the slot's index; counts the photons per cell."""
    i = wp.tid()
    values[i] = i
    if at >= 0:
        if i >= stored[at]:
            keys[i] = UNUSED_KEY
            return
    if it.order[i] < min_order:
        keys[i] = UNUSED_KEY
        return
    p = it.pos[i]
    ci = cell_index(p[0], inv_cell, dims[0])
    cj = cell_index(p[1], inv_cell, dims[1])
    ck = cell_index(p[2], inv_cell, dims[2])
    key = ci + dims[0] * (cj + dims[1] * ck)
    keys[i] = key
    wp.atomic_add(counts, key, 1)


@wp.kernel
def sorted_photons_kernel(it: Interactions, values: wp.array(dtype=wp.int32),
                          cell_start: wp.array(dtype=wp.int32), n_cells: int,
                          pos: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                          power: wp.array(dtype=wp.vec3)):
    """``wp.tid()`` indexes the sorted used photons (``cell_start[n_cells]`` of them; the
    launch may be larger): copy them in cell order."""
    r = wp.tid()
    if r >= cell_start[n_cells]:
        return
    i = values[r]
    pos[r] = it.pos[i]
    dirs[r] = it.dir[i]
    power[r] = it.flux[i]
