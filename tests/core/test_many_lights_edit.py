"""Editing with virtual lights (paper sections 4–5): immediate contribution updates (eq. 6),
progressive regeneration, the global density scale (eqs. 7–8), colour/albedo/g edits.
"""

import copy

import numpy as np
import pytest
import warp as wp

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.many_lights.contribution import segment_depths
from vtkillum.core.many_lights.render import ManyLightsRenderer
from vtkillum.core.warp_common import make_medium
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, cloud

SIZE = 16
OPTS = {"count": 48, "avsm_resolution": 8, "jitter": False, "seed": 5, "update_fraction": 0.3}


@pytest.fixture(scope="module")
def volume():
    return cloud(SIZE)


def scene_with(volume, diameter=6.0, albedo=0.9, g=0.3, lights=None, colour=(1.0, 1.0, 1.0)):
    return _medium_scene(volume, diameter, albedo, g, lights or [_side_light()], colour)


def regenerate(renderer, limit=200):
    frames = 0
    while renderer.state.stale:
        stats = renderer.frame()
        frames += 1
        assert frames < limit
    return frames, stats


def assert_same_set(a, b):
    va, vb = a.state.vls, b.state.vls
    np.testing.assert_array_equal(va.path_count, vb.path_count)
    np.testing.assert_array_equal(va.position, vb.position)
    np.testing.assert_array_equal(va.pdf, vb.pdf)
    np.testing.assert_allclose(va.power(), vb.power(), rtol=1e-6, atol=1e-12)


def test_transfer_function_edit_then_regeneration_equals_fresh(volume):
    renderer = ManyLightsRenderer(volume, scene_with(volume, 6.0), SIZE, SIZE, "cpu", **OPTS)
    before = renderer.run(1).result().radiance
    vls = renderer.state.vls
    positions, slots, builds = vls.position.copy(), vls.slot.copy(), renderer.state.pool.builds
    edited = scene_with(volume, 14.0)
    edit = renderer.update(edited)
    # immediate: contributions re-evaluated along the stored paths, nothing moved or rebuilt
    assert "sigma_t" in edit["edits"] and edit["stale_paths"] == vls.n_paths
    np.testing.assert_array_equal(vls.position, positions)
    np.testing.assert_array_equal(vls.slot, slots)
    assert renderer.state.pool.builds == builds
    immediate = renderer.run(1).result().radiance
    assert not np.allclose(immediate, before)
    fresh = ManyLightsRenderer(volume, edited, SIZE, SIZE, "cpu", **OPTS)
    fresh_image = fresh.run(1).result().radiance
    assert not np.allclose(immediate, fresh_image, rtol=1e-3)  # Fig. 6, centre column
    # progressive: a fraction of the paths per frame, oldest first
    paths_at_edit = vls.paths_at_reset
    stats = renderer.frame()
    assert stats["paths"] <= np.ceil(0.3 * paths_at_edit) and renderer.state.stale
    assert vls.frontier == stats["paths"]
    frames, _ = regenerate(renderer)
    assert 1 <= frames <= 4
    assert_same_set(renderer, fresh)
    np.testing.assert_allclose(renderer.result().radiance, fresh_image, rtol=1e-5, atol=1e-9)


def test_density_scale_without_range_redistributes(volume):
    renderer = ManyLightsRenderer(volume, scene_with(volume), SIZE, SIZE, "cpu", **OPTS)
    renderer.run(1)
    edit = renderer.set_density_scale(2.5)
    assert edit["edits"] == ["density_scale"] and edit["stale_paths"] > 0
    regenerate(renderer)
    fresh = ManyLightsRenderer(volume, scene_with(volume), SIZE, SIZE, "cpu",
                               density_scale=2.5, **OPTS)
    assert_same_set(renderer, fresh)
    np.testing.assert_allclose(renderer.result().radiance, fresh.run(1).result().radiance,
                               rtol=1e-5, atol=1e-9)


