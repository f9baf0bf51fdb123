"""Historygrams: an incremental update after a transfer-function edit gives the same photon
map and the same image as a full recompute with the same seeds, and recomputes what the
masks say (Jönsson et al. 2012, sections 4.2-4.3)."""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.photon.historygram import (
    ALL_BITS,
    BITS,
    data_bin,  # noqa: F401  (kernels use it; imported to check it exists)
    interval_mask,
    intervals_mask,
    mask_bins,
    query_mask,
    query_masks,
)
from vtkillum.core.photon.mapper import PhotonMapper
from vtkillum.core.photon.tracing import photon_tables
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

N = 24
SIZE = 24
RECEIVER, OTHER, OCCLUDER = 0.3, 0.55, 0.8


def scene_volume():
    """A receiver slab (0.3) under an occluding ball (0.8) lit from above, and a third ball
    (0.55) beside them; empty space is 0."""
    h = 1.0 / (N - 1)
    x = np.arange(N) * h
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    v = np.zeros((N, N, N), np.float32)
    v[(Y > 0.15) & (Y < 0.3) & (X > 0.1) & (X < 0.6)] = RECEIVER
    v[(X - 0.35) ** 2 + (Y - 0.65) ** 2 + (Z - 0.5) ** 2 < 0.15 ** 2] = OCCLUDER
    v[(X - 0.8) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2 < 0.12 ** 2] = OTHER
    v[-1, -1, -1] = 1.0  # data range [0, 1]
    return Volume(v, (h, h, h))


def tf(receiver=0.5, other=0.5, occluder=0.9, other_color=(1.0, 0.5, 0.2)):
    w = 0.06
    pts = [0.0, RECEIVER - w, RECEIVER, RECEIVER + w, OTHER - w, OTHER, OTHER + w,
           OCCLUDER - w, OCCLUDER, OCCLUDER + w, 1.0]
    alpha = [0.0, 0.0, receiver, 0.0, 0.0, other, 0.0, 0.0, occluder, 0.0, 0.0]
    white = (1.0, 1.0, 1.0)
    colors = [white] * 4 + [other_color] * 3 + [white] * 4
    return TransferFunction(pts, alpha, colors)


CAMERA = Camera((0.5, 0.9, 2.6), (0.5, 0.45, 0.5), (0.0, 1.0, 0.0), 35.0)
LIGHTS = [DirectionalLight((0.1, -1.0, -0.05), (4.0, 4.0, 4.0))]


def mapper(direct="exact", spatial=True, historygrams=True):
    volume = scene_volume()
    return volume, PhotonMapper("cpu", photons=6000, radius=2.0 * volume.mean_spacing(),
                                max_order=0, segments=6, seed=5, historygrams=historygrams,
                                spatial_historygram=spatial, direct=direct)


def run(m, volume, transfer_function):
    stats = m.update(volume, transfer_function, volume.mean_spacing(), 0.9, 0.2, LIGHTS)
    image = m.render(volume, CAMERA, SIZE, SIZE, 0.5 * volume.spacing.min(), seed=2)
    return stats, image


def full(transfer_function, direct="exact"):
    volume, m = mapper(direct)
    return m, run(m, volume, transfer_function)[1]


def masks(volume, old, new):
    u = volume.mean_spacing()
    qs, qc = query_masks(photon_tables(old, u, volume.value_range)[:2],
                         photon_tables(new, u, volume.value_range)[:2], volume.value_range)
    return np.uint64(qs), np.uint64(qc)


def flagged(segs, qs, qc):
    hit = ((segs["hist"] & qs) | (segs["chist"] & qc)) != 0
    return int(np.count_nonzero(hit & (segs["state"] == 1)))


def assert_same_map(a, b):
    da, db = a.map.numpy(), b.map.numpy()
    for key in da:
        np.testing.assert_array_equal(da[key], db[key], err_msg=key)


EDITS = {
    "opacity": tf(other=0.8),
    "colour": tf(other_color=(0.2, 0.4, 1.0)),
    "shadow": tf(occluder=0.0),  # removing the occluder lights the receiver
}


