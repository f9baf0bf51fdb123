"""Ray caster (emission, single scattering, illumination volume) against analytic references.

Geometry used throughout: homogeneous boxes seen by a parallel camera along the
z axis, so every pixel's ray crosses a known length of a known medium, and
directional lights tilted in the x-z plane, so the light's path to the box exit
is known in closed form.
"""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.raycast import render_emission, render_illuminated, render_single
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

COLOR = (0.3, 0.6, 0.9)


def constant_tf(alpha, color=COLOR, lo=-1.0, hi=100.0):
    """Transfer function with the same opacity and colour for every data value."""
    return TransferFunction([lo, hi], [alpha, alpha], [color, color])


def top_camera(extent, scale, below=False):
    """Parallel camera looking down -z from above the box (or up +z from below) at its centre."""
    cx, cy, cz = 0.5 * extent[0], 0.5 * extent[1], 0.5 * extent[2]
    z = -50.0 if below else extent[2] + 50.0
    return Camera((cx, cy, z), (cx, cy, cz), (0.0, 1.0, 0.0), parallel_projection=True,
                  parallel_scale=scale)


def sigma_from_alpha(alpha, u):
    return -np.log(1.0 - alpha) / u


def tilted_light(phi_deg, irradiance=(1.0, 1.0, 1.0)):
    """Light travelling downwards (-z), tilted by phi towards +x."""
    phi = np.radians(phi_deg)
    return DirectionalLight((np.sin(phi), 0.0, -np.cos(phi)), irradiance)


def hg(cos_theta, g):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos_theta) ** 1.5)


def slab_single_scattering(sigma, length, sec, forward, albedo, color, g, irradiance=1.0):
    """Exact single scattering of a homogeneous slab of thickness ``length``.

    The camera looks along the slab normal; the light enters through the top face
    with ``sec = 1 / cos(phi)``. Backward geometry (camera on the light's side): at
    depth ``t`` the light path is ``t sec``; forward (camera below): ``(L - t) sec``.
    ``∫0^L σs p E exp(-σ t) exp(-σ (a + b t)) dt`` in closed form.
    """
    cos_theta = 1.0 / sec if forward else -1.0 / sec
    a, b = (length * sec, -sec) if forward else (0.0, sec)
    k = sigma * (1.0 + b)
    integral = length if abs(k) < 1e-12 else (1.0 - np.exp(-k * length)) / k
    sigma_s = albedo * np.asarray(color) * sigma
    return sigma_s * hg(cos_theta, g) * irradiance * np.exp(-sigma * a) * integral


def wide_slab(thickness=8, nx=33, ny=9):
    """Constant-scalar box, wide in x so tilted light always enters through the top face."""
    return Volume(np.ones((nx, ny, thickness + 1)), spacing=(1.0, 1.0, 1.0))


# --- emission: Beer–Lambert ---------------------------------------------------------------------
@pytest.mark.parametrize("u", [1.0, 2.5])
@pytest.mark.parametrize("jitter", [False, True])
def test_emission_beer_lambert(device, u, jitter):
    vol = Volume(np.ones((9, 9, 9)))  # extent 8 along every axis
    alpha_tf = 0.2
    scene = Scene(transfer_function=constant_tf(alpha_tf), opacity_unit_distance=u,
                  camera=top_camera(vol.extent, 3.0))
    res = render_emission(vol, scene, 16, 16, device, step_size=0.5, jitter=jitter,
                          early_termination=1.0)
    expected = 1.0 - np.exp(-sigma_from_alpha(alpha_tf, u) * 8.0)
    np.testing.assert_allclose(res.alpha, expected, atol=1e-4)
    expected_rgb = np.broadcast_to(np.asarray(COLOR) * expected, res.radiance.shape)
    np.testing.assert_allclose(res.radiance, expected_rgb, atol=1e-4)
    assert res.radiance.shape == (16, 16, 3) and res.radiance.dtype == np.float32
    assert res.alpha.dtype == np.float32


