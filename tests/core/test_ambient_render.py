"""The "ambient-scattering" render method: conventions, caching (Table 1), path-tracer comparison."""

import numpy as np
import pytest

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import METHODS, render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.units import WorldUnits
from vtkillum.core.volume import Volume


def hg(cos_theta, g):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos_theta) ** 1.5)


def ball(n=32, sigma=8.0, u=0.1):
    """A dense ball (radius 0.8) in [-1, 1]^3 whose centre has extinction ``sigma``."""
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    R = np.sqrt(X**2 + Y**2 + Z**2)
    vol = Volume(np.clip((0.8 - R) / 0.1, 0, 1).astype(np.float32), spacing=(2 / (n - 1),) * 3,
                 origin=(-1, -1, -1))
    tf = TransferFunction([0, 1], [0, 1 - np.exp(-sigma * u)])
    return vol, tf, u


def ball_scene(tf, u, g=0.0, **kw):
    cam = Camera(position=(0, 0, 5), focal_point=(0, 0, 0), view_up=(0, 1, 0), view_angle=30)
    return Scene(transfer_function=tf, opacity_unit_distance=u, albedo=0.9, anisotropy=g,
                 lights=[DirectionalLight((1, -0.3, -0.5), (1, 1, 1))], camera=cam, **kw)


def test_registered():
    assert METHODS["ambient-scattering"].endswith(":render_ambient_scattering")


def test_optically_thin_box_is_single_scattering(device):
    # A thin homogeneous box seen along -z by a parallel camera, lit at 60 degrees from the
    # view direction: L = albedo * color * sigma * length * E * p(cos theta) (T ~ 1).
    n, sigma, g = 16, 1e-3, 0.5
    vol = Volume(np.ones((n, n, n), np.float32))  # extent 15 world units
    alpha = 1 - np.exp(-sigma)
    tf = TransferFunction([0, 1], [alpha, alpha], [[1, 0.5, 0.25]] * 2)
    light_dir = np.array([np.sin(np.radians(60)), 0.0, np.cos(np.radians(60))])
    # camera looks along -z, so the direction to the camera is +z; theta is between +z
    # and the light's travel direction
    cam = Camera(position=(7.5, 7.5, 40), focal_point=(7.5, 7.5, 7.5), parallel_projection=True,
                 parallel_scale=3.0)
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, albedo=0.9, anisotropy=g,
                  lights=[DirectionalLight(light_dir, (2.0, 1.0, 4.0))], camera=cam)
    res = render(vol, scene, "ambient-scattering", 8, 8, device=device, radius=1.0, jitter=False,
                 cache=AmbientScatteringCache(device))
    ref = 0.9 * np.array([1, 0.5, 0.25]) * sigma * 15.0 * np.array([2.0, 1.0, 4.0]) \
        * hg(np.cos(np.radians(60)), g)
    np.testing.assert_allclose(res.radiance[4, 4], ref, rtol=0.03)
    assert res.alpha[4, 4] == pytest.approx(1 - np.exp(-sigma * 15), rel=1e-3)


def test_alpha_is_the_primary_ray_opacity(device):
    vol, tf, u = ball(20)
    scene = ball_scene(tf, u)
    amb = render(vol, scene, "ambient-scattering", 16, 16, device=device, early_termination=1.0,
                 cache=AmbientScatteringCache(device, data_textures=False))  # exact sampling
    emi = render(vol, scene, "emission", 16, 16, device=device, early_termination=1.0,
                 textures=False)  # exact sampling too
    np.testing.assert_allclose(amb.alpha, emi.alpha, atol=1e-5)


def test_empty_volume_is_black(device):
    vol = Volume(np.zeros((8, 8, 8), np.float32))
    tf = TransferFunction([0, 1], [0, 0.5])
    res = render(vol, Scene(transfer_function=tf), "ambient-scattering", 8, 8, device=device,
                 cache=AmbientScatteringCache(device))
    assert np.all(res.radiance == 0) and np.all(res.alpha == 0)


