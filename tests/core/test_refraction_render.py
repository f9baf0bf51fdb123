"""The ``refraction`` method as a whole: registry, options, limits, environment, soft light."""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.refraction.environment import (
    checker_environment,
    mip_pyramid,
    sample_environment,
)
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.render import REFRACTION_OPTIONS, render_refraction
from vtkillum.core.render import METHODS, render
from vtkillum.core.scene import METHOD_OPTIONS, Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def small_scene(light=(0.2, -0.1, 1.0), opacity=0.3):
    x = np.linspace(-1, 1, 16)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    volume = Volume(np.exp(-(X ** 2 + Y ** 2 + Z ** 2) * 3).astype(np.float32),
                    spacing=(2 / 15,) * 3, origin=(-1, -1, -1))
    camera = Camera((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), view_angle=30.0)
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, opacity]), camera=camera,
                  lights=[DirectionalLight(light, (2.0, 2.0, 2.0))])
    return volume, scene


def test_registered_with_its_scene_section():
    assert METHODS["refraction"].endswith("render_refraction")
    assert METHOD_OPTIONS["refraction"] == REFRACTION_OPTIONS


def test_renders_through_the_registry(device):
    volume, scene = small_scene()
    result = render(volume, scene, "refraction", 16, 12, device)
    assert result.radiance.shape == (12, 16, 3) and result.alpha.shape == (12, 16)
    assert result.radiance.max() > 0 and np.isfinite(result.radiance).all()
    assert result.info["method"] == "refraction" and result.info["planes"] > 10


def test_scene_section_sets_the_defaults(device):
    volume, scene = small_scene()
    optics = RefractiveOptics([0.0, 1.0], [1.0, 1.4])
    fine = render_refraction(volume, scene, 12, 12, device, optics=optics)
    scene.options["refraction"]["sample_distance"] = 2.0
    coarse = render_refraction(volume, scene, 12, 12, device, optics=optics)
    assert coarse.info["planes"] < 0.6 * fine.info["planes"]
    again = render_refraction(volume, scene, 12, 12, device, optics=optics, sample_distance=1.0)
    assert again.info["planes"] == fine.info["planes"]  # keywords override the scene


@pytest.mark.parametrize("lights, match", [
    ([PointLight((0, 0, -3))], "directional"),
    ([DirectionalLight((0, 0, 1)), DirectionalLight((0.1, 0, 1))], "exactly one"),
    ([DirectionalLight((1.0, 0.0, 0.08))], "85 degrees"),   # 85.4° from the view direction
    ([DirectionalLight((0.0, 0.0, -1.0))], "85 degrees"),   # behind the volume, towards us
])
def test_lights_beyond_the_method_are_refused(lights, match):
    volume, scene = small_scene()
    scene.lights = lights
    with pytest.raises(ValueError, match=match):
        render_refraction(volume, scene, 8, 8, "cpu")


def test_light_at_the_limit_is_accepted():
    volume, scene = small_scene(light=(1.0, 0.0, 0.09))  # 84.9°
    assert np.isfinite(render_refraction(volume, scene, 8, 8, "cpu").radiance).all()


@pytest.mark.parametrize("options, match", [
    ({"sample_distance": 0.0}, "sample_distance"),
    ({"sample_distance": -1.0}, "sample_distance"),
    ({"step_size": 0.0}, "step_size"),
    ({"softness": -0.1}, "softness"),
    ({"roughness": 0.0}, "roughness"),
    ({"early_termination": 1.5}, "early_termination"),
    ({"seed": -1}, "seed"),
    ({"intensity_correction": 1}, "intensity_correction"),
    ({"optics": "glass"}, "RefractiveOptics"),
    ({"sample_distance": 1e-7}, "planes"),
    ({"bogus": 1}, "unknown refraction option"),
])
def test_bad_options_are_refused(options, match):
    volume, scene = small_scene()
    with pytest.raises(ValueError, match=match):
        render_refraction(volume, scene, 8, 8, "cpu", **options)


def test_non_positive_refractive_index_is_refused():
    with pytest.raises(ValueError, match="> 0"):
        RefractiveOptics([0.0, 1.0], [1.0, 0.0])


def test_uniform_environment_is_seen_unchanged(device):
    """A transparent, non-refracting volume in front of a uniform map shows the map."""
    volume, scene = small_scene(opacity=0.0)
    env = np.full((8, 16, 3), [0.2, 0.5, 0.9], np.float32)
    result = render_refraction(volume, scene, 10, 10, device, environment=env)
    np.testing.assert_allclose(result.radiance, np.broadcast_to([0.2, 0.5, 0.9], (10, 10, 3)),
                               rtol=1e-5)
    assert np.all(result.alpha == 1.0)