def test_emission_misses_and_background(device):
    """Rays that miss the box stay transparent and black."""
    vol = Volume(np.ones((5, 5, 5)))
    scene = Scene(transfer_function=constant_tf(0.5), camera=top_camera(vol.extent, 8.0))
    res = render_emission(vol, scene, 16, 16, device)
    assert res.alpha[0, 0] == 0 and np.all(res.radiance[0, 0] == 0)
    assert res.alpha[8, 8] > 0.9


def test_early_termination_stops_rays(device):
    vol = Volume(np.ones((9, 9, 33)))
    scene = Scene(transfer_function=constant_tf(0.5), camera=top_camera(vol.extent, 3.0))
    full = render_emission(vol, scene, 8, 8, device, jitter=False, early_termination=1.0)
    early = render_emission(vol, scene, 8, 8, device, jitter=False, early_termination=0.9)
    assert early.info["mean_samples_per_pixel"] < 0.2 * full.info["mean_samples_per_pixel"]
    assert np.all(early.alpha > 0.9) and np.all(early.alpha < full.alpha)


# --- single scattering ----------------------------------------------------------------------------
@pytest.mark.parametrize("sigma_l", [0.05, 2.0])  # optically thin and thick slabs
def test_single_scattering_slab_analytic(device, sigma_l):
    thickness, u, albedo, phi = 8, 1.0, 0.8, 30.0
    sigma = sigma_l / thickness
    alpha_tf = 1.0 - np.exp(-sigma * u)
    vol = wide_slab(thickness)
    e = np.array([2.0, 1.0, 0.5])
    scene = Scene(transfer_function=constant_tf(alpha_tf), opacity_unit_distance=u,
                  albedo=albedo, anisotropy=0.0, lights=[tilted_light(phi, e)],
                  camera=top_camera(vol.extent, 3.0))
    res = render_single(vol, scene, 12, 12, device, step_size=0.25, jitter=False,
                        early_termination=1.0)
    sec = 1.0 / np.cos(np.radians(phi))
    expected = slab_single_scattering(sigma, thickness, sec, False, albedo, COLOR, 0.0) * e
    # Measured: 2e-6 (thin) and 6e-4 (thick); a first-order step rule would be off by 3 %.
    np.testing.assert_allclose(res.radiance, np.broadcast_to(expected, res.radiance.shape),
                               rtol=2e-3)


def test_single_scattering_anisotropy_forward_vs_backward(device):
    thickness, g, phi, sigma = 8, 0.6, 30.0, 0.01
    vol = wide_slab(thickness)
    tf = constant_tf(1.0 - np.exp(-sigma))
    sec = 1.0 / np.cos(np.radians(phi))
    out = {}
    for forward in (False, True):
        scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, albedo=1.0, anisotropy=g,
                      lights=[tilted_light(phi)], camera=top_camera(vol.extent, 3.0, forward))
        rad = render_single(vol, scene, 8, 8, device, step_size=0.25, jitter=False).radiance
        expected = slab_single_scattering(sigma, thickness, sec, forward, 1.0, COLOR, g)
        np.testing.assert_allclose(rad, np.broadcast_to(expected, rad.shape), rtol=5e-3)
        out[forward] = rad.mean()
    # Forward scattering towards a camera that looks into the light is much brighter for g > 0.
    assert out[True] > 5.0 * out[False]