def test_density_scale_with_mean_transmittance_needs_no_redistribution(volume):
    """Eq. 8: positions do not depend on S, so a scale edit is exactly a fresh render."""
    opts = {**OPTS, "scale_range": [0.4, 3.0]}
    renderer = ManyLightsRenderer(volume, scene_with(volume), SIZE, SIZE, "cpu", **opts)
    renderer.run(1)
    positions, builds = renderer.state.vls.position.copy(), renderer.state.pool.builds
    edit = renderer.set_density_scale(2.2)
    assert edit["edits"] == ["density_scale"] and edit["stale_paths"] == 0
    assert not renderer.state.stale
    np.testing.assert_array_equal(renderer.state.vls.position, positions)
    assert renderer.state.pool.builds == builds  # AVSMs are read as T^S
    fresh = ManyLightsRenderer(volume, scene_with(volume), SIZE, SIZE, "cpu",
                               density_scale=2.2, **opts)
    assert_same_set(renderer, fresh)
    np.testing.assert_allclose(renderer.run(1).result().radiance,
                               fresh.run(1).result().radiance, rtol=1e-5, atol=1e-9)


def test_scaled_transmittance_equals_ray_marching_with_scaled_sigma(volume):
    """``T_new = T_old^(S_new / S_old)`` (eq. 7) for the stored segments, no marching."""
    scene = scene_with(volume)
    renderer = ManyLightsRenderer(volume, scene, SIZE, SIZE, "cpu",
                                  **{**OPTS, "scale_range": [0.5, 2.0]})
    renderer.set_density_scale(1.7)
    state, vls = renderer.state, renderer.state.vls
    # The renderer's own volume and scene: it works in canonical units (vtkillum.core.units).
    volume, scene = renderer.volume, renderer.scene
    scaled = make_medium(volume, scene.resolved_transfer_function(volume),
                         scene.resolved_unit_distance(volume) / 1.7, scene.albedo,
                         scene.anisotropy, "cpu")
    tau = wp.zeros(vls.n_vls, dtype=wp.float32, device="cpu")
    d = vls.dev
    segment_depths(scaled, state.lights, d["position"], d["vertex"], d["light_of"], tau,
                   state.opts["step_size"], "cpu")
    np.testing.assert_allclose(np.exp(-1.7 * vls.tau), np.exp(-tau.numpy()), rtol=2e-5,
                               atol=1e-7)


def test_colour_albedo_and_g_edits_update_contributions_only(volume):
    base = scene_with(volume, albedo=0.8, g=0.2)
    renderer = ManyLightsRenderer(volume, base, SIZE, SIZE, "cpu", **OPTS)
    vls = renderer.state.vls
    power = vls.power()
    positions = vls.position.copy()
    vertex = vls.vl_vertex
    assert vertex.max() >= 2
    # albedo: vertex k carries k + 1 scattering coefficients
    edit = renderer.update(scene_with(volume, albedo=0.6, g=0.2))
    assert edit["edits"] == ["albedo"] and edit["stale_paths"] == 0
    np.testing.assert_allclose(vls.power(), power * (0.75 ** (vertex + 1))[:, None], rtol=2e-5)
    # colour (the transfer function's colours, sigma_t unchanged): per channel the same law
    edit = renderer.update(scene_with(volume, albedo=0.6, g=0.2, colour=(1.0, 0.5, 0.25)))
    assert edit["edits"] == ["color"] and edit["stale_paths"] == 0
    factor = 0.75 ** (vertex + 1)
    expected = power * np.stack([factor, factor * 0.5 ** (vertex + 1),
                                 factor * 0.25 ** (vertex + 1)], -1)
    np.testing.assert_allclose(vls.power(), expected, rtol=2e-5, atol=1e-30)
    # g: the first vertices have no phase function in their weight; later ones change
    edit = renderer.update(scene_with(volume, albedo=0.6, g=-0.4, colour=(1.0, 0.5, 0.25)))
    assert edit["edits"] == ["anisotropy"] and edit["stale_paths"] == 0
    after = vls.power()
    np.testing.assert_allclose(after[vertex == 0], expected[vertex == 0], rtol=2e-5)
    assert not np.allclose(after[vertex >= 1], expected[vertex >= 1], rtol=1e-3)
    # light colour: linear
    light = _side_light()
    edit = renderer.update(scene_with(volume, albedo=0.6, g=-0.4, colour=(1.0, 0.5, 0.25),
                                      lights=[DirectionalLight(light.direction,
                                                               2 * light.irradiance)]))
    assert edit["edits"] == ["light-color"] and edit["stale_paths"] == 0
    np.testing.assert_allclose(vls.power(), 2 * after, rtol=2e-5)
    np.testing.assert_array_equal(vls.position, positions)
    assert not renderer.state.stale


