"""The ``"many-lights"`` render method: registration, the single term, options, bad input."""

import numpy as np
import pytest

from vtkillum.core.many_lights.render import DEFAULTS, ManyLightsRenderer, parse_options
from vtkillum.core.render import METHODS, render
from vtkillum.core.scene import METHOD_OPTIONS, Scene
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, cloud

SIZE = 16
FAST = {"count": 24, "avsm_resolution": 8, "sets": 1}


@pytest.fixture(scope="module")
def scene():
    volume = cloud(SIZE)
    return volume, _medium_scene(volume, 6.0, 0.9, 0.3, [_side_light()])


def test_registered_with_its_scene_section(scene):
    volume, sc = scene
    assert METHODS["many-lights"] == "vtkillum.core.many_lights.render:render_many_lights"
    assert METHOD_OPTIONS["many_lights"] == DEFAULTS
    data = sc.to_dict()
    data["many_lights"] = {"count": 24, "avsm_resolution": 8, "seed": 4}
    loaded = Scene.from_dict(data)
    result = render(volume, loaded, "many-lights", 12, 10, "cpu")
    assert result.radiance.shape == (10, 12, 3) and result.alpha.shape == (10, 12)
    assert result.info["vls"] >= 24 and np.isfinite(result.radiance).all()
    assert result.info["multiple"].sum() > 0
    with pytest.raises(ValueError, match="many_lights: unknown field"):
        Scene.from_dict({**sc.to_dict(), "many_lights": {"vls": 10}})


def test_single_term_is_the_ray_casters(scene):
    """Without jitter the single-scattering term is ``single``'s image, bit for bit."""
    volume, sc = scene
    ours = render(volume, sc, "many-lights", SIZE, SIZE, "cpu", jitter=False, **FAST)
    single = render(volume, sc, "single", SIZE, SIZE, "cpu", jitter=False)
    np.testing.assert_allclose(ours.info["single"], single.radiance, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ours.alpha, single.alpha, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ours.radiance, ours.info["single"] + ours.info["multiple"],
                               rtol=1e-6)


def test_same_seed_same_image_other_seed_other_image(scene):
    volume, sc = scene
    a = render(volume, sc, "many-lights", SIZE, SIZE, "cpu", seed=3, **FAST)
    b = render(volume, sc, "many-lights", SIZE, SIZE, "cpu", seed=3, **FAST)
    c = render(volume, sc, "many-lights", SIZE, SIZE, "cpu", seed=4, **FAST)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    assert not np.array_equal(a.info["multiple"], c.info["multiple"])


def test_sets_accumulate_and_camera_reset_keeps_the_lights(scene):
    volume, sc = scene
    renderer = ManyLightsRenderer(volume, sc, SIZE, SIZE, "cpu", **FAST)
    first = renderer.run(1).result()
    positions = renderer.state.vls.position.copy()
    renderer.run(2)
    assert renderer.result().info["sets"] == 3
    camera = sc.resolved_camera(volume)
    camera.position = camera.position * 1.1
    renderer.reset(camera)
    assert renderer.passes == 0
    np.testing.assert_array_equal(renderer.state.vls.position, positions)
    moved = renderer.run(1).result()
    assert not np.allclose(moved.radiance, first.radiance)


def test_albedo_zero_leaves_absorption_only(scene):
    """No scattering: no light from the VLs or the lights, no NaN, the same alpha."""
    volume, _ = scene
    dark = _medium_scene(volume, 6.0, 0.0, 0.3, [_side_light()])
    result = render(volume, dark, "many-lights", SIZE, SIZE, "cpu", jitter=False, **FAST)
    emission = render(volume, dark, "single", SIZE, SIZE, "cpu", jitter=False)
    assert np.isfinite(result.radiance).all() and np.isfinite(result.alpha).all()
    assert np.all(result.radiance == 0)
    np.testing.assert_allclose(result.alpha, emission.alpha, rtol=1e-6)
    assert result.alpha.max() > 0.9


def test_black_lights_give_no_virtual_lights(scene):
    volume, _ = scene
    black = _medium_scene(volume, 6.0, 0.9, 0.3, [_side_light(0.0)])
    result = render(volume, black, "many-lights", SIZE, SIZE, "cpu", **FAST)
    assert np.all(result.radiance == 0) and result.info["vls"] == 0


@pytest.mark.parametrize("bad, match", [
    ({"count": 0}, "count must be a positive integer"),
    ({"count": 2.5}, "count must be a positive integer"),
    ({"vsl_radius": -1.0}, "vsl_radius must be a number of voxels >= 0"),
    ({"vsl_neighbours": 0}, "vsl_neighbours must be a positive integer"),
    ({"sets": -1}, "sets must be an integer >= 0"),
    ({"time_budget": -1.0}, "time_budget must be a number >= 0"),
    ({"virtual_lights": "disc"}, "virtual_lights must be one of"),
    ({"avsm_nodes": 1}, "avsm_nodes"),
    ({"avsm_nodes": 17}, "avsm_nodes"),
    ({"avsm_resolution": 1}, "avsm_resolution"),
    ({"transmittance": "exact"}, "transmittance must be one of"),
    ({"update_fraction": 0.0}, "update_fraction"),
    ({"scale_range": [2.0, 1.0]}, "scale_range"),
    ({"density_scale": 0.0}, "density_scale"),
    ({"radius_exponent": 1.0}, "radius_exponent"),
    ({"view_samples": 0}, "view_samples"),
    ({"lights": 3}, "unknown many-lights option"),
])
def test_bad_options_are_refused(scene, bad, match):
    volume, sc = scene
    with pytest.raises(ValueError, match=match):
        parse_options(bad, volume, sc)