def test_single_scattering_shadow_from_occluder(device):
    """A dense block between the light and a thin layer darkens the part of the layer behind it."""
    s = np.zeros((33, 5, 17))
    s[:, :, 0:3] = 1.0  # thin lit layer at the bottom
    s[0:12, :, 10:16] = 2.0  # opaque block above the left part of it
    vol = Volume(s)
    tf = TransferFunction([0.0, 0.5, 1.0, 1.5, 2.0], [0.0, 0.0, 0.3, 0.99, 0.99])
    cam = Camera((16, 2, -40), (16, 2, 8), (0, 1, 0), parallel_projection=True, parallel_scale=2)
    scene = Scene(transfer_function=tf, lights=[DirectionalLight((0, 0, -1))], camera=cam)
    res = render_single(vol, scene, 64, 8, device, jitter=False)
    # Seen from below, image columns run along the camera's right vector.
    r, _, _ = cam.basis()
    cols_left = slice(4, 16) if r[0] > 0 else slice(48, 60)
    cols_right = slice(48, 60) if r[0] > 0 else slice(4, 16)
    shadowed = res.radiance[:, cols_left].mean()
    lit = res.radiance[:, cols_right].mean()
    assert shadowed < 0.05 * lit


def test_point_light_far_away_matches_directional(device):
    vol = wide_slab(8)
    tf = constant_tf(0.05)
    direc = tilted_light(30.0, (1.0, 0.5, 2.0))
    far = 1.0e4
    point = PointLight(vol.extent / 2 - far * direc.direction, far ** 2 * direc.irradiance)
    images = []
    for light in (direc, point):
        scene = Scene(transfer_function=tf, lights=[light], camera=top_camera(vol.extent, 3.0))
        images.append(render_single(vol, scene, 8, 8, device, jitter=False).radiance)
    np.testing.assert_allclose(images[1], images[0], rtol=5e-3)


def test_point_light_shadow_rays_stop_at_the_light(device):
    """A black absorber beyond a point light (seen from the lit layer) casts no shadow."""
    s = np.zeros((17, 17, 17))
    s[:, :, 0:2] = 1.0  # scattering layer at the bottom
    blocked = s.copy()
    blocked[:, :, 12:16] = -1.0  # black, dense block above the light
    # Values between 0 and -1 (the block's border) are black too: the block scatters nothing.
    tf = TransferFunction([-1.0, -0.5, 0.0, 0.5, 1.0], [0.99, 0.99, 0.0, 0.0, 0.3],
                          [[0, 0, 0]] * 3 + [[1, 1, 1]] * 2)
    light = PointLight((8.0, 8.0, 7.0), (50.0, 50.0, 50.0))
    cam = Camera((8, 8, -40), (8, 8, 8), (0, 1, 0), parallel_projection=True, parallel_scale=6)
    scene = Scene(transfer_function=tf, lights=[light], camera=cam)
    free = render_single(Volume(s), scene, 16, 16, device, jitter=False).radiance
    behind = render_single(Volume(blocked), scene, 16, 16, device, jitter=False).radiance
    assert free.mean() > 0.01
    np.testing.assert_allclose(behind, free, rtol=1e-5, atol=1e-7)


# --- illumination volume --------------------------------------------------------------------------
def slab_fluence(vol, sigma, light, irradiance, upsample=2):
    """Analytic φ = T E on a grid ``upsample`` times finer than the data (homogeneous box)."""
    shape = [(n - 1) * upsample + 1 for n in vol.dims]
    axes = [np.linspace(0.0, e, n) for e, n in zip(vol.extent, shape)]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    w = -light.direction  # towards the light
    with np.errstate(divide="ignore", invalid="ignore"):
        exits = [np.where(w[a] > 0, (vol.extent[a] - p[..., a]) / w[a],
                          np.where(w[a] < 0, -p[..., a] / w[a], np.inf)) for a in range(3)]
    dist = np.min(exits, axis=0)
    return np.exp(-sigma * dist)[..., None] * np.asarray(irradiance)