def test_reverting_an_edit_restores_the_contributions(volume):
    renderer = ManyLightsRenderer(volume, scene_with(volume), SIZE, SIZE, "cpu", **OPTS)
    power = renderer.state.vls.power()
    renderer.update(scene_with(volume, 12.0))
    assert not np.allclose(renderer.state.vls.power(), power)
    renderer.update(scene_with(volume, 6.0))
    np.testing.assert_allclose(renderer.state.vls.power(), power, rtol=1e-5, atol=1e-30)
    assert renderer.update(scene_with(volume, 6.0))["edits"] == []


def test_light_move_keeps_the_maps_of_the_other_lights_paths(volume):
    lights = [_side_light(), PointLight((-1.5, 1.2, 0.8), (20.0, 20.0, 20.0))]
    moved = [lights[0], PointLight((1.5, 1.4, 0.5), (20.0, 20.0, 20.0))]
    renderer = ManyLightsRenderer(volume, scene_with(volume, lights=lights), SIZE, SIZE, "cpu",
                                  **{**OPTS, "update_fraction": 1.0})
    vls = renderer.state.vls
    assert set(vls.path_light) == {0, 1}
    positions = vls.position.copy()
    power = vls.power()
    edit = renderer.update(scene_with(volume, lights=moved))
    assert edit["edits"] == ["light-moved"] and edit["stale_paths"] == vls.n_paths
    np.testing.assert_array_equal(vls.position, positions)
    # only the paths of the moved light change their contributions
    of_moved = vls.path_light[vls.vl_path] == 1
    np.testing.assert_allclose(vls.power()[~of_moved], power[~of_moved], rtol=1e-6)
    assert not np.allclose(vls.power()[of_moved], power[of_moved])
    _, stats = regenerate(renderer)
    assert stats["reused"] > 0 and stats["avsms"] + stats["reused"] == stats["vls"]
    fresh = ManyLightsRenderer(volume, scene_with(volume, lights=moved), SIZE, SIZE, "cpu",
                               **{**OPTS, "update_fraction": 1.0})
    assert_same_set(renderer, fresh)
    np.testing.assert_allclose(renderer.result().radiance, fresh.run(1).result().radiance,
                               rtol=1e-5, atol=1e-9)


def test_update_budget_limits_the_maps_built_per_frame(volume):
    renderer = ManyLightsRenderer(volume, scene_with(volume), SIZE, SIZE, "cpu",
                                  **{**OPTS, "update_budget": 6, "update_fraction": 1.0})
    renderer.update(scene_with(volume, 9.0))
    built = []
    while renderer.state.stale:
        stats = renderer.frame()
        built.append(stats["avsms"])
        longest = renderer.state.vls.path_count.max()
        assert stats["avsms"] <= max(6, longest)
    assert len(built) >= 3


def test_adding_a_light_regenerates_at_once(volume):
    scene = scene_with(volume)
    renderer = ManyLightsRenderer(volume, scene, SIZE, SIZE, "cpu", **OPTS)
    more = copy.copy(scene)
    more.lights = [*scene.lights, PointLight((0.0, 1.5, 0.0), (5.0, 5.0, 5.0))]
    edit = renderer.update(more)
    assert edit["edits"] == ["lights-added-or-removed"] and edit["stale_paths"] == 0
    fresh = ManyLightsRenderer(volume, more, SIZE, SIZE, "cpu", **OPTS)
    assert_same_set(renderer, fresh)


def test_edits_names_what_update_would_do_without_doing_it(volume):
    scene = scene_with(volume)
    renderer = ManyLightsRenderer(volume, scene, SIZE, SIZE, "cpu", **OPTS)
    state = renderer.state
    power = state.vls.power()

    def edits(scene, **kwargs):  # the state works in the renderer's canonical units
        return state.edits(renderer.units.scene(scene), **kwargs)

    assert edits(scene) == []
    assert edits(scene_with(volume, albedo=0.6, colour=(1.0, 0.5, 0.5))) == ["color", "albedo"]
    assert edits(scene_with(volume, 12.0)) == ["sigma_t"]
    assert edits(scene, density_scale=2.0) == ["density_scale"]
    np.testing.assert_array_equal(state.vls.power(), power)
    assert not state.stale
    assert renderer.update(scene_with(volume, 12.0))["edits"] == ["sigma_t"]