def test_table1_invalidation(device):
    vol, tf, u = ball(16)
    cache = AmbientScatteringCache(device)
    scene = ball_scene(tf, u)

    def go(scene, **kw):
        return render(vol, scene, "ambient-scattering", 8, 8, device=device, cache=cache,
                      **kw).info["recomputed"]

    assert go(scene) == ["sat", "extinction", "radiance"]
    scene.camera = Camera(position=(0, 4, 3), focal_point=(0, 0, 0))
    assert go(scene) == []  # camera: nothing
    scene.anisotropy = 0.5
    assert go(scene) == ["radiance"]  # phase function: radiance cache only
    scene.lights = [PointLight((2, 2, 2), (5, 5, 5))]
    assert go(scene) == ["radiance"]  # light: radiance cache only
    scene.lights = [PointLight((2, 2, 2), (5, 5, 5), radius=0.5)]
    assert go(scene) == ["radiance"]  # the light's size (held irradiance within it) too
    # the cache works in render()'s canonical units (vtkillum.core.units): lengths / L
    length = WorldUnits.for_volume(vol).length
    assert cache._lights.radius.numpy()[0] * length == pytest.approx(0.5)
    scene.transfer_function = TransferFunction([0, 1], [0, 0.3])
    assert go(scene) == ["sat", "extinction", "radiance"]  # TF: everything
    assert go(scene, radius=6.0) == ["extinction", "radiance"]  # radius: SAT kept
    assert cache.stats == {"sat": 2, "extinction": 3, "radiance": 6}


def test_cached_result_equals_fresh_result(device):
    vol, tf, u = ball(16)
    cache = AmbientScatteringCache(device)
    scene = ball_scene(tf, u, g=0.3)
    first = render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache)
    scene.anisotropy = -0.4
    scene.transfer_function = TransferFunction([0, 1], [0, 0.2])
    render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache)
    scene.anisotropy = 0.3
    scene.transfer_function = tf
    again = render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache)
    fresh = render(vol, scene, "ambient-scattering", 12, 12, device=device,
                   cache=AmbientScatteringCache(device))
    np.testing.assert_allclose(again.radiance, fresh.radiance, rtol=1e-6)
    np.testing.assert_allclose(first.radiance, fresh.radiance, rtol=1e-6)
    assert first.radiance.max() > 0


def test_anisotropy_changes_the_picture(device):
    # Backlit ball: forward scattering sends more light towards the camera.
    vol, tf, u = ball(20, sigma=3.0)
    cam = Camera(position=(0, 0, 5), focal_point=(0, 0, 0))
    cache = AmbientScatteringCache(device)
    out = {}
    for g in (-0.6, 0.6):
        scene = Scene(transfer_function=tf, opacity_unit_distance=u, anisotropy=g,
                      lights=[DirectionalLight((0.2, 0, 1.0))], camera=cam)
        out[g] = render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache)
    assert out[0.6].radiance.sum() > 1.5 * out[-0.6].radiance.sum()


def test_optional_specular_and_ambient_occlusion(device):
    vol, tf, u = ball(16)
    scene = ball_scene(tf, u)
    cache = AmbientScatteringCache(device)
    base = render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache)
    spec = render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache,
                  specular=2.0)
    ao = render(vol, scene, "ambient-scattering", 12, 12, device=device, cache=cache,
                ambient_occlusion=True)
    assert np.all(spec.radiance >= base.radiance - 1e-7) and spec.radiance.sum() > base.radiance.sum()
    assert np.all(ao.radiance >= base.radiance - 1e-7) and ao.radiance.sum() > base.radiance.sum()
    assert ao.info["recomputed"] == [] and spec.info["recomputed"] == []


def test_bad_options(device):
    vol, tf, u = ball(8)
    scene = ball_scene(tf, u)
    with pytest.raises(ValueError, match="unknown ambient-scattering option"):
        render(vol, scene, "ambient-scattering", 4, 4, device=device, spp=3)
    with pytest.raises(ValueError, match="radius"):
        render(vol, scene, "ambient-scattering", 4, 4, device=device, radius=-1.0)
    with pytest.raises(ValueError, match="ambient_occlusion"):
        render(vol, scene, "ambient-scattering", 4, 4, device=device, ambient_occlusion=0.3)
    with pytest.raises(ValueError, match="radius_units"):
        render(vol, scene, "ambient-scattering", 4, 4, device=device, radius_units="mm")