def test_illuminated_equals_isotropic_single(device):
    thickness, phi, sigma = 8, 30.0, 0.125  # optical thickness 1: shadows matter
    vol = wide_slab(thickness)
    light = tilted_light(phi, (1.5, 1.0, 0.5))
    scene = Scene(transfer_function=constant_tf(1.0 - np.exp(-sigma)), opacity_unit_distance=1.0,
                  albedo=0.7, anisotropy=0.0, lights=[light], camera=top_camera(vol.extent, 3.0))
    illum = IlluminationVolume.for_volume(vol, slab_fluence(vol, sigma, light, light.irradiance))
    opts = dict(step_size=0.5, jitter=False, early_termination=1.0)
    single = render_single(vol, scene, 12, 12, device, **opts)
    shaded = render_illuminated(vol, scene, 12, 12, device, illumination=illum, **opts)
    np.testing.assert_allclose(shaded.radiance, single.radiance, rtol=2e-3)
    np.testing.assert_allclose(shaded.alpha, single.alpha, atol=1e-6)
    # A plain array is accepted too and gives the same image.
    again = render_illuminated(vol, scene, 12, 12, device, illumination=illum.scattered, **opts)
    np.testing.assert_array_equal(again.radiance, shaded.radiance)


def test_phong_factor_analytic(device):
    """Scalar ramp s = 8 - z under a constant-opacity TF: homogeneous medium with normal ±z.

    The gradient points away from the camera; two-sided lighting turns the normal to
    face it, so S = ka + kd cos(phi) + ks max(n.h, 0)^shininess everywhere, exactly.
    """
    nz = 9
    z = np.arange(nz, dtype=float)
    vol = Volume(np.broadcast_to(nz - 1 - z, (17, 9, nz)).copy())
    phi = 40.0
    light = tilted_light(phi)
    fluence = np.ones((4, 4, 4, 3))
    base = Scene(transfer_function=constant_tf(0.1), lights=[light],
                 camera=top_camera(vol.extent, 3.0))
    shaded = Scene(transfer_function=constant_tf(0.1), lights=[light],
                   camera=top_camera(vol.extent, 3.0),
                   shading={"ambient": 0.2, "diffuse": 0.7, "specular": 0.5, "shininess": 8.0})
    opts = dict(step_size=0.5, jitter=False)
    ref = render_illuminated(vol, base, 8, 8, device, illumination=fluence, **opts).radiance
    img = render_illuminated(vol, shaded, 8, 8, device, illumination=fluence, **opts).radiance
    n = np.array([0.0, 0.0, 1.0])  # faces the camera above
    l = -light.direction
    h = (l + n) / np.linalg.norm(l + n)  # v = n here
    s_expected = 0.2 + 0.7 * abs(n @ l) + 0.5 * max(n @ h, 0.0) ** 8
    np.testing.assert_allclose(img, s_expected * ref, rtol=1e-4)


def test_phong_gradient_free_and_blob(device):
    """Homogeneous data: S = ka + kd. Structured data: diffuse shading changes the image's shape."""
    vol = Volume(np.ones((9, 9, 9)))
    fluence = np.ones((9, 9, 9, 3))
    kw = dict(transfer_function=constant_tf(0.2), camera=top_camera(vol.extent, 3.0))
    opts = dict(step_size=0.5, jitter=False)
    plain = render_illuminated(vol, Scene(**kw), 8, 8, device, illumination=fluence, **opts)
    diffuse = render_illuminated(
        vol, Scene(**kw, shading={"ambient": 1.0, "diffuse": 0.5, "specular": 3.0}),
        8, 8, device, illumination=fluence, **opts)
    np.testing.assert_allclose(diffuse.radiance, 1.5 * plain.radiance, rtol=1e-5)

    x = np.linspace(-1, 1, 24)
    r2 = sum(c ** 2 for c in np.meshgrid(x, x, x, indexing="ij"))
    blob = Volume(np.exp(-r2 / 0.2))
    tf = TransferFunction([0.0, 0.3, 1.0], [0.0, 0.2, 0.8])
    fl = np.ones((12, 12, 12, 3))
    light = [DirectionalLight((1.0, 0.0, 0.0))]
    a = render_illuminated(blob, Scene(transfer_function=tf, lights=light), 24, 24, device,
                           illumination=fl, **opts).radiance[..., 0]
    b = render_illuminated(blob, Scene(transfer_function=tf, lights=light,
                                       shading={"ambient": 0.0, "diffuse": 1.0}),
                           24, 24, device, illumination=fl, **opts).radiance[..., 0]
    ratio = b[a > 1e-3] / a[a > 1e-3]
    assert ratio.std() > 0.05  # not a uniform rescaling: the normals matter


