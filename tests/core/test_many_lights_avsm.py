"""Adaptive volumetric shadow maps of the virtual lights (paper section 3.4, Fig. 3).

* a homogeneous slab: every stored node is exact (``exp(-sigma d)`` at its depth), and
  lookups at a texel's direction return it;
* random heterogeneous volumes: cached against ray-marched transmittance, with stated
  bounds (the numbers of the paper's Fig. 3 for our sizes), trilinear better than point;
* Salvi's adaptive compression keeps the corners of a two-slab curve, where an even
  subsampling in depth does not;
* the multiple-scattering image with AVSMs against the same VLs ray-marched (Fig. 3 as
  one number: mean relative error per pixel);
* the pool keeps maps when it grows and hands freed slots out again.
"""

import functools

import numpy as np
import pytest
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.many_lights.avsm import (
    ShadowMapPool,
    ShadowMaps,
    avsm_lookup,
    avsm_transmittance,
    lookup_function,
    node_insertion,
    texel_direction_host,
    texel_type,
    texel_view,
)
from vtkillum.core.many_lights.render import ManyLightsRenderer
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import Medium, make_medium, shadow_transmittance
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, cloud
from vtkillum.data.procedural import _fbm

init_warp()


@wp.kernel
def compare_kernel(m: Medium, sm: ShadowMaps, origins: wp.array(dtype=wp.vec3),
                   slots: wp.array(dtype=wp.int32), points: wp.array(dtype=wp.vec3), step: float,
                   out: wp.array2d(dtype=wp.float32)):
    """``wp.tid()`` indexes query points: ray-marched and cached T from a VL to the point."""
    i = wp.tid()
    o = origins[i]
    x = points[i]
    v = o - x
    d = wp.length(v)
    out[i, 0] = shadow_transmittance(m, x, v / d, d, step, 0.5, 0.0)
    out[i, 1] = avsm_transmittance(sm, slots[i], o, x)


def compare(medium, pool, lookup, origins, slots, points, step, device):
    out = wp.zeros((len(points), 2), dtype=wp.float32, device=device)
    wp.launch(compare_kernel, dim=len(points),
              inputs=[medium, pool.maps(lookup), wp.array(origins, dtype=wp.vec3, device=device),
                      wp.array(slots, dtype=wp.int32, device=device),
                      wp.array(points, dtype=wp.vec3, device=device), float(step), out],
              device=device)
    return out.numpy()


def unit_volume(values):
    n = values.shape[0]
    h = 1.0 / (n - 1)
    return Volume(values.astype(np.float32), (h, h, h), (0.0, 0.0, 0.0))


def test_homogeneous_medium_is_exact_at_the_stored_depths(device):
    sigma, u = 2.5, 0.1
    volume = unit_volume(np.ones((9, 9, 9)))
    tf = TransferFunction([0.0, 1.0], [1 - np.exp(-sigma * u)] * 2)
    medium = make_medium(volume, tf, u, device=device)
    pool = ShadowMapPool(6, 5, device)
    slots = pool.allocate(1)
    origin = np.array([[0.3, 0.55, 0.4]], np.float32)
    pool.build(medium, wp.array(origin, dtype=wp.vec3, device=device), [0], slots, 0.05, 0)
    rows = []
    for face in range(6):
        for row in (0, 2, 5):
            for col in (1, 4):
                nodes = pool.curve(slots[0], face, row, col)
                depth, trans = nodes[:, 0].astype(np.float64), nodes[:, 1]
                assert np.all(np.diff(depth) >= 0) and np.all(np.diff(trans) <= 0)
                np.testing.assert_allclose(trans, np.exp(-sigma * depth), rtol=2e-5)
                # the last node is the box exit
                w = texel_direction_host(face, row, col, 6)
                exit_t = np.min(np.where(w > 0, (1 - origin[0]) / np.where(w > 0, w, 1),
                                         np.where(w < 0, -origin[0] / np.where(w < 0, w, 1),
                                                  np.inf)))
                assert depth[-1] == pytest.approx(exit_t, rel=1e-4)
                rows.append((w, depth))
    # Lookups along a texel's centre direction at its stored depths return the nodes.
    origins, points, expected = [], [], []
    for w, depth in rows:
        for d in depth:
            origins.append(origin[0])
            points.append(origin[0] + (d * (1 - 1e-6)) * w)
            expected.append(np.exp(-sigma * d))
    for lookup in ("point", "trilinear"):
        out = compare(medium, pool, lookup, np.array(origins, np.float32),
                      np.zeros(len(points), np.int32), np.array(points, np.float32), 0.01,
                      device)
        np.testing.assert_allclose(out[:, 1], expected, rtol=1e-4, atol=1e-6)