def test_closer_to_the_path_tracer_than_single_scattering():
    """Thick (optical radius 6.4), high-albedo (0.9) ball lit from the side.

    Multiple scattering carries most of the light here; single scattering misses it.
    Errors: mean absolute pixel difference over covered pixels / mean reference radiance.
    """
    vol, tf, u = ball(32, sigma=8.0)
    scene = ball_scene(tf, u)
    ref = render(vol, scene, "path", 32, 32, device="cpu", spp=256, max_bounces=64, seed=1)
    covered = ref.alpha > 0.05

    def error(result):
        return float(np.abs(result.radiance - ref.radiance)[covered].mean()
                     / ref.radiance[covered].mean())

    single = error(render(vol, scene, "single", 32, 32, device="cpu"))
    ambient = error(render(vol, scene, "ambient-scattering", 32, 32, device="cpu", radius=2.0,
                           cache=AmbientScatteringCache("cpu")))
    print(f"relative error vs path tracer: single {single:.3f}, ambient-scattering {ambient:.3f}")
    assert ambient < 0.6 * single


def test_empty_space_skipping_changes_no_pixel(device, rng):
    # Two small blobs in a mostly empty volume, with opacity only in the middle of the data
    # range: interpolation between 0 and 1 passes through it (post-classification), so a
    # block is empty only if its whole data range maps to zero extinction.
    from vtkillum.core.empty_space import block_ranges, occupancy
    from vtkillum.core.ambient.gather import gather
    from vtkillum.core.warp_common import make_camera

    s = np.zeros((40, 36, 33), np.float32)
    s[6:12, 8:13, 5:9] = 1.0
    s[25:31, 20:27, 20:26] = rng.random((6, 7, 6)) * 0.4 + 0.3
    vol = Volume(s, spacing=(0.5, 0.6, 0.7))
    tf = TransferFunction([0.0, 0.35, 0.5, 0.65, 1.0], [0.0, 0.0, 0.6, 0.0, 0.0])
    scene = Scene(transfer_function=tf, lights=[DirectionalLight((1, -1, -1))],
                  camera=Camera.looking_at_bounds(vol.bounds, direction=(-0.3, -0.2, -1.0)))
    cache = AmbientScatteringCache(device)
    st = cache.update(vol, tf, 0.5, 0.9, 0.3, scene.lights, 2.0)
    occ = st.occupied.numpy()
    assert 0 < occ.sum() < occ.size  # some blocks can be skipped, the blobs' cannot
    ranges = block_ranges(st.medium.scalars, device).numpy()
    assert occ[0, 1, 0] == 1 and ranges[0, 1, 0, 1] == 1.0  # 0..1 block: 0.5 in between
    cam = make_camera(scene.resolved_camera(vol), vol, 24, 20)
    args = (st.medium, st.sigma_tilde, st.radiance.grid, st.lights, cam, st.table_slice,
            st.table.sigma_max, st.radius, 0.3)
    skip = gather(*args, device=device, occupied=st.occupied, spacing=vol.spacing)
    full = gather(*args, device=device)
    np.testing.assert_array_equal(skip[0], full[0])
    np.testing.assert_array_equal(skip[1], full[1])
    assert full[0].max() > 0 and skip[2] < full[2]  # fewer samples, same picture
    assert np.all(occupancy(st.medium, block_ranges(st.medium.scalars, device), device).numpy()
                  == occ)


