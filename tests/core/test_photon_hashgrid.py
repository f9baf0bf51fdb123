"""The photon hash and the work orders of the GPU paths: the gather sums exactly the photons
within the radius (against brute force, for several cell sizes), and the orders chosen for
speed on the GPU (photons sorted by where they leave the lights, segments gathered one
thread per sample) give the same bits as the plain ones (forced on the CPU here)."""

import numpy as np
import pytest
import warp as wp

import vtkillum.core.photon.hashgrid as hashgrid
import vtkillum.core.photon.segments as segments
import vtkillum.core.photon.tracing as tracing
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.photon.emission import make_emitters
from vtkillum.core.photon.hashgrid import PhotonGrid, build_photon_grid, gather_flux
from vtkillum.core.photon.historygram import ALL_BITS
from vtkillum.core.photon.storage import allocate
from vtkillum.core.photon.tracing import PhotonMap, photon_medium

from test_photon_historygram import EDITS, assert_same_map, mapper, run, tf


@wp.kernel
def flux_kernel(grid: PhotonGrid, x: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = gather_flux(grid, x[i])


def random_photons(n, extent, rng):
    """Photons in ``[0, extent]`` with clusters (a dense layer and a dense blob), random
    flux and orders 1-2; one photon exactly on a cell corner."""
    pos = rng.uniform(0.0, 1.0, (n, 3)) * extent
    pos[: n // 4, 1] = extent[1] * (0.9 + 0.01 * rng.uniform(size=n // 4))  # a layer
    pos[n // 4: n // 2] = extent * 0.3 + 0.02 * rng.normal(size=(n // 2 - n // 4, 3))
    pos = np.clip(pos, 0.0, extent)
    pos[-1] = extent * 0.5
    it = allocate(n, "cpu")
    it.pos = wp.array(pos.astype(np.float32), dtype=wp.vec3, device="cpu")
    it.dir = wp.array(rng.normal(size=(n, 3)).astype(np.float32), dtype=wp.vec3, device="cpu")
    it.flux = wp.array(rng.uniform(0.5, 1.0, (n, 3)).astype(np.float32), dtype=wp.vec3,
                       device="cpu")
    it.order = wp.array(rng.integers(1, 3, n).astype(np.int32), dtype=wp.int32, device="cpu")
    return it, pos.astype(np.float32)


@pytest.mark.parametrize("per_radius, max_cells", [(1, 1 << 25), (2, 1 << 25), (3, 1 << 25),
                                                   (2, 500)])
def test_gather_sums_exactly_the_photons_within_the_radius(monkeypatch, per_radius, max_cells):
    monkeypatch.setattr(hashgrid, "CELLS_PER_RADIUS", per_radius)
    monkeypatch.setattr(hashgrid, "MAX_CELLS", max_cells)
    rng = np.random.default_rng(1)
    extent = np.array([1.0, 0.7, 0.5])
    radius = 0.06
    it, pos = random_photons(4000, extent, rng)
    flux = it.flux.numpy()
    order = it.order.numpy()
    grid = build_photon_grid(it, 4000, extent, radius, 2, "cpu")
    assert grid.count == int(np.count_nonzero(order >= 2))
    assert int(np.prod(tuple(grid.dims))) <= max_cells
    queries = np.vstack([rng.uniform(-0.05, 1.05, (300, 3)) * extent, pos[:50],
                         pos[:50] + [radius, 0.0, 0.0], extent * 0.5 + [0.0, radius, 0.0]])
    queries = queries.astype(np.float32)
    out = wp.zeros(len(queries), dtype=wp.vec3, device="cpu")
    wp.launch(flux_kernel, dim=len(queries),
              inputs=[grid, wp.array(queries, dtype=wp.vec3, device="cpu"), out], device="cpu")
    # Brute force with the kernel's own test (float32 |x_p - x|^2 <= r^2).
    v = pos[None, :, :] - queries[:, None, :]
    d2 = (v * v).sum(-1, dtype=np.float32)
    inside = (d2 <= np.float32(radius) * np.float32(radius)) & (order >= 2)[None, :]
    expected = (inside[:, :, None] * flux[None]).sum(1) / (4.0 / 3.0 * np.pi * radius ** 3)
    assert inside.sum() > 1000
    np.testing.assert_allclose(out.numpy(), expected, rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize("max_order", [0, 1, 2])
@pytest.mark.parametrize("lights", [[PointLight((0.3, 0.4, 0.2), (2.0, 2.0, 2.0))],
                                    [DirectionalLight((0.2, -1.0, 0.3), (1.0, 1.0, 1.0)),
                                     PointLight((0.3, 0.9, 0.2), (2.0, 2.0, 2.0))]])
def test_emission_order_gives_the_same_photon_map(monkeypatch, lights, max_order):
    """Photons traced in the order of where they leave the lights (the GPU's order) are
    stored exactly as in index order: by rounds with the counts read in between (S_n
    unbounded), and in the one round of a bounded S_n that copies in photon order."""
    volume, m = mapper()
    medium, _ = photon_medium(volume, tf(), volume.mean_spacing(), 0.9, 0.2, "cpu")
    emitters, _ = make_emitters(lights, volume, 3000, "cpu")
    maps = []
    for devices in ((), ("cpu",)):
        monkeypatch.setattr(tracing, "COHERENT_DEVICES", devices)
        order = tracing.emission_order(emitters, 11, 3000, "cpu").numpy()
        assert sorted(order) == list(range(3000))
        assert (devices == ()) == bool(np.all(order == np.arange(3000)))
        pm = PhotonMap(3000, "cpu", seed=11, max_order=max_order,
                       step=0.5 * volume.spacing.min())
        stats = pm.trace(medium, emitters, volume.value_range)
        assert stats["rounds"] >= 1 and stats["total"] == pm.total > 0
        assert stats["interactions_added"] == pm.total
        maps.append(pm.numpy())
    for key in maps[0]:
        np.testing.assert_array_equal(maps[0][key], maps[1][key], err_msg=key)
    if max_order:
        assert maps[0]["order"].max() == max_order
        assert np.all(maps[0]["count"] <= max_order)


@pytest.mark.parametrize("order, padding", [("across", 2.0), ("across", 1.1), ("ray", 2.0)])
@pytest.mark.parametrize("batch", [1 << 27, 700])
def test_per_sample_gather_gives_the_same_segments(monkeypatch, batch, order, padding):
    """Photon-only segments gathered one thread per sample (the GPU's path, in batches, the
    samples of a warp along a ray or across neighbouring rays, the latter falling back to
    the former in batches padded too much) equal the per-segment computation bit for bit,
    and an incremental update through it still equals a full recompute."""
    monkeypatch.setattr(segments, "SAMPLE_ORDER", order)
    monkeypatch.setattr(segments, "ACROSS_MIN_SAMPLES", 0)
    monkeypatch.setattr(segments, "ACROSS_MAX_PADDING", padding)
    calls = []
    across = segments._sample_light_across
    monkeypatch.setattr(segments, "_sample_light_across",
                        lambda *a: calls.append(across(*a)) or calls[-1])
    images = []
    for devices in ((), ("cpu",)):
        monkeypatch.setattr(segments, "SAMPLE_PARALLEL_DEVICES", devices)
        monkeypatch.setattr(segments, "SAMPLES_PER_BATCH", batch)
        volume, m = mapper("photons")
        run(m, volume, tf())
        first = m.segments_numpy()
        stats, image = run(m, volume, EDITS["shadow"])
        assert stats["mode"] == "incremental"
        images.append((first, image, m))
    (seg_a, img_a, m_a), (seg_b, img_b, m_b) = images
    for key in seg_a:
        np.testing.assert_array_equal(seg_a[key], seg_b[key], err_msg=key)
    np.testing.assert_array_equal(img_a.radiance, img_b.radiance)
    np.testing.assert_array_equal(img_a.alpha, img_b.alpha)
    assert_same_map(m_a, m_b)
    # Incremental (per-sample path) == full recompute (per-sample path).
    volume, ref = mapper("photons")
    full_image = run(ref, volume, EDITS["shadow"])[1]
    np.testing.assert_array_equal(img_b.radiance, full_image.radiance)
    # The orders really ran: across batches, and with little padding allowed some fell back.
    if order == "ray":
        assert not calls
    elif padding >= 2.0:
        assert any(c is not None for c in calls)
    else:
        assert any(c is None for c in calls)


def test_colour_edits_read_the_kept_sample_counts(monkeypatch):
    """Per-sample path: a σt edit, then colour edits (whose query reads each segment's
    sample count kept at its computation instead of marching it again) give what a full
    recompute gives, bit for bit; the kept counts are the marched ones."""
    monkeypatch.setattr(segments, "SAMPLE_PARALLEL_DEVICES", ("cpu",))
    volume, m = mapper("photons")
    run(m, volume, tf())
    chain = [EDITS["shadow"], tf(occluder=0.0, other_color=(0.2, 0.4, 1.0)),
             tf(occluder=0.0, other_color=(0.9, 0.1, 0.1), other=0.5)]
    for edit in chain:
        stats, image = run(m, volume, edit)
        assert m.last_render["mode"] == "incremental"
        reference = run(mapper("photons")[1], volume, edit)[1]
        np.testing.assert_array_equal(image.radiance, reference.radiance)
        np.testing.assert_array_equal(image.alpha, reference.alpha)
    assert m.last_render["segments_recomputed"] > 0
    kept = m._seg["samples"].numpy()
    state = m._seg["state"].numpy()
    assert np.all(kept[state == segments.COMPUTED] >= 0)
    # The kept counts equal a fresh march of the same segments.
    n = kept.size
    flags = wp.zeros(n, dtype=wp.int32, device="cpu")
    fresh = wp.zeros(n, dtype=wp.int32, device="cpu")
    _, vp, cam, _, _ = m._view
    wp.launch(segments.segment_query_kernel, dim=n,
              inputs=[m.medium, cam, vp, m._seg["hist"], m._seg["chist"], m._seg["state"],
                      wp.full(n, -1, dtype=wp.int32, device="cpu"), wp.uint64(ALL_BITS),
                      wp.uint64(ALL_BITS), wp.uint64(0), wp.uint64(0), wp.uint64(0), 0,
                      wp.vec3(1.0), m.radius, 1, flags, fresh,
                      wp.zeros(2, dtype=wp.int32, device="cpu")], device="cpu")
    marched = fresh.numpy()
    hit = flags.numpy() == 1
    assert hit.sum() > 0
    np.testing.assert_array_equal(kept[hit], marched[hit])