def random_volume(seed, n=24):
    rng = np.random.default_rng(seed)
    lattices = [rng.random((16, 16, 16), dtype=np.float32) for _ in range(4)]
    x = np.linspace(0.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    q = 3.0 * np.stack([X, Y, Z], -1).astype(np.float32)
    return unit_volume(_fbm(q + seed, lattices))


@pytest.mark.parametrize("resolution, nodes, lookup, mean_bound, p95_bound", [
    (48, 8, "trilinear", 0.004, 0.010),
    (48, 8, "point", 0.007, 0.020),
    (16, 8, "trilinear", 0.009, 0.025),
    (48, 12, "trilinear", 0.0025, 0.006),
])
def test_cached_against_ray_marched_on_random_volumes(resolution, nodes, lookup, mean_bound,
                                                      p95_bound):
    """Absolute transmittance error at random points, 3 random volumes x 6 VLs."""
    errors = []
    for seed in range(3):
        volume = random_volume(seed)
        lo, hi = volume.value_range
        tf = TransferFunction([lo, (lo + hi) / 2, hi], [0.0, 0.05, 0.3])
        medium = make_medium(volume, tf, volume.mean_spacing(), device="cpu")
        pool = ShadowMapPool(resolution, nodes, "cpu")
        rng = np.random.default_rng(seed + 10)
        origins = rng.random((6, 3)).astype(np.float32)
        slots = pool.allocate(6)
        pool.build(medium, wp.array(origins, dtype=wp.vec3, device="cpu"), np.arange(6), slots,
                   float(volume.spacing.min()), 0)
        which = rng.integers(0, 6, 6000)
        points = rng.random((6000, 3)).astype(np.float32)
        out = compare(medium, pool, lookup, origins[which], slots[which], points,
                      float(volume.spacing.min()) / 2, "cpu")
        assert 0.1 < out[:, 0].mean() < 0.9  # neither transparent nor opaque
        errors.append(out[:, 1] - out[:, 0])
    err = np.abs(np.concatenate(errors))
    assert err.mean() < mean_bound, err.mean()
    assert np.percentile(err, 95) < p95_bound, np.percentile(err, 95)


def test_adaptive_compression_keeps_the_corners():
    """Two thin dense slabs along +x: 5 nodes place themselves at the curve's corners."""
    n = 41
    values = np.zeros((n, 5, 5))
    values[10:13] = 1.0   # slab 1 at x = 0.25 .. 0.3
    values[25:27] = 1.0   # slab 2 at x = 0.625 .. 0.65
    volume = unit_volume(values)
    tf = TransferFunction([0.0, 1.0], [0.0, 0.5])
    medium = make_medium(volume, tf, 0.1, device="cpu")
    pool = ShadowMapPool(3, 5, "cpu")
    slots = pool.allocate(1)
    origin = np.array([[0.0, 0.05, 0.05]], np.float32)  # the box is 1 x 0.1 x 0.1
    pool.build(medium, wp.array(origin, dtype=wp.vec3, device="cpu"), [0], slots, 0.002, 0)
    nodes = pool.curve(slots[0], 0, 1, 1)  # +x face, centre texel: the ray along +x
    depth = np.linspace(0.0, 1.0, 2001)
    # the truth, marched finely along the ray (values constant across y and z)
    sig, _c, lo, hi = tf.lookup_tables(0.1, volume.value_range)
    s = np.interp(depth, np.linspace(0, 1, n), values[:, 0, 0])
    sigma = np.interp(s, np.linspace(lo, hi, len(sig)), sig)
    truth = np.exp(-np.concatenate([[0], np.cumsum(0.5 * (sigma[1:] + sigma[:-1])
                                                   * np.diff(depth))]))

    def curve(d, t):
        return np.interp(depth, np.concatenate([[0], d]), np.concatenate([[1], t]))

    adaptive = np.abs(curve(nodes[:, 0], nodes[:, 1]) - truth).mean()
    even_d = np.linspace(0.0, 1.0, 6)[1:]
    even = np.abs(curve(even_d, np.interp(even_d, depth, truth)) - truth).mean()
    assert adaptive < 0.01 and adaptive < even / 4, (adaptive, even)


def test_multiple_scattering_image_error_fig3():
    """The same VLs rendered with cached and with ray-marched transmittance."""
    volume = cloud(24)
    scene = _medium_scene(volume, 8.0, 0.9, 0.3, [_side_light()])
    common = {"count": 96, "jitter": False, "seed": 1}
    marched = ManyLightsRenderer(volume, scene, 24, 24, "cpu", transmittance="ray-marching",
                                 **common).run(1).result().info["multiple"]
    for lookup, bound in (("trilinear", 0.03), ("point", 0.03)):
        cached = ManyLightsRenderer(volume, scene, 24, 24, "cpu", avsm_lookup=lookup,
                                    **common).run(1).result().info["multiple"]
        lum_m, lum_c = marched.mean(-1), cached.mean(-1)
        seen = lum_m > 0.05 * lum_m.max()
        relative = np.abs(lum_c - lum_m)[seen] / lum_m[seen]
        assert relative.mean() < bound, (lookup, relative.mean())
        assert abs(cached.sum() / marched.sum() - 1.0) < bound


def test_pool_grows_without_losing_maps_and_reuses_slots():
    volume = random_volume(4, n=12)
    lo, hi = volume.value_range
    medium = make_medium(volume, TransferFunction([lo, hi], [0.0, 0.4]), 0.1, device="cpu")
    pool = ShadowMapPool(4, 4, "cpu")
    first = pool.allocate(3)
    positions = wp.array(np.full((3, 3), 0.5, np.float32), dtype=wp.vec3, device="cpu")
    pool.build(medium, positions, [0, 1, 2], first, 0.05, 7)
    before = pool.curve(first[1], 2, 1, 3)
    more = pool.allocate(40)
    assert pool.capacity >= 43 and len(set(more) | set(first)) == 43
    np.testing.assert_array_equal(pool.curve(first[1], 2, 1, 3), before)
    assert np.all(pool.epoch[first] == 7)
    pool.release(first[:2])
    again = pool.allocate(2)
    assert sorted(again) == sorted(first[:2])


def test_empty_blocks_are_exactly_transparent_and_skipping_them_changes_nothing(device):
    """On the CT phantom most blocks are air: they are classified empty, a block whose
    points straddle the TF's only visible band is not (a trilinear sample between its
    values lands in the band), and AVSMs and shadow rays with skipping equal those without,
    bit for bit, for VLs and points inside the body and in the air around it."""
    from vtkillum.data.procedural import ct_phantom, default_scene

    volume = ct_phantom(48)
    scene = default_scene("ct", volume)
    media = [make_medium(volume, scene.transfer_function, volume.mean_spacing(), device=device,
                         skip_empty=skip) for skip in (True, False)]
    empty = media[0].occupied.numpy() == 0
    assert empty.shape == (6, 6, 6) and 0.2 < empty.mean() < 0.9, empty.mean()
    assert media[1].occupied.numpy().all()

    values = np.zeros((33, 33, 33))
    values[12, 12, 12] = 1.0  # values 0 and 1 only: the visible band [0.45, 0.55] between
    band = unit_volume(values)
    tf = TransferFunction([0.0, 0.45, 0.5, 0.55, 1.0], [0.0, 0.0, 0.5, 0.0, 0.0])
    occupied = make_medium(band, tf, 0.1, device=device).occupied.numpy()
    assert occupied.shape == (4, 4, 4) and occupied[1, 1, 1] == 1 and occupied.sum() == 1

    extent = np.asarray(volume.extent, np.float32)
    origins = np.array([[0.5, 0.5, 0.5], [0.3, 0.45, 0.6], [0.05, 0.05, 0.05]], np.float32)
    origins *= extent
    positions = wp.array(origins, dtype=wp.vec3, device=device)
    maps = []
    for medium in media:
        pool = ShadowMapPool(8, 8, device)
        slots = pool.allocate(3)
        pool.build(medium, positions, [0, 1, 2], slots, float(min(volume.spacing)), 0)
        maps.append(pool.nodes.numpy())
    np.testing.assert_array_equal(maps[0], maps[1])
    assert np.ptp(maps[0][..., 1]) > 0.5  # the maps do see the body

    # Shadow rays (the single-scattering term, light volumes) from random points.
    rng = np.random.default_rng(3)
    points = wp.array((rng.random((64, 3)) * extent).astype(np.float32), dtype=wp.vec3,
                      device=device)
    dirs = rng.normal(size=(64, 3))
    dirs = wp.array((dirs / np.linalg.norm(dirs, axis=1)[:, None]).astype(np.float32),
                    dtype=wp.vec3, device=device)
    marched = []
    for medium in media:
        out = wp.zeros(64, dtype=wp.float32, device=device)
        wp.launch(shadow_kernel, dim=64, inputs=[medium, points, dirs, out], device=device)
        marched.append(out.numpy())
    np.testing.assert_array_equal(marched[0], marched[1])
    assert marched[0].min() < 0.5 < marched[0].max()


@wp.kernel
def shadow_kernel(m: Medium, points: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                  out: wp.array(dtype=wp.float32)):
    """``wp.tid()`` indexes rays: the transmittance to the box exit, jittered samples."""
    i = wp.tid()
    out[i] = shadow_transmittance(m, points[i], dirs[i], 1.0e30, 0.7, 0.3, 0.0)


@functools.cache
def insertion_kernel(count):
    """Feeds each row of candidate nodes through ``node_insertion(count)``."""
    insert = node_insertion(count)
    Vec = wp.types.vector(length=count + 1, dtype=wp.float32)

    @wp.kernel(module="unique")
    def feed(depths: wp.array2d(dtype=wp.float32), trans: wp.array2d(dtype=wp.float32),
             out: wp.array3d(dtype=wp.float32), kept: wp.array(dtype=wp.int32)):
        i = wp.tid()
        D = Vec()
        T = Vec()
        n = int(0)
        for s in range(depths.shape[1]):
            D, T, n = insert(D, T, n, depths[i, s], trans[i, s])
        for j in range(wp.static(count)):
            out[i, j, 0] = D[j]
            out[i, j, 1] = T[j]
        kept[i] = n

    return feed


def salvi_reference(depths, trans, count):
    """Salvi et al.'s insertion and removal, written plainly (float32 arithmetic)."""
    D, T = [], []
    for d, t in zip(depths, trans):
        D.append(d)
        T.append(t)
        if len(D) > count:
            areas = []
            for j in range(len(D) - 1):
                dl, tl = (np.float32(0), np.float32(1)) if j == 0 else (D[j - 1], T[j - 1])
                areas.append(abs((D[j] - dl) * (T[j + 1] - tl) - (D[j + 1] - dl) * (T[j] - tl)))
            best = int(np.argmin(areas))  # the first of equal areas
            del D[best], T[best]
    return np.array(D, np.float32), np.array(T, np.float32)


@pytest.mark.parametrize("count", [2, 3, 8, 16])
def test_node_insertion_is_salvis_compression(device, count):
    """The unrolled insertion of the construction kernels keeps the nodes that the plain
    algorithm keeps, for sequences shorter and longer than ``count``."""
    rng = np.random.default_rng(count)
    rows, length = 64, 3 * count
    depths = np.cumsum(rng.random((rows, length), np.float32) + 0.01, axis=1, dtype=np.float32)
    trans = np.exp(-np.cumsum(rng.random((rows, length)) * rng.random((rows, 1)) * 3, axis=1))
    trans = trans.astype(np.float32)
    lengths = rng.integers(1, length + 1, rows)
    for n in np.unique(lengths):  # one launch per distinct sequence length
        which = np.flatnonzero(lengths == n)
        part = wp.zeros((len(which), count, 2), dtype=wp.float32, device=device)
        part_kept = wp.zeros(len(which), dtype=wp.int32, device=device)
        wp.launch(insertion_kernel(count), dim=len(which),
                  inputs=[wp.array(np.ascontiguousarray(depths[which, :n]), dtype=wp.float32,
                                   device=device),
                          wp.array(np.ascontiguousarray(trans[which, :n]), dtype=wp.float32,
                                   device=device), part, part_kept], device=device)
        got, got_kept = part.numpy(), part_kept.numpy()
        for row, i in enumerate(which):
            D, T = salvi_reference(depths[i, :n], trans[i, :n], count)
            assert got_kept[row] == len(D) == min(n, count)
            np.testing.assert_array_equal(got[row, :len(D), 0], D)
            np.testing.assert_array_equal(got[row, :len(D), 1], T)
    assert (lengths > count).sum() > 10  # removal was exercised


@functools.cache
def lookup_pair_kernel(count):
    """The scanning :func:`avsm_lookup` and the counting ``lookup_function(count)``."""
    counted = lookup_function(count)
    Texel = texel_type(count)

    @wp.kernel(module="unique")
    def both(sm: ShadowMaps, texels: wp.array(dtype=Texel), origins: wp.array(dtype=wp.vec3),
             slots: wp.array(dtype=wp.int32), points: wp.array(dtype=wp.vec3),
             out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        v = points[i] - origins[i]
        d = wp.length(v)
        out[i, 0] = avsm_lookup(sm, slots[i], v, d)
        out[i, 1] = counted(sm, texels, slots[i], v, d)

    return both


@pytest.mark.parametrize("count", [3, 8])
def test_counting_lookup_equals_the_scan(device, count):
    """At random points, at the stored depths of texel centres, at the VL itself and far
    behind the last node, for point and trilinear filtering."""
    volume = random_volume(1)
    lo, hi = volume.value_range
    tf = TransferFunction([lo, (lo + hi) / 2, hi], [0.0, 0.1, 0.6])
    medium = make_medium(volume, tf, volume.mean_spacing(), device=device)
    pool = ShadowMapPool(6, count, device)
    rng = np.random.default_rng(count)
    origins = rng.random((4, 3)).astype(np.float32)
    slots = pool.allocate(4)
    pool.build(medium, wp.array(origins, dtype=wp.vec3, device=device), np.arange(4), slots,
               float(volume.spacing.min()), 0)
    which = rng.integers(0, 4, 3000)
    points = rng.random((3000, 3)).astype(np.float32)
    points[:40] = origins[which[:40]]  # depth 0
    points[40:80] = origins[which[40:80]] + 5.0 * (points[40:80] - origins[which[40:80]])
    for k in range(80, 400):  # a stored node's depth along a texel centre
        face, row, col, node = rng.integers(0, 6), rng.integers(0, 6), rng.integers(0, 6), \
            rng.integers(0, count)
        depth = pool.curve(slots[which[k]], face, row, col)[node, 0]
        points[k] = origins[which[k]] + depth * texel_direction_host(face, row, col, 6)
    for lookup in ("point", "trilinear"):
        out = wp.zeros((3000, 2), dtype=wp.float32, device=device)
        maps = pool.maps(lookup)
        wp.launch(lookup_pair_kernel(count), dim=3000,
                  inputs=[maps, texel_view(maps),
                          wp.array(origins[which], dtype=wp.vec3, device=device),
                          wp.array(slots[which], dtype=wp.int32, device=device),
                          wp.array(points, dtype=wp.vec3, device=device), out], device=device)
        scan, counted = out.numpy().T
        np.testing.assert_array_equal(counted, scan)
        assert 0.05 < scan.mean() < 0.95 and np.ptp(scan) > 0.5