def test_query_mask_from_tables():
    volume = scene_volume()
    u = volume.mean_spacing()
    old = photon_tables(tf(), u, volume.value_range)[:2]
    assert query_mask(old, old, volume.value_range) == 0
    new = photon_tables(tf(other=0.8), u, volume.value_range)[:2]
    bins = mask_bins(query_mask(old, new, volume.value_range))
    # The edit changes opacity on (0.49, 0.61): bins 31..39 of 64, nothing else.
    assert bins and min(bins) >= int(0.48 * BITS) and max(bins) <= int(0.62 * BITS)
    assert interval_mask(0.0, 1.0, (0.0, 1.0)) == ALL_BITS


@pytest.mark.parametrize("edit", sorted(EDITS))
@pytest.mark.parametrize("direct", ["exact", "photons"])
def test_incremental_equals_full_recompute(edit, direct):
    volume, m = mapper(direct)
    run(m, volume, tf())
    before = m.map.numpy()
    segs = m.segments_numpy()
    qs, qc = masks(volume, tf(), EDITS[edit])
    stats, image = run(m, volume, EDITS[edit])
    # What the masks say: photons whose path Historygrams meet the queries are retraced.
    expected = int(np.count_nonzero((before["path_hist"] & qs) | (before["path_chist"] & qc)))
    assert stats["mode"] == "incremental"
    assert stats["photons_retraced"] == expected > 0
    assert stats["photons_retraced"] < 0.9 * m.photons
    by_data = flagged(segs, qs, qc)
    info = m.last_render
    assert info["mode"] == "incremental"
    assert info["segments_recomputed"] >= by_data
    assert info["segments_recomputed"] < 0.9 * info["segments"]

    reference_mapper, reference = full(EDITS[edit], direct)
    assert_same_map(m, reference_mapper)
    np.testing.assert_array_equal(image.radiance, reference.radiance)
    np.testing.assert_array_equal(image.alpha, reference.alpha)
    assert image.radiance.max() > 0


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_bounded_order_update_equals_full_recompute(edit):
    """With S_n = 2 a retrace ends every path in one round, queued without reading the
    counts in between (the buffer sized for the most the round can leave): the same map
    and image as a full recompute."""
    def make():
        volume = scene_volume()
        return volume, PhotonMapper("cpu", photons=6000, radius=2.0 * volume.mean_spacing(),
                                    max_order=2, segments=6, seed=5, direct="photons")

    volume, m = make()
    run(m, volume, tf())
    stats, image = run(m, volume, EDITS[edit])
    assert stats["mode"] == "incremental" and stats["photons_retraced"] > 0
    assert stats["interactions_added"] > 0 and stats["interactions_removed"] > 0
    assert m.map.capacity >= m.map.total
    volume, reference = make()
    _, expected = run(reference, volume, EDITS[edit])
    assert stats["interactions"] == reference.map.total
    assert_same_map(m, reference)
    np.testing.assert_array_equal(image.radiance, expected.radiance)
    np.testing.assert_array_equal(image.alpha, expected.alpha)


def test_query_mask_of_many_intervals_is_the_or_of_each():
    """The query of an edit (one vectorised pass over the changed table entries) sets
    exactly the bins of :func:`interval_mask` of each interval."""
    rng = np.random.default_rng(3)
    for value_range in ((0.0, 1.0), (-3.0, 250.0), (2.0, 2.0)):
        lo, hi = value_range
        for _ in range(200):
            n = int(rng.integers(0, 6))
            a = rng.uniform(lo - 0.2 * (hi - lo + 1), hi + 0.2 * (hi - lo + 1), n)
            b = a + rng.uniform(0.0, 0.1, n) * (hi - lo + 1) * rng.integers(0, 2, n)
            expected = 0
            for x, y in zip(a, b):
                expected |= interval_mask(x, y, value_range)
            assert intervals_mask(a, b, value_range) == expected


def test_spatial_historygram_is_needed_for_shadows():
    """Removing the occluder: the receiver's segments hold none of the occluder's data
    values (photon mode), only the spatial Historygram sends them for recomputation."""
    edit = EDITS["shadow"]
    _, reference = full(edit, "photons")
    volume, m = mapper("photons", spatial=False)
    run(m, volume, tf())
    segs = m.segments_numpy()
    _, stale = run(m, volume, edit)
    by_data = flagged(segs, *masks(volume, tf(), edit))
    # Without the spatial Historygram exactly the data-flagged segments (plus those that
    # became visible) are recomputed ...
    assert m.last_render["segments_recomputed"] >= by_data
    assert m.last_render["segments_recomputed"] - by_data <= m.last_render["segments"] // 10
    # ... and the receiver stays dark where the occluder's shadow was.
    diff = np.abs(stale.radiance - reference.radiance).max()
    assert diff > 0.05 * reference.radiance.max(), diff

    volume, m = mapper("photons", spatial=True)
    run(m, volume, tf())
    _, image = run(m, volume, edit)
    assert m.last_render["segments_recomputed"] > by_data
    np.testing.assert_array_equal(image.radiance, reference.radiance)