def test_refraction_distorts_the_environment(device):
    """A lens bends the view rays, so the checkered map is seen displaced where the lens is,
    and only there."""
    volume, scene = small_scene(opacity=0.0)
    env = checker_environment(64, squares=32)
    plain = render_refraction(volume, scene, 24, 24, device, environment=env)
    lens = render_refraction(volume, scene, 24, 24, device, environment=env,
                             optics=RefractiveOptics([0.0, 1.0], [1.0, 1.3]))
    diff = np.abs(lens.radiance - plain.radiance).sum(-1)
    assert diff[9:15, 9:15].mean() > 10 * diff[:3, :3].mean() + 1e-3


def test_environment_mip_levels_follow_the_spread():
    """Level 0 returns texels; a spread of a whole map returns its mean (mip-mapping)."""
    env = checker_environment(32, squares=32, contrast=0.5)
    mean = env.reshape(-1, 3).mean(0)
    d = np.array([[0.3, -0.5, -0.8], [-0.6, -0.4, 0.7]])
    sharp = sample_environment(env, d, 0.0, device="cpu")
    blurred = sample_environment(env, d, 2 * np.pi, device="cpu")
    assert np.abs(sharp - mean).max() > 0.05
    np.testing.assert_allclose(blurred, np.broadcast_to(mean, blurred.shape), rtol=1e-4)
    levels = mip_pyramid(env)
    assert levels[-1].shape[:2] == (1, 1)
    np.testing.assert_allclose(levels[-1][0, 0], mean, rtol=1e-4)


def test_background_colour_composited_along_bent_rays(device):
    """With a background colour, the result holds C + (1 - A) M bg and alpha 1."""
    volume, scene = small_scene(opacity=0.0)
    scene.background = np.array([0.1, 0.2, 0.3])
    optics = RefractiveOptics([0.0], [1.0], [0.0, 1.0], [[1, 1, 1], [0.5, 0.5, 0.5]])
    result = render_refraction(volume, scene, 10, 10, device, optics=optics)
    assert np.all(result.alpha == 1.0)
    corner, centre = result.radiance[0, 0], result.radiance[5, 5]
    np.testing.assert_allclose(corner, [0.1, 0.2, 0.3], rtol=1e-3)  # hardly any medium there
    assert np.all(centre < 0.9 * corner)  # seen through the grey medium


