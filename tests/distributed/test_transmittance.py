"""Distributed ``transmittance`` (forwarded ray segments) against the one-rank core.

Run on every rank of ``mpirun -np N python -m pytest tests/distributed`` (N = 1, 2, 4;
3 ranks through a sub-communicator of the 4). Each rank computes the one-rank result for
the whole (small) volume itself and compares its own piece.

Tolerance: ``|dT| <= ATOL + RTOL * T`` with :data:`ATOL` = 1e-7 and :data:`RTOL` = 1e-5
(well inside 1e-6 absolute; relative below 1e-6, where the early stop at ``T < 1e-6``
decides which sample a ray ends on and an absolute 1e-6 could not see a wrong stop), and
the fluence within 1e-6 of its maximum, for every light: along each axis, diagonal, point lights inside another rank's block and outside
the box, steps that do and do not line up with the grid. The distributed march adds the
one-rank samples in the one-rank order (see :mod:`vtkillum.core.parallel.transmittance`):
measured 0 (bit-identical) on 1-4 ranks. The first distributed version (a plane sweep)
differed by up to 2e-2 here, so these tests fail on any approximation at the cuts.
"""

import numpy as np
import pytest

from vtkillum.core.light_transmittance import light_transmittance
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.parallel import Decomposition, Parallel, sub_slices
from vtkillum.core.parallel.transmittance import (
    cell_owners,
    distributed_light_transmittance,
)
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

from .conftest import all_ranks, max_abs
from .volumes import ORIGIN, SHAPES, SPACING, blobs, piece_centre, piece_volume, whole_extent

ATOL = 1e-7
RTOL = 1e-5

TF = TransferFunction(scalars=[0.0, 1.5], opacity=[0.0, 0.6], colors=[[1, 1, 1], [1, 1, 1]])
#: Opaque enough that shadow rays through the far third stop there (T < 1e-6), a few
#: samples after T falls below 1e-6 (a wrong stop shows well above ATOL).
STOP_TF = TransferFunction(scalars=[0.0, 1.0], opacity=[0.0, 0.99],
                           colors=[[1, 1, 1], [1, 1, 1]])
#: Dense: most shadow rays stop early (T < 1e-6) somewhere along their way.
DENSE_TF = TransferFunction(scalars=[0.0, 0.3], opacity=[0.0, 1.0],
                            colors=[[1, 1, 1], [1, 1, 1]])
AXIS_LIGHTS = [DirectionalLight(d, (1, 1, 1)) for d in
               [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]]
DIAGONAL_LIGHTS = [DirectionalLight((1, 1, 1), (1, 1, 1)),
                   DirectionalLight((-1, 0.6, -0.4), (1, 0.5, 0.2)),
                   DirectionalLight((0.3, -1.0, 0.7), (0.4, 0.4, 1.0))]


def _compare(par, axis_name, lights, tf=TF, step=None, field=None, origin=ORIGIN, planes=0):
    shape = SHAPES[axis_name]
    whole = whole_extent(shape)
    field = blobs(shape) if field is None else field
    extent = Decomposition.of(whole, par.size).extents[par.rank]
    t, phi = distributed_light_transmittance(piece_volume(field, extent, whole), extent, whole,
                                             tf, 1.0, lights, step_size=step, comm=par.comm,
                                             origin=origin, segment_planes=planes)
    t_ref, phi_ref = light_transmittance(Volume(field, SPACING, ORIGIN), tf, 1.0, lights,
                                         step_size=step, segment_planes=planes, textures=False)
    cut = sub_slices(extent, whole)
    ref = t_ref[(slice(None), *cut)]
    err = [max_abs(t[li], ref[li]) for li in range(len(lights))]
    scale = max(float(np.abs(phi_ref).max()), 1e-30)
    phi_err = max_abs(phi, phi_ref[cut])
    ok = t.shape == ref.shape and bool(np.all(np.abs(t - ref) <= ATOL + RTOL * ref)) \
        and phi_err <= 1e-6 * scale
    all_ranks(par, ok, f"{par.size} ranks, split along {axis_name}: max |dT| per light {err}, "
              f"fluence {phi_err:.2e} of {scale:.3g}")
    return err


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
def test_lights_along_each_axis_equal_one_rank(par, axis_name):
    _compare(par, axis_name, AXIS_LIGHTS)


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
def test_diagonal_lights_equal_one_rank(par, axis_name):
    _compare(par, axis_name, DIAGONAL_LIGHTS)


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
def test_point_light_inside_another_ranks_block(par, axis_name):
    whole = whole_extent(SHAPES[axis_name])
    d = Decomposition.of(whole, par.size)
    # The light sits in the last piece (another rank's block for every other rank), one
    # exactly on a cut plane, and one outside the box.
    cut_point = np.asarray(ORIGIN) + np.asarray(d.extents[-1][0::2]) * np.asarray(SPACING)
    lights = [PointLight(tuple(piece_centre(d.extents[-1])), (5, 5, 5)),
              PointLight(tuple(cut_point + 0.3), (3, 3, 3)),
              PointLight((-3.0, 5.0, 20.0), (40, 40, 40))]
    _compare(par, axis_name, lights)