# --- jitter ---------------------------------------------------------------------------------------
def test_jitter_mean_is_unbiased_for_uneven_steps(device):
    """Step 3 through a slab of length 8: fixed sampling takes 3 samples, jitter 8/3 on average."""
    sigma = 0.025
    vol = Volume(np.ones((9, 9, 9)))
    scene = Scene(transfer_function=constant_tf(1.0 - np.exp(-sigma)), opacity_unit_distance=1.0,
                  camera=top_camera(vol.extent, 3.0))
    exact = 1.0 - np.exp(-sigma * 8.0)
    fixed = render_emission(vol, scene, 32, 32, device, step_size=3.0, jitter=False).alpha
    jit = render_emission(vol, scene, 32, 32, device, step_size=3.0, jitter=True, seed=7).alpha
    assert abs(fixed.mean() - exact) > 0.015  # 3 samples of 3: optical depth 9 sigma
    assert abs(jit.mean() - exact) < 4e-3
    assert jit.std() > 0.01  # it is noise, not a constant
    other = render_emission(vol, scene, 32, 32, device, step_size=3.0, seed=8).alpha
    assert not np.array_equal(other, jit)  # the seed changes the pattern


def test_jitter_removes_banding_on_sloped_surface(device):
    """A tilted sheet sampled with coarse steps: fixed steps give a triangle wave along x
    (wood grain, period step / slope), jittered steps noise that averages out over rows and
    frames (seeds) towards a flat profile."""
    slope = 0.125  # sheet height changes by one step every 8 world units = 16 pixels
    x = np.arange(33, dtype=float)[:, None, None]
    z = np.arange(17, dtype=float)[None, None, :]
    vol = Volume(np.broadcast_to(z + slope * x, (33, 33, 17)).copy())
    tf = TransferFunction([0.0, 8.5, 9.0, 10.0, 10.5, 40.0], [0, 0, 0.6, 0.6, 0, 0])  # a sheet
    cam = Camera((16, 16, 40), (16, 16, 8), (0, 1, 0), parallel_projection=True,
                 parallel_scale=16)
    scene = Scene(transfer_function=tf, camera=cam)

    def banding(alpha):  # std along x of the row-averaged, lightly smoothed profile
        profile = np.convolve(alpha.mean(0), np.ones(3) / 3, mode="valid")
        return profile.std()

    ref = render_emission(vol, scene, 64, 64, device, step_size=0.02, jitter=False).alpha
    fixed = render_emission(vol, scene, 64, 64, device, step_size=1.0, jitter=False).alpha
    jit = np.mean([render_emission(vol, scene, 64, 64, device, step_size=1.0, seed=s).alpha
                   for s in range(4)], axis=0)
    assert banding(ref) < 1e-3  # the sheet is uniform: no structure along x
    assert banding(fixed) > 0.02
    assert banding(fixed) > 4.0 * banding(jit)
    assert abs(jit.mean() - ref.mean()) < 0.015