def shadow_profile(device, softness):
    """Light behind a half-plane occluder edge (opaque slab for x < 0), across the edge."""
    n = (40, 8, 40)
    x = np.arange(n[0]) - 19.5
    z = np.arange(n[2])
    occ = ((x[:, None] < 0) & (np.abs(z[None, :] - 8) < 1.5)).astype(np.float32)
    volume = Volume(np.repeat(occ[:, None, :], n[1], axis=1))
    camera = Camera((19.5, 3.5, -50.0), (19.5, 3.5, 0.0), (0.0, 1.0, 0.0),
                    parallel_projection=True, parallel_scale=20.0)
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.999]), camera=camera,
                  lights=[DirectionalLight((0.0, 0.0, 1.0), (1, 1, 1))])
    r = render_refraction(volume, scene, 40, 40, device, softness=softness, record_light=[38])
    light = r.info["light_planes"][38]["light"][..., 0]
    return light[light.shape[0] // 2]


def test_softness_widens_the_penumbra(device):
    """A hard light leaves a sharp shadow edge; soft light (incremental elliptical blur)
    spreads it over several texels, the wider the softer."""
    def width(profile):
        return int(np.sum((profile > 0.1) & (profile < 0.9)))

    hard = shadow_profile(device, 0.0)
    soft = shadow_profile(device, 0.3)
    softer = shadow_profile(device, 0.8)
    assert hard.min() < 0.01 and hard.max() > 0.99
    assert width(hard) <= 2 < width(soft) < width(softer)
    assert soft.sum() == pytest.approx(hard.sum(), rel=0.05)  # blurred, not lost


def oblique_scene():
    """:func:`small_scene` seen from above and aside: the planes cut the cube in polygons
    much smaller than its sheared shadow, so light culling has texels to skip."""
    volume, scene = small_scene(opacity=0.3)
    scene.camera = Camera((2.5, 1.8, -4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), view_angle=35.0)
    return volume, scene


def test_plane_rects_hold_the_cross_sections():
    """Every point of the box on a plane lies inside that plane's rectangle, ``margin`` texels
    from its edge (unless the grid ends first); the rectangles skip a good part of the grid."""
    from vtkillum.core.refraction.planes import camera_corners, plane_rects, sweep_geometry

    volume, scene = oblique_scene()
    camera = scene.resolved_camera(volume)
    g = sweep_geometry(volume, camera, 40, 40, scene.lights[0].direction, 0.1)
    R, cam, _ = camera_corners(volume, camera)
    rects = plane_rects(g, 3)
    rng = np.random.default_rng(1)
    pts = (rng.random((20000, 3)) * volume.extent - cam) @ R.T  # camera frame
    j = np.round((pts[:, 2] - g.z0) / g.dz).astype(int)
    keep = (j >= 0) & (j < g.planes) & (np.abs(pts[:, 2] - g.z0 - j * g.dz) < 0.05 * g.dz)
    tex = (pts[keep, :2] - g.grid_origin - j[keep, None] * g.shift) / g.texel
    r = rects[j[keep]]
    n = np.array([g.nx, g.ny])
    assert keep.sum() > 500
    assert np.all((tex >= r[:, :2] + 3 - 1e-6) | (r[:, :2] == 0))
    assert np.all((tex <= r[:, 2:] - 3 - 1 + 1e-6) | (r[:, 2:] == n))
    area = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
    assert area.mean() < 0.8 * g.texels and np.all(rects[:, 2:] >= rects[:, :2])


@pytest.mark.parametrize("eta, tol", [((1.0, 1.0), 1e-6), ((1.0, 1.4), 1e-6)])
def test_light_culling_leaves_the_image(device, eta, tol):
    """Propagating the light only over the planes' cross-sections with the box gives the
    image of the whole sheared grid (straight light and gentle refraction), with fewer
    texels."""
    volume, scene = oblique_scene()
    optics = RefractiveOptics([0.0, 1.0], list(eta))
    whole = render_refraction(volume, scene, 40, 40, device, optics=optics, softness=0.2,
                              cull_light=False)
    culled = render_refraction(volume, scene, 40, 40, device, optics=optics, softness=0.2)
    assert culled.info["light_texels"] < 0.8 * whole.info["light_texels"]
    np.testing.assert_allclose(culled.radiance, whole.radiance, atol=tol * whole.radiance.max())


def test_light_culling_changes_strong_caustics_less_than_the_blur_seed(device):
    """Behind strong refraction the light field is chaotic: the light just outside the culled
    rectangles reaches the inside through the blur and the Newton step. Culling then changes
    the image, but far less than the blur's random rotations (another seed) do."""
    volume, scene = oblique_scene()
    optics = RefractiveOptics([0.0, 0.3, 1.0], [1.0, 1.6, 1.3])
    kw = dict(optics=optics, softness=0.2)
    whole = render_refraction(volume, scene, 40, 40, device, cull_light=False, **kw).radiance
    culled = render_refraction(volume, scene, 40, 40, device, **kw).radiance
    seed = render_refraction(volume, scene, 40, 40, device, cull_light=False, seed=1, **kw).radiance
    assert np.abs(culled - whole).mean() < 0.25 * np.abs(seed - whole).mean()


def test_padded_plane_count_renders_the_same(device, monkeypatch):
    """A graph runs a whole number of plane buckets (the planes past the frame's return at
    once), so that a moving camera replays it: the padded sweep gives the same image. On
    the CPU the capture fails and the padded launches run directly, the path tested here."""
    from vtkillum.core.refraction import render as module
    from vtkillum.core.refraction.render import RefractionRenderer, graph_planes

    assert graph_planes(1) == module.PLANE_BUCKET and graph_planes(module.PLANE_BUCKET) == 32
    assert graph_planes(module.PLANE_BUCKET + 1) == 2 * module.PLANE_BUCKET
    volume, scene = oblique_scene()
    optics = RefractiveOptics([0.0, 1.0], [1.0, 1.3])
    plain = render_refraction(volume, scene, 24, 20, device, optics=optics, softness=0.2,
                              graph=False)
    assert plain.info["planes"] % module.PLANE_BUCKET != 0
    renderer = RefractionRenderer(device)
    if device == "cpu":
        monkeypatch.setattr(renderer, "_use_graph", lambda opts: True)
    padded = renderer.render(volume, scene, 24, 20, optics=optics, softness=0.2)
    assert padded.info["launches"] > plain.info["launches"]
    np.testing.assert_allclose(padded.radiance, plain.radiance, atol=1e-6)
    np.testing.assert_allclose(padded.alpha, plain.alpha, atol=1e-6)


def test_moving_camera_replays_the_captured_graph(device):
    """On CUDA a camera that moves (changing the plane count and the light rectangles a
    little) replays the graph captured for the first frame instead of capturing another."""
    if device == "cpu":
        pytest.skip("launch graphs need a CUDA device")
    from vtkillum.core.refraction.render import RefractionRenderer

    volume, scene = oblique_scene()
    optics = RefractiveOptics([0.0, 1.0], [1.0, 1.3])
    renderer = RefractionRenderer(device)
    planes = []
    for degrees in (0, 5, 10, 15):  # 26, 26, 27, 27 planes; 560-740 light texels
        a = np.radians(degrees) + 0.55
        scene.camera = Camera((5.0 * np.sin(a), 1.8, -5.0 * np.cos(a)), (0.0, 0.0, 0.0),
                              (0.0, 1.0, 0.0), view_angle=35.0)
        r = renderer.render(volume, scene, 24, 20, optics=optics, softness=0.2)
        assert r.info["graph"] and r.info["graph_error"] is None
        planes.append(r.info["planes"])
    assert len(set(planes)) > 1  # the plane count did change
    assert len(renderer._graphs) == 1