@pytest.mark.parametrize("step", [0.37, 0.5, 0.11])
def test_steps_that_do_not_line_up_with_the_grid(par, step):
    _compare(par, "x", DIAGONAL_LIGHTS[:2] + AXIS_LIGHTS[:1], step=step)


def test_early_stop_in_dense_data_is_the_one_rank_stop(par):
    _compare(par, "y", DIAGONAL_LIGHTS[:1] + AXIS_LIGHTS[2:4], tf=DENSE_TF)


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
def test_early_stop_in_another_ranks_block(par, axis_name):
    """Opaque data in the far half only: rays from the near pieces stop in another rank's
    block, and that rank returns the stopped sum (not a march to go on with)."""
    shape = SHAPES[axis_name]
    a = "xyz".index(axis_name)
    field = blobs(shape)
    far = [slice(None)] * 3
    far[a] = slice(shape[a] * 2 // 3, None)
    field[tuple(far)] += 1.0
    toward_far = [0.0, 0.0, 0.0]
    toward_far[a] = -1.0  # travel direction: the rays to the light run towards +axis
    lights = [DirectionalLight(tuple(toward_far), (1, 1, 1)),
              DirectionalLight(tuple(np.asarray(toward_far) + (0.3, -0.2, 0.25)), (1, 1, 1))]
    _compare(par, axis_name, lights, tf=STOP_TF, field=field)


def test_default_origin_from_the_piece(par):
    """Without ``origin`` the whole volume's first point comes from the piece (exact for
    the test volume's binary spacing)."""
    _compare(par, "z", DIAGONAL_LIGHTS[:1] + [PointLight((3.0, 4.0, 6.0), (5, 5, 5))],
             origin=None)


def test_every_smaller_rank_count(par):
    """VTK's split for 2 .. size ranks (3 on a 4-rank run) through sub-communicators."""
    for n in range(2, par.size):
        sub = par.comm.Split(0 if par.rank < n else 1, par.rank)
        try:
            if par.rank < n:
                for axis_name in sorted(SHAPES):
                    _compare(Parallel.create(sub), axis_name,
                             DIAGONAL_LIGHTS[:2] + [PointLight((2.0, 4.5, 5.5), (5, 5, 5))])
        finally:
            sub.Free()
        par.comm.Barrier()


@pytest.mark.parametrize("pieces", [1, 2, 3, 4, 5, 8])
def test_cell_owners_tile_the_cells_once(pieces):
    whole = (0, 20, 0, 12, 0, 10)
    d = Decomposition.of(whole, pieces)
    bricks, owner = cell_owners(d)
    for i in range(20):
        for j in range(12):
            for k in range(10):
                p = owner[bricks[0][i], bricks[1][j], bricks[2][k]]
                e = d.extents[p]
                assert e[0] <= i < e[1] and e[2] <= j < e[3] and e[4] <= k < e[5]


def test_many_lights_agree_with_one_at_a_time(par):
    whole = whole_extent(SHAPES["x"])
    field = blobs(SHAPES["x"])
    extent = Decomposition.of(whole, par.size).extents[par.rank]
    volume = piece_volume(field, extent, whole)
    lights = AXIS_LIGHTS[:2] + DIAGONAL_LIGHTS
    together, _ = distributed_light_transmittance(volume, extent, whole, TF, 1.0, lights,
                                                  comm=par.comm)
    alone = [distributed_light_transmittance(volume, extent, whole, TF, 1.0, [light],
                                             comm=par.comm)[0][0] for light in lights]
    all_ranks(par, all(np.array_equal(together[i], alone[i]) for i in range(len(lights))))


def test_wrong_piece_is_refused(par):
    whole = whole_extent(SHAPES["x"])
    field = blobs(SHAPES["x"])
    with pytest.raises(ValueError, match="VTK's piece"):
        distributed_light_transmittance(piece_volume(field, whole, whole), whole,
                                        (0, 30, 0, 12, 0, 10), TF, 1.0, AXIS_LIGHTS[:1],
                                        comm=par.comm)


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
@pytest.mark.parametrize("planes", [3, 16])
def test_chained_segments_equal_one_rank(par, axis_name, planes):
    """Chained segments slab by slab across the ranks (:mod:`vtkillum.core.parallel.chained`)
    equal the one-rank chained grid, for axis, diagonal and point lights together (the point
    light keeps its exact ray), early stops included; short slabs (3 planes) cross the cuts
    often."""
    lights = [AXIS_LIGHTS[1], *DIAGONAL_LIGHTS, PointLight((1.0, -2.0, 3.0), (20.0, 20.0, 20.0))]
    _compare(par, axis_name, lights, planes=planes)
    _compare(par, axis_name, DIAGONAL_LIGHTS[:1], tf=DENSE_TF, planes=planes)