@pytest.mark.parametrize("g", [0.0, 0.4])
def test_avsm_kernel_equals_the_generic_vl_sum(device, g):
    """The AVSM-specialised VL sum (tiles of pixels, counting lookups, no cone sample in an
    isotropic medium) gives the generic ``vl_kernel``'s image, over two bands of rows that
    are not whole tiles."""
    import warp as wp

    from vtkillum.core.many_lights import gather
    from vtkillum.core.many_lights.cache import ManyLightsState
    from vtkillum.core.warp_common import make_camera

    volume = cloud(SIZE)
    sc = _medium_scene(volume, 6.0, 0.9, g, [_side_light()])
    state = ManyLightsState(volume, sc, parse_options({**FAST, "seed": 2}, volume, sc), device)
    o = state.opts
    width, height = 100, 61  # on the CPU, bands of 40 and 21 rows
    cam = make_camera(sc.resolved_camera(volume), volume, width, height)
    prm = gather.gather_params(o["step_size"], True, 5, o["early_termination"], 8, "avsm",
                               o["vl_step"], state.scale, False, True)
    vls, maps = state.virtual_lights(), state.maps()
    images = [wp.zeros((height, width), dtype=wp.vec3, device=device) for _ in range(2)]
    alpha = wp.zeros((height, width), dtype=wp.float32, device=device)
    samples = wp.zeros((height, width), dtype=wp.int32, device=device)
    gather.gather_device(state.medium, cam, state.lights, vls, maps, prm, images[0], images[1],
                         alpha, samples, device)
    tiled = images[1].numpy()

    # The generic kernel over the whole image in one band.
    position = wp.zeros((8, height, width), dtype=wp.vec3, device=device)
    weight = wp.zeros((8, height, width), dtype=wp.vec3, device=device)
    generic = wp.zeros((height, width), dtype=wp.vec3, device=device)
    wp.launch(gather.view_kernel, dim=(height, width),
              inputs=[state.medium, cam, state.lights, vls.count, prm, 0, images[0], alpha,
                      samples, position, weight], device=device)
    wp.launch(gather.vl_kernel, dim=(8, height, width),
              inputs=[state.medium, cam, vls, maps, prm, 0, position, weight], device=device)
    wp.launch(gather.compose_kernel, dim=(height, width), inputs=[0, 8, weight, generic],
              device=device)
    generic = generic.numpy()
    band = gather.BAND_PIXELS["cpu"] // width
    assert (generic[:band].sum(-1) > 0).mean() > 0.1 and (generic[band:].sum(-1) > 0).mean() > 0.1
    np.testing.assert_allclose(tiled, generic, rtol=2e-5, atol=1e-7 * generic.max())


def test_alpha_only_march_leaps_empty_blocks_to_the_same_positions(device):
    """Without the single term the view rays leap over empty blocks; alpha, the VL
    positions and so the multiple-scattering image equal those of the march that computes
    the single term (no jitter: the two then draw the same random numbers)."""
    import warp as wp

    from vtkillum.core.many_lights import gather
    from vtkillum.core.many_lights.cache import ManyLightsState
    from vtkillum.core.warp_common import make_camera
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume
    from vtkillum.data.procedural import ct_phantom, default_scene

    # A dense cube one cell inside the block faces: the first sample after a leap counts.
    values = np.zeros((41, 41, 41), np.float32)
    values[9:32, 9:32, 9:32] = 1.0  # blocks of 8 cells: the outer ones are empty
    sc = default_scene("ct", ct_phantom(32))
    volume = Volume(values, (0.025,) * 3, (0.0, 0.0, 0.0))
    sc.transfer_function = TransferFunction([0.0, 1.0], [0.0, 0.9])
    sc.camera = None
    state = ManyLightsState(volume, sc, parse_options({**FAST, "seed": 3}, volume, sc), device)
    assert (state.medium.occupied.numpy() == 0).mean() > 0.2  # there is air to leap over
    o = state.opts
    cam = make_camera(sc.resolved_camera(volume), volume, 40, 40)
    out = []
    for single in (True, False):
        prm = gather.gather_params(o["step_size"], False, 5, o["early_termination"], 8, "avsm",
                                   o["vl_step"], state.scale, single, True)
        images = [wp.zeros((40, 40), dtype=wp.vec3, device=device) for _ in range(2)]
        alpha = wp.zeros((40, 40), dtype=wp.float32, device=device)
        samples = wp.zeros((40, 40), dtype=wp.int32, device=device)
        gather.gather_device(state.medium, cam, state.lights, state.virtual_lights(),
                             state.maps(), prm, images[0], images[1], alpha, samples, device)
        out.append((images[1].numpy(), alpha.numpy(), samples.numpy()))
    (ms_a, alpha_a, n_a), (ms_b, alpha_b, n_b) = out
    np.testing.assert_array_equal(alpha_b, alpha_a)
    np.testing.assert_array_equal(ms_b, ms_a)
    assert ms_a.sum() > 0 and alpha_a.max() > 0.1
    assert n_b.sum() < n_a.sum()  # fewer samples taken