def test_edit_that_changes_nothing_recomputes_nothing():
    volume, m = mapper()
    _, first = run(m, volume, tf())
    # A new transfer function object with the same values, and a change outside the data:
    # (values above 1.0 never occur) -- neither touches any table entry.
    same = tf()
    same_plus = TransferFunction(np.append(same.scalars, 1.5), np.append(same.opacity, 0.7),
                                 np.vstack([same.colors, [[0.1, 0.2, 0.3]]]))
    for edit in (same, same_plus):
        stats, image = run(m, volume, edit)
        assert stats["mode"] == "unchanged" and stats["photons_retraced"] == 0
        assert m.last_render["segments_recomputed"] == 0
        np.testing.assert_array_equal(image.radiance, first.radiance)


def test_without_historygrams_everything_is_recomputed():
    volume, m = mapper(historygrams=False)
    run(m, volume, tf())
    stats, image = run(m, volume, EDITS["colour"])
    assert stats["mode"] == "full" and stats["photons_retraced"] == m.photons
    assert m.last_render["mode"] == "full"
    _, reference = full(EDITS["colour"])
    np.testing.assert_array_equal(image.radiance, reference.radiance)


def test_colour_edit_keeps_photons_that_never_scattered_there():
    """A colour-only edit with S_n = 1: no photon scattered, none is retraced (the colour
    Historygram); only segments that scattered light in the edited material recompute."""
    volume = scene_volume()
    m = PhotonMapper("cpu", photons=6000, radius=2.0 * volume.mean_spacing(), max_order=1,
                     segments=6, seed=5, direct="photons")
    run(m, volume, tf())
    segs = m.segments_numpy()
    qs, qc = masks(volume, tf(), EDITS["colour"])
    assert qs == 0 and qc != 0
    stats, image = run(m, volume, EDITS["colour"])
    assert stats["photons_retraced"] == 0
    assert m.last_render["segments_recomputed"] == flagged(segs, qs, qc) > 0
    assert m.last_render["segment_fraction"] < 0.3
    reference = PhotonMapper("cpu", photons=6000, radius=2.0 * volume.mean_spacing(),
                             max_order=1, segments=6, seed=5, direct="photons")
    _, expected = run(reference, volume, EDITS["colour"])
    np.testing.assert_array_equal(image.radiance, expected.radiance)


@pytest.mark.parametrize("max_order", [1, 0])
def test_path_masks_are_the_or_of_every_path(max_order):
    """``PhotonMap.path_masks`` is the OR of the stored paths' Historygrams after a trace and
    after a retrace; a query that misses it needs no look at the paths (no query launch),
    one that meets it does."""
    volume = scene_volume()
    m = PhotonMapper("cpu", photons=3000, radius=2.0 * volume.mean_spacing(),
                     max_order=max_order, segments=4, seed=3, direct="photons")

    def expected():
        paths = m.map.numpy()
        return (int(np.bitwise_or.reduce(paths["path_hist"])),
                int(np.bitwise_or.reduce(paths["path_chist"])))

    run(m, volume, tf())
    assert m.map.path_masks == expected()
    assert m.map.path_masks[0] != 0
    # S_n = 1: no path scattered, so its colour mask is empty and a colour edit is answered
    # without a query; with multiple scattering the colour edit must query the paths.
    assert (m.map.path_masks[1] == 0) == (max_order == 1)
    stats, _ = run(m, volume, EDITS["colour"])
    assert stats["mode"] == "incremental"
    assert (m._query_buffers is None) == (max_order == 1)
    stats, _ = run(m, volume, EDITS["opacity"])  # retraces photons
    assert stats["photons_retraced"] > 0
    assert m.map.path_masks == expected()
