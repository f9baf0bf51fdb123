"""The distributed radiance cache (tube march by segment forwarding) against the one-rank
:class:`~vtkillum.core.ambient.cache.AmbientScatteringCache`, on every rank of
``mpirun -np N python -m pytest tests/distributed/test_ambient_radiance.py``.

Every sample of every chain is taken at the one-rank position with the one-rank float32
arithmetic; what differs is ``σ̃t``'s summed-area table rounding (1e-6 of its maximum,
``test_ambient.py``), carried through ``T̃``. Tolerance: 1e-5 of the largest radiance.
"""

import numpy as np
import pytest

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.ambient.distributed_radiance import distributed_radiance_cache
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.parallel import Decomposition, sub_slices
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

from .conftest import all_ranks, max_abs
from .volumes import ORIGIN, SHAPES, SPACING, blobs, piece_centre, piece_volume, whole_extent

TOL = 1e-5
# dense enough that the fronts fall to a few per cent across the box: shadows cross the cuts
TF = TransferFunction(scalars=[0.0, 1.5], opacity=[0.0, 0.9], colors=[[1, 1, 1], [1, 1, 1]])

AXES = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
DIAGONALS = [(1, 1, 1), (-1, 1, -1), (1, -2, 0.5), (-0.3, -1, 1)]


def _compare(par, shape, lights, radius, samples=1, anisotropy=0.3, **options):
    whole = whole_extent(shape)
    field = blobs(shape)
    extent = Decomposition.of(whole, par.size).extents[par.rank]
    got = distributed_radiance_cache(piece_volume(field, extent, whole), extent, whole, TF, 1.0,
                                     radius, lights, anisotropy=anisotropy, comm=par.comm,
                                     samples=samples, **options)
    cache = AmbientScatteringCache(par.device, step_samples=samples, data_textures=False)
    state = cache.update(Volume(field, SPACING, ORIGIN), TF, 1.0, 0.9, anisotropy, lights,
                         radius, "world", cache_shape=shape)
    ref = state.radiance.numpy()[(slice(None),) + sub_slices(extent, whole)]
    ref_sigma = state.sigma_tilde.numpy()[sub_slices(extent, whole)]
    return got, ref, ref_sigma


def _check(par, got, ref, ref_sigma, what):
    scale = float(np.abs(ref).max())
    err = max_abs(got.radiance, ref)
    err_sigma = max_abs(got.sigma_tilde, ref_sigma)
    # the shadows must be there (a test volume that lets everything through proves nothing)
    darkest = min(par.comm.allgather(float(np.abs(ref).min()) / scale))
    dark = darkest < 0.5
    ok = got.radiance.shape == ref.shape and err <= TOL * scale and dark \
        and err_sigma <= 1e-6 * float(np.abs(ref_sigma).max())
    all_ranks(par, ok, f"{what}: radiance max diff {err:.3g} of {scale:.3g} "
                       f"(darkest {darkest:.3g} of it), σ̃t diff {err_sigma:.3g}")
    return err / scale


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
@pytest.mark.parametrize("radius", [0.5, 1.5, 4.0])  # world units: 1, 3 and 8 voxels
def test_directional_lights_along_axes_and_diagonals(par, axis_name, radius):
    lights = [DirectionalLight(np.asarray(d, float), (1.0, 0.8, 0.6)) for d in AXES + DIAGONALS]
    got, ref, ref_sigma = _compare(par, SHAPES[axis_name], lights, radius)
    _check(par, got, ref, ref_sigma, f"split {axis_name}, r {radius}")
    if par.size > 1:  # chains cross the cuts: records were handed on
        all_ranks(par, par.comm.allreduce(got.forwarded) > 0, "no record was forwarded")


@pytest.mark.parametrize("axis_name", sorted(SHAPES))
def test_point_lights_inside_other_pieces_and_outside(par, axis_name):
    shape = SHAPES[axis_name]
    whole = whole_extent(shape)
    extents = Decomposition.of(whole, par.size).extents
    # the same lights on every rank: one in the middle of each piece, one outside the box
    lights = [PointLight(piece_centre(ext) + 0.13, (3.0, 2.0, 1.0)) for ext in extents]
    lights.append(PointLight(np.asarray(ORIGIN) + (-4.0, 14.0, 3.0), (400.0, 400.0, 400.0)))
    got, ref, ref_sigma = _compare(par, shape, lights, 1.0)
    _check(par, got, ref, ref_sigma, f"point lights, split {axis_name}")


def test_several_samples_per_step(par):
    lights = [DirectionalLight(np.asarray(d, float), (1.0, 1.0, 1.0))
              for d in [(0, 0, 1), (1, 1, 1), (-1, 0.5, 0)]]
    got, ref, ref_sigma = _compare(par, SHAPES["x"], lights, 1.5, samples=3, anisotropy=-0.2)
    _check(par, got, ref, ref_sigma, "3 samples per step")


def test_chains_started_in_batches(par):
    # 997 chains per batch: several batches, not as many on every rank (uneven pieces)
    lights = [DirectionalLight(np.asarray(d, float), (1.0, 1.0, 1.0)) for d in [(1, 1, 1), (0, -1, 0)]]
    got, ref, ref_sigma = _compare(par, SHAPES["y"], lights, 1.0, max_records=997)
    _check(par, got, ref, ref_sigma, "batches of 997 chains")