# --- errors ---------------------------------------------------------------------------------------
def test_illumination_errors(device):
    vol = Volume(np.ones((5, 5, 5)))
    scene = Scene(transfer_function=constant_tf(0.2))
    with pytest.raises(ValueError, match=r"\(nx, ny, nz, 3\)"):
        render_illuminated(vol, scene, 4, 4, device, illumination=np.ones((5, 5, 5)))
    with pytest.raises(ValueError, match="at least 2"):
        render_illuminated(vol, scene, 4, 4, device, illumination=np.ones((1, 5, 5, 3)))
    with pytest.raises(ValueError, match="needs illumination"):
        render_illuminated(vol, scene, 4, 4, device)
    with pytest.raises(ValueError, match="for_volume"):
        render_illuminated(vol, scene, 4, 4, device,
                           illumination=IlluminationVolume(np.ones((3, 3, 3, 3)), (4, 4, 8)))
    with pytest.raises(ValueError, match="non-negative"):
        IlluminationVolume.for_volume(vol, -np.ones((3, 3, 3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        IlluminationVolume.for_volume(vol, np.full((3, 3, 3, 3), np.nan))


def test_option_errors(device):
    vol = Volume(np.ones((5, 5, 5)))
    scene = Scene(transfer_function=constant_tf(0.2))
    with pytest.raises(ValueError, match="unknown ray-casting option"):
        render_emission(vol, scene, 4, 4, device, spp=4)
    with pytest.raises(ValueError, match="step_size"):
        render_emission(vol, scene, 4, 4, device, step_size=-1.0)
    with pytest.raises(ValueError, match="early_termination"):
        render_emission(vol, scene, 4, 4, device, early_termination=0.0)
    with pytest.raises(ValueError, match="shading.diffuse"):
        render_illuminated(vol, Scene(shading={"diffuse": -1.0}), 4, 4, device,
                           illumination=np.ones((2, 2, 2, 3)))


def test_progress_and_info(device, monkeypatch):
    import vtkillum.core.raycast as rc

    monkeypatch.setitem(rc.TILE_PIXELS, "cpu", 64)
    monkeypatch.setitem(rc.TILE_PIXELS, "cuda", 64)
    vol = Volume(np.ones((5, 5, 5)))
    scene = Scene(transfer_function=constant_tf(0.2), camera=top_camera(vol.extent, 3.0))
    calls = []
    tiled = render_emission(vol, scene, 16, 16, device, progress=calls.append, jitter=False)
    whole = render_emission(vol, scene, 16, 16, device, jitter=False)
    # Reports weighted by each band's ray length inside the box (plus a small floor per
    # pixel): the time-left estimate follows the work, not the rows.
    from vtkillum.core.raymarch import pixel_work
    from vtkillum.core.warp_common import make_camera

    work = pixel_work(make_camera(scene.camera, vol, 16, 16), vol.extent, 16, 16, device)
    band = work.reshape(4, 64).sum(1) + 0.02 * work.mean() * 64
    np.testing.assert_allclose(calls, list(np.cumsum(band)[:3] / band.sum()) + [1.0], rtol=1e-5)
    assert tiled.info["tiles"] == 4
    np.testing.assert_array_equal(tiled.radiance, whole.radiance)
    for key in ("setup_s", "render_s", "download_s", "total_s", "mean_samples_per_pixel"):
        assert key in tiled.info


def test_pixel_work_is_the_ray_length_inside_the_box(device):
    """Parallel camera along -z over a 2 x 1 x 3 box: pixels over the box see 3 world
    units of it, the others none."""
    from vtkillum.core.raymarch import pixel_work
    from vtkillum.core.warp_common import make_camera

    vol = Volume(np.ones((3, 2, 4)), spacing=(1.0, 1.0, 1.0))  # extent 2 x 1 x 3
    cam = Camera(position=(1.0, 0.5, 10.0), focal_point=(1.0, 0.5, 0.0),
                 parallel_projection=True, parallel_scale=2.0)
    work = pixel_work(make_camera(cam, vol, 16, 16), vol.extent, 16, 16, device)
    # 16 px over 4 world units: the box spans columns 4..11 (2 units) and rows 6..9 (1 unit)
    inside = np.zeros((16, 16), bool)
    inside[6:10, 4:12] = True
    np.testing.assert_allclose(work[inside], 3.0, rtol=1e-5)
    assert np.all(work[~inside] == 0.0)