def test_unscattered_light_reaches_the_centre_in_backscatter():
    """Single scattering alone (a table for albedo 0: no scattered part M) in a homogeneous
    cube lit from the camera's side, optical radius r σt = 0.7 and 2.1: the centred gather
    gives single scattering (within 20 %: σ̃t of the SAT treats the outside as empty, so the
    first r of the entry face is attenuated less), while the paper's table term carries the
    light scattered at the sphere's far boundary back across the whole sphere, and the image
    is 3-100 times too dark."""
    from vtkillum.core.ambient.table import generate_table

    absorbing = generate_table(albedo=0.0, n_theta=64, n_sigma=64, n_g=3, samples=16,
                               device="cpu", progress=False)
    n, sigma, u = 24, 8.0, 0.1
    vol = Volume(np.ones((n, n, n), np.float32), spacing=(1 / (n - 1),) * 3)
    tf = TransferFunction([0, 1], [1 - np.exp(-sigma * u)] * 2)
    cam = Camera(position=(0.5, 0.5, 3), focal_point=(0.5, 0.5, 0.5), parallel_projection=True,
                 parallel_scale=0.3)
    for direction in ((0, 0, -1), (0.6, 0, -0.8)):
        scene = Scene(transfer_function=tf, opacity_unit_distance=u, albedo=0.9,
                      lights=[DirectionalLight(direction)], camera=cam)
        single = render(vol, scene, "single", 16, 16, device="cpu", jitter=False).radiance.mean()
        for radius in (2.0, 6.0):
            ratio = {g: render(vol, scene, "ambient-scattering", 16, 16, device="cpu",
                               jitter=False, radius=radius, gather=g, table=absorbing,
                               cache=AmbientScatteringCache("cpu")).radiance.mean() / single
                     for g in ("centred", "paper")}
            print(direction, radius, ratio)
            assert 0.95 < ratio["centred"] < 1.2
            assert ratio["paper"] < 0.4


def test_tube_sampling_options(device):
    """The step field (default: 2 samples per step) against the mean of sigma~ along each step
    (a sample per data spacing): the same picture within a few per cent; bad options refused."""
    vol, tf, u = ball(24, sigma=6.0)
    scene = ball_scene(tf, u, g=0.4)
    out = {}
    for tube, k in (("field", 2), ("field", 1), ("midpoint", 2), ("paper", 1)):
        cache = AmbientScatteringCache(device, tube_sampling=tube, step_samples=k)
        out[tube, k] = render(vol, scene, "ambient-scattering", 24, 24, device=device,
                              cache=cache, radius=3.0).radiance
    exact = out["midpoint", 2]

    def rel(key):
        return np.sqrt(np.mean((out[key] - exact) ** 2) / np.mean(exact**2))

    # measured on the CPU: 0.003 (2 samples), 0.010 (1), the paper's one sample of sigma~ 0.022
    assert rel(("field", 2)) < 0.005
    assert rel(("field", 1)) < 0.015 < rel(("paper", 1))
    assert out["field", 2].sum() == pytest.approx(exact.sum(), rel=0.005)
    assert AmbientScatteringCache(device).tube_sampling == "field"
    with pytest.raises(ValueError, match="tube_sampling"):
        AmbientScatteringCache(device, tube_sampling="exact")
    with pytest.raises(ValueError, match="step_samples"):
        AmbientScatteringCache(device, step_samples=0)


def test_light_and_g_edits_replay_the_recorded_march(device):
    """A g or light edit overwrites the march's inputs in place and replays the recorded
    launch (no new cache object): the result equals a fresh cache's."""
    vol, tf, u = ball(16)
    cache = AmbientScatteringCache(device)
    scene = ball_scene(tf, u, g=0.2)
    render(vol, scene, "ambient-scattering", 10, 10, device=device, cache=cache)
    first = cache._radiance
    assert first.replay is not None
    for edit in ("g", "light", "point"):
        if edit == "g":
            scene.anisotropy = -0.3
        elif edit == "light":
            scene.lights = [DirectionalLight((-0.4, 1.0, 0.2), (0.5, 1.0, 2.0))]
        else:
            scene.lights = [PointLight((0.3, 1.5, -0.2), (4.0, 3.0, 2.0))]
        again = render(vol, scene, "ambient-scattering", 10, 10, device=device, cache=cache)
        assert again.info["recomputed"] == ["radiance"]
        assert cache._radiance is first  # replayed into the same arrays
        fresh_cache = AmbientScatteringCache(device)
        fresh = render(vol, scene, "ambient-scattering", 10, 10, device=device, cache=fresh_cache)
        np.testing.assert_array_equal(cache._radiance.numpy(), fresh_cache._radiance.numpy())
        np.testing.assert_allclose(again.radiance, fresh.radiance, rtol=1e-6, atol=1e-9)
