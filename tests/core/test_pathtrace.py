"""The reference path tracer (``vtkillum.core.pathtrace``) against analytic results.

Most tests use a homogeneous cube of side ``a`` (local frame ``[0, a]³``), a parallel
camera looking down ``-z`` that covers it, and a directional light travelling along
``-x``, for which single scattering and the energy balance have closed forms. The
radiance integrated over the image plane of a parallel camera,

    J = ∫ L dA = Σ_pixels L · (pixel area),

is the radiant intensity leaving the volume towards the camera; the path tracer's
jittered sub-pixel positions make its per-image estimate of ``J`` unbiased, with a
variance estimated from the per-pass spread of each pixel.
"""

import numpy as np
import pytest
import warp as wp
from scipy.stats import chisquare

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.pathtrace import PathTracer, delta_tracking, ratio_tracking, render_path
from vtkillum.core.raycast import render_single
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import Medium, make_medium

SIDE = 1.0  # cube side a (world units)
HALF_VIEW = 0.55  # parallel scale: half the view height
IMAGE = 24


def hg(cos_theta, g):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos_theta) ** 1.5)


def cube_scene(tau, albedo, g=0.0, n=12):
    """Homogeneous cube of optical thickness ``tau`` per side, lit along -x, seen along -z."""
    volume = Volume(np.ones((n, n, n)), spacing=(SIDE / (n - 1),) * 3)
    opacity = 1.0 - np.exp(-tau)  # sigma_t = -ln(1 - alpha) / u with u = SIDE
    tf = TransferFunction([0.0, 2.0], [opacity, opacity])
    centre = np.full(3, SIDE / 2)
    camera = Camera(centre + (0, 0, 5.0), centre, (0, 1, 0), parallel_projection=True,
                    parallel_scale=HALF_VIEW)
    scene = Scene(transfer_function=tf, opacity_unit_distance=SIDE, albedo=albedo, anisotropy=g,
                  lights=[DirectionalLight((-1.0, 0.0, 0.0), (1.0, 1.0, 1.0))], camera=camera)
    return volume, scene


def intensity(tracer):
    """Image-plane integral J of the grey radiance and its standard error."""
    pixel_area = (2 * HALF_VIEW / tracer.height) ** 2  # square pixels, aspect 1
    j = tracer.radiance[..., 0].astype(np.float64).sum() * pixel_area
    sigma = np.sqrt(tracer.radiance_variance[..., 0].sum()) * pixel_area
    return j, sigma


def smooth_scene(albedo=0.8, g=0.4, n=20):
    """A smooth heterogeneous blob with colours, a directional and a point light."""
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    s = np.exp(-((X - 0.15) ** 2 + Y**2 + (Z + 0.1) ** 2) / 0.35) + 0.15 * np.sin(2 * X + Y)
    volume = Volume(s, spacing=(2.0 / (n - 1),) * 3, origin=(-1.0, -1.0, -1.0))
    tf = TransferFunction([0.0, 0.4, 1.0], [0.0, 0.25, 0.6],
                          [[1.0, 1.0, 1.0], [1.0, 0.7, 0.4], [0.5, 0.8, 1.0]])
    lights = [DirectionalLight((1.0, -0.6, -0.4), (1.0, 0.9, 0.8)),
              PointLight((-1.8, 1.2, 2.0), (6.0, 6.0, 7.0))]
    camera = Camera((0.8, 0.6, 4.0), (0.0, 0.0, 0.0), (0, 1, 0), view_angle=35.0)
    scene = Scene(transfer_function=tf, opacity_unit_distance=0.5, albedo=albedo, anisotropy=g,
                  lights=lights, camera=camera)
    return volume, scene


def line_medium(device, total_tau=7.0):
    """A medium varying along x only, and the exact optical depth τ(t) along y = z = 0.1.

    Data are a sampled sine along x (constant in y and z), so along the line trilinear
    interpolation is linear interpolation between the nodes; σ_t = -ln(1 - α(s)) / u is
    integrated with a fine trapezoid rule. ``u`` is chosen so that the whole line has
    optical depth ``total_tau``.
    """
    n, h = 24, 0.1
    xs = np.arange(n) * h
    f = 0.55 + 0.45 * np.sin(3.0 * xs)
    tf = TransferFunction([0.0, 1.0], [0.0, 0.9])
    fine = np.linspace(0.0, xs[-1], 20001)
    raw = -np.log1p(-tf.alpha(np.interp(fine, xs, f)))  # σ_t · u along the line
    cumulative = np.concatenate([[0.0], np.cumsum((raw[1:] + raw[:-1]) / 2 * np.diff(fine))])
    u = cumulative[-1] / total_tau
    volume = Volume(np.broadcast_to(f[:, None, None], (n, 4, 4)).copy(), spacing=(h, h, h))
    medium = make_medium(volume, tf, u, 1.0, 0.0, device)
    return medium, (lambda t: np.interp(t, fine, cumulative / u)), xs[-1]


@wp.kernel
def transmittance_kernel(m: Medium, o: wp.vec3, d: wp.vec3, t_end: float, roulette: int,
                         out: wp.array(dtype=float)):
    """``wp.tid()`` indexes independent ratio-tracking estimates along ``o + t d``."""
    i = wp.tid()
    T, state = ratio_tracking(m, o, d, 0.0, t_end, roulette, wp.rand_init(123, i))
    out[i] = T


@wp.kernel
def collision_kernel(m: Medium, o: wp.vec3, d: wp.vec3, t_end: float,
                     out: wp.array(dtype=float)):
    """``wp.tid()`` indexes delta-tracking walks; writes the collision distance or -1."""
    i = wp.tid()
    hit, t, s, state = delta_tracking(m, o, d, 0.0, t_end, wp.rand_init(321, i))
    out[i] = wp.where(hit, t, -1.0)


@pytest.mark.parametrize("roulette", [0, 1])
def test_ratio_tracking_is_unbiased(device, roulette):
    """Mean of the shadow-ray estimator equals exp(-τ) for τ from 0.5 to 7 (with roulette,
    most estimates below τ ≈ 2.3 go through the weight window)."""
    medium, tau, length = line_medium(device)
    n = 100_000
    out = wp.zeros(n, dtype=float, device=device)
    o, d = wp.vec3(0.0, 0.1, 0.1), wp.vec3(1.0, 0.0, 0.0)
    for t_end in (0.1, 0.6, 1.2, length):
        wp.launch(transmittance_kernel, n, inputs=[medium, o, d, float(t_end), roulette, out],
                  device=device)
        T = out.numpy().astype(np.float64)
        exact = np.exp(-tau(t_end))
        assert np.all((T >= 0) & (T <= 1))
        assert abs(T.mean() - exact) < 4 * T.std() / np.sqrt(n) + 1e-6, (t_end, T.mean(), exact)
    # roulette ends hopeless estimates early: over the whole line most are exactly zero
    assert (np.mean(T == 0) > 0.9) == bool(roulette)


def test_delta_tracking_samples_collisions_with_density_sigma_t_T(device):
    """χ² of collision distances against F(t) = 1 - exp(-τ(t)); misses are a bin too."""
    medium, tau, length = line_medium(device, total_tau=2.0)
    n = 100_000
    out = wp.zeros(n, dtype=float, device=device)
    wp.launch(collision_kernel, n, inputs=[medium, wp.vec3(0.0, 0.1, 0.1),
                                           wp.vec3(1.0, 0.0, 0.0), float(length), out],
              device=device)
    t = out.numpy().astype(np.float64)
    edges = np.linspace(0.0, length, 31)
    observed = np.append(np.histogram(t[t >= 0], bins=edges)[0], np.sum(t < 0))
    survival = np.exp(-tau(edges))
    expected = np.append(-np.diff(survival), survival[-1]) * n
    assert chisquare(observed, expected * observed.sum() / expected.sum()).pvalue > 1e-3
    # the same histogram against a homogeneous medium of equal total depth is rejected
    wrong = np.exp(-tau(length) * edges / length)
    wrong_expected = np.append(-np.diff(wrong), wrong[-1]) * n
    wrong_expected *= observed.sum() / wrong_expected.sum()
    assert chisquare(observed, wrong_expected).pvalue < 1e-10


def test_single_scattering_matches_closed_form(device):
    """Homogeneous cube, light along -x, camera along +z (θ = 90°): with σ = τ / a,

        J₁ = ∫ dy ∫ dx e^{-σ(a-x)} ∫ dz e^{-σ(a-z)} Λσ p(0) E = Λ p(0) E a² (1 - e^{-τ})² / τ,

    and alpha over the cube's footprint is 1 - e^{-τ}.
    """
    tau, albedo, g = 2.0, 0.8, 0.3
    volume, scene = cube_scene(tau, albedo, g)
    tracer = PathTracer(volume, scene, IMAGE, IMAGE, device=device, seed=3, max_bounces=1)
    tracer.run(96)
    j, sigma = intensity(tracer)
    exact = albedo * hg(0.0, g) * SIDE**2 * (1 - np.exp(-tau)) ** 2 / tau
    assert abs(j - exact) < 4 * sigma, (j, exact, sigma)
    assert sigma < 0.02 * exact  # the check has teeth
    # pixels whose footprint lies inside the cube's projection
    centres = (np.arange(IMAGE) + 0.5) / IMAGE * 2 * HALF_VIEW - HALF_VIEW
    inside = np.abs(centres) < SIDE / 2 - HALF_VIEW / IMAGE
    a_in = tracer.alpha[np.ix_(inside, inside)]
    # per sample the estimate is binary (T is 0 or 1 in a homogeneous medium at the majorant)
    p = 1 - np.exp(-tau)
    assert a_in.mean() == pytest.approx(p, abs=4 * np.sqrt(p * (1 - p) / (a_in.size * 96)))
    outside = ~(np.abs(centres) < SIDE / 2 + HALF_VIEW / IMAGE)
    assert np.all(tracer.alpha[outside, :] == 0) and np.all(tracer.radiance[:, outside] == 0)


def test_albedo_zero_is_black_but_opaque(device):
    volume, scene = smooth_scene(albedo=0.0)
    result = render_path(volume, scene, 16, 16, device, None, spp=4, max_bounces=8)
    assert np.all(result.radiance == 0.0)
    assert result.alpha.max() > 0.3


def test_max_bounces_one_matches_raycast_single(device):
    """max_bounces=1 is single scattering: compare with the ray caster's ``render_single``.

    The ray caster samples pixel centres, the path tracer averages over each pixel's
    footprint: the ray caster renders 3×3 sub-pixel centres per pixel, averaged. Per-pixel
    differences are measured in units of the path tracer's standard error (plus 1 % of the
    value for the ray caster's own discretisation).
    """
    volume, scene = smooth_scene()
    size, spp = 24, 256
    tracer = PathTracer(volume, scene, size, size, device=device, seed=5, max_bounces=1)
    tracer.run(spp)
    pt, var = tracer.radiance.astype(np.float64), tracer.radiance_variance
    ref = render_single(volume, scene, 3 * size, 3 * size, device, None,
                        step_size=0.25 * volume.spacing[0], jitter=False, early_termination=1.0)
    rc = ref.radiance.astype(np.float64).reshape(size, 3, size, 3, 3).mean(axis=(1, 3))
    rc_alpha = ref.alpha.astype(np.float64).reshape(size, 3, size, 3).mean(axis=(1, 3))
    assert rc.max() > 0.01  # the scene is lit
    # Per pixel where primary paths collide often (alpha > 0.2, i.e. dozens of scattering
    # events per pixel), so that the sample variance itself is trustworthy.
    dense = np.broadcast_to((rc_alpha > 0.2)[..., None], rc.shape)
    assert dense.sum() > 450
    sigma = np.sqrt(var + (0.01 * rc) ** 2)[dense]
    z = (pt - rc)[dense] / sigma
    assert np.abs(z).max() < 5.0, np.abs(z).max()
    assert 0.6 < np.mean(z**2) < 1.6, np.mean(z**2)
    # image sums per channel over every pixel: 4 standard errors plus 0.5 % systematic allowance
    diff = pt.sum(axis=(0, 1)) - rc.sum(axis=(0, 1))
    assert np.all(np.abs(diff) < 4 * np.sqrt(var.sum(axis=(0, 1))) + 0.005 * rc.sum(axis=(0, 1)))
    # alpha: both estimate 1 - T along the primary ray
    assert np.abs(tracer.alpha - rc_alpha).mean() < 0.01


def test_multiple_scattering_brightens_monotonically_within_energy_bound(device):
    """Albedo 0.99, τ = 4 per side, isotropic phase function.

    Bound. Let P_k be the power scattered at photons' k-th scattering event. The first
    collisions take P_c = E a² (1 - e^{-τ}) (light enters the face x = a at normal
    incidence, homogeneous cube), so P_1 = Λ P_c; at most all the k-times scattered power
    collides again, so P_{k+1} ≤ Λ P_k ≤ Λ^k P_c. The k-th order image-plane integral of a
    parallel camera looking along ω_o is a volume integral of the scattered source:

        J_k = ∫_V T_cam(x) σ_s(x) ∫ p(ω'·ω_o) L_{k-1}(x, ω') dω' dV
            ≤ p_max ∫_V σ_s(x) ∫ L_{k-1}(x, ω') dω' dV = p_max P_k,

    since T_cam ≤ 1 and p ≤ p_max, and σ_s times the fluence of the (k-1)-times scattered
    light is the power density scattered at the k-th event. Summing the orders the path
    tracer keeps,

        J(n) = Σ_{k=1..n} J_k ≤ p_max E a² (1 - e^{-τ}) Σ_{k=1..n} Λ^k,   p_max = 1/(4π).

    Each added order adds non-negative radiance, so J(n) is non-decreasing in n; with
    Λ = 0.99 the increments are far above the noise.
    """
    tau, albedo = 4.0, 0.99
    volume, scene = cube_scene(tau, albedo, 0.0, n=10)
    p_c = SIDE**2 * (1 - np.exp(-tau))
    values = []
    for i, n in enumerate((1, 2, 4, 16)):
        tracer = PathTracer(volume, scene, 16, 16, device=device, seed=10 + i, max_bounces=n)
        tracer.run(48)
        j, sigma = intensity(tracer)
        bound = p_c / (4 * np.pi) * sum(albedo**k for k in range(1, n + 1))
        assert j < bound, (n, j, bound)
        values.append((j, sigma))
    exact_single = albedo / (4 * np.pi) * SIDE**2 * (1 - np.exp(-tau)) ** 2 / tau
    assert abs(values[0][0] - exact_single) < 4 * values[0][1]
    for (j0, s0), (j1, s1) in zip(values, values[1:]):
        assert j1 - j0 > 4 * np.hypot(s0, s1), values


def quarter_sphere_quadrature(n_mu=4, n_phi=3):
    """Directions and weights integrating over ω_y ≥ 0, ω_z ≥ 0 (a quarter of the sphere).

    ω = (μ, √(1-μ²) cos φ, √(1-μ²) sin φ): Gauss–Legendre in μ on [-1, 0] and [0, 1]
    separately and in φ on [0, π/2], so that no node sits on the kinks of the cube's
    projected area (the planes ω_x = 0, ω_y = 0, ω_z = 0).
    """
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mus = np.concatenate([(x - 1) / 2, (x + 1) / 2])
    w_mu = np.concatenate([w / 2, w / 2])
    x, w = np.polynomial.legendre.leggauss(n_phi)
    phis = (x + 1) * np.pi / 4
    w_phi = w * np.pi / 4
    for mu, wm in zip(mus, w_mu):
        for phi, wp_ in zip(phis, w_phi):
            st = np.sqrt(1 - mu * mu)
            yield np.array([mu, st * np.cos(phi), st * np.sin(phi)]), wm * wp_


def parallel_camera_towards(direction, half):
    """Parallel camera receiving light that leaves the cube along ``direction``."""
    centre = np.full(3, SIDE / 2)
    up = np.cross(direction, (0.31, 0.9, 0.12))
    return Camera(centre + 5.0 * direction, centre, up, parallel_projection=True,
                  parallel_scale=half)


@pytest.mark.parametrize("g", [0.0, 0.5])
def test_energy_conservation_without_absorption(device, g):
    """Albedo 1: every photon that collides eventually leaves, so the scattered power over
    the whole sphere is P = E a² (1 - e^{-τ}) (light enters the face x = a at normal
    incidence). The radiant intensity J(ω) of each direction is an image-plane integral
    of a parallel camera; the cube's symmetry under y → a - y and z → a - z lets a quarter
    sphere quadrature (×4) integrate it. max_bounces = 64 leaves a negligible part of the
    power inside (a τ = 2 cube keeps photons for a few scatterings on average).
    """
    tau = 2.0
    volume, scene = cube_scene(tau, 1.0, g, n=8)
    half, size = 0.9, 24  # covers the cube's projection (radius √3/2 a) from any side
    total, variance = 0.0, 0.0
    for i, (direction, weight) in enumerate(quarter_sphere_quadrature()):
        scene.camera = parallel_camera_towards(direction, half)
        tracer = PathTracer(volume, scene, size, size, device=device, seed=i, max_bounces=64)
        tracer.run(128)
        pixel_area = (2 * half / size) ** 2
        total += 4 * weight * tracer.radiance[..., 0].astype(np.float64).sum() * pixel_area
        variance += (4 * weight * pixel_area) ** 2 * tracer.radiance_variance[..., 0].sum()
    exact = SIDE**2 * (1 - np.exp(-tau))
    assert abs(total - exact) < 4 * np.sqrt(variance) + 0.005 * exact, (total, exact)
    assert np.sqrt(variance) < 0.005 * exact


def light_tracing_intensity(tau, albedo, g, escape, max_bounces, n_photons=200_000, seed=0):
    """Independent numpy reference: photons from the light, next-event to the camera.

    Photons enter the face x = a of the homogeneous cube uniformly, travelling along -x
    with power E a² each (E = 1); at each of their first ``max_bounces`` collisions the
    power is multiplied by the albedo and the intensity leaving towards ``escape`` is
    ``power · p(d · escape) · exp(-σ · distance to the box along escape)``, with ``d``
    the photon's travel direction; the next travel direction ``d'`` has ``d · d'`` drawn
    from HG. Vectorised over photons. Returns the mean intensity and its standard error.
    """
    rng = np.random.default_rng(seed)
    sigma = tau / SIDE
    x = np.column_stack([np.full(n_photons, SIDE), rng.uniform(0, SIDE, (n_photons, 2))])
    d = np.tile([-1.0, 0.0, 0.0], (n_photons, 1))
    power = np.full(n_photons, SIDE**2)
    contribution = np.zeros(n_photons)

    def exit_distance(p, w):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(w > 0, (SIDE - p) / w, np.where(w < 0, -p / w, np.inf))
        return t.min(axis=1)

    for _ in range(max_bounces):
        t = -np.log1p(-rng.random(n_photons)) / sigma
        power = np.where(t < exit_distance(x, d), power * albedo, 0.0)
        x = x + np.minimum(t, SIDE * 2)[:, None] * d
        escape_length = exit_distance(np.clip(x, 0, SIDE), np.broadcast_to(escape, x.shape))
        contribution += power * hg(d @ escape, g) * np.exp(-sigma * escape_length)
        # HG sampling of the new travel direction about the old one
        u = rng.random(n_photons)
        if abs(g) < 1e-6:
            cos_t = 1 - 2 * u
        else:
            cos_t = (1 + g * g - ((1 - g * g) / (1 - g + 2 * g * u)) ** 2) / (2 * g)
        cos_t = np.clip(cos_t, -1, 1)
        phi = rng.uniform(0, 2 * np.pi, n_photons)
        helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        t1 = np.cross(d, helper)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(d, t1)
        sin_t = np.sqrt(1 - cos_t**2)[:, None]
        d = (sin_t * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
             + cos_t[:, None] * d)
    return contribution.mean(), contribution.std() / np.sqrt(n_photons)


def test_anisotropic_multiple_scattering_matches_light_tracing(device):
    """Camera paths (this module) and light paths (numpy, above) estimate the same
    intensity; with g = 0.6 and an oblique view, getting the orientation of the phase
    function wrong in either NEE or direction sampling changes the answer by many σ."""
    tau, albedo, g, bounces = 2.0, 0.9, 0.6, 6
    escape = np.array([0.45, 0.35, 0.82])
    escape /= np.linalg.norm(escape)
    volume, scene = cube_scene(tau, albedo, g, n=8)
    half, size = 0.9, 24
    scene.camera = parallel_camera_towards(escape, half)
    tracer = PathTracer(volume, scene, size, size, device=device, seed=17, max_bounces=bounces)
    tracer.run(256)
    pixel_area = (2 * half / size) ** 2
    j = tracer.radiance[..., 0].astype(np.float64).sum() * pixel_area
    sigma = np.sqrt(tracer.radiance_variance[..., 0].sum()) * pixel_area
    ref, ref_sigma = light_tracing_intensity(tau, albedo, g, escape, bounces)
    assert abs(j - ref) < 4 * np.hypot(sigma, ref_sigma), (j, ref, sigma, ref_sigma)
    assert np.hypot(sigma, ref_sigma) < 0.015 * ref


def test_same_seed_reproduces_bit_for_bit(device):
    volume, scene = smooth_scene()
    a = render_path(volume, scene, 16, 16, device, None, spp=6, max_bounces=6, seed=42)
    b = render_path(volume, scene, 16, 16, device, None, spp=6, max_bounces=6, seed=42)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.alpha, b.alpha)


def test_different_seeds_differ_but_agree_statistically(device):
    volume, scene = smooth_scene()
    runs = []
    for seed in (1, 2):
        tracer = PathTracer(volume, scene, 16, 16, device=device, seed=seed, max_bounces=4)
        tracer.run(48)
        runs.append((tracer.radiance.astype(np.float64), tracer.radiance_variance))
    (r1, v1), (r2, v2) = runs
    assert not np.array_equal(r1, r2)
    var = v1 + v2
    lit = var > 0
    z = (r1 - r2)[lit] / np.sqrt(var[lit])
    assert 0.6 < np.mean(z**2) < 1.6, np.mean(z**2)
    diff = r1.sum(axis=(0, 1)) - r2.sum(axis=(0, 1))
    assert np.all(np.abs(diff) < 4 * np.sqrt(var.sum(axis=(0, 1))))


def test_error_decreases_like_inverse_sqrt_spp(device):
    """RMS error against a 1024-spp reference after 4, 16 and 64 samples per pixel.

    Expected: e(n)² = v / n + v / 1024, so e(4) / e(64) ≈ 3.9 and e(16) / e(64) ≈ 1.9.
    """
    volume, scene = smooth_scene(albedo=0.9, n=16)
    ref = PathTracer(volume, scene, 12, 12, device=device, seed=100, max_bounces=4).run(1024)
    reference = ref.radiance.astype(np.float64)
    tracer = PathTracer(volume, scene, 12, 12, device=device, seed=7, max_bounces=4)
    errors = {}
    for n in (4, 16, 64):
        tracer.run(n - tracer.samples)
        errors[n] = np.sqrt(np.mean((tracer.radiance - reference) ** 2))
    assert errors[4] > errors[16] > errors[64]
    assert 2.5 < errors[4] / errors[64] < 6.0, errors
    assert 1.4 < errors[16] / errors[64] < 2.8, errors


def test_progressive_api(device):
    volume, scene = smooth_scene()
    tracer = PathTracer(volume, scene, 10, 8, device=device, seed=9, max_bounces=3)
    assert tracer.samples == 0 and tracer.radiance.shape == (8, 10, 3)
    with pytest.raises(ValueError, match="two passes"):
        tracer.radiance_variance
    first = tracer.run(3).radiance
    assert tracer.samples == 3 and first.dtype == np.float32 and first.max() > 0
    # reset restarts the random streams: the same passes give the same image
    again = tracer.reset().run(3)
    np.testing.assert_array_equal(again.radiance, first)
    result = tracer.result()
    assert result.info["spp"] == 3 and result.info["ms_per_pass"] > 0
    assert result.radiance.shape == (8, 10, 3) and result.alpha.shape == (8, 10)
    # a new camera changes the picture
    moved = Camera((3.0, 0.5, 2.0), (0.0, 0.0, 0.0), (0, 1, 0), view_angle=35.0)
    tracer.reset(moved).run(3)
    assert tracer.camera is moved and not np.array_equal(tracer.radiance, first)
    # the tracer's mean equals the average of its passes: 2 runs of 2 == 4 passes at once
    tracer.reset().run(2).run(2)
    four = PathTracer(volume, scene, 10, 8, device=device, seed=9, max_bounces=3,
                      samples_per_pass=1)
    four.reset(moved).run(4)
    np.testing.assert_allclose(tracer.radiance, four.radiance, rtol=1e-6)


def test_render_path_options_and_progress(device):
    volume, scene = smooth_scene()
    scene.options["path"].update(spp=3, max_bounces=2, seed=4)
    seen = []
    result = render_path(volume, scene, 8, 8, device, seen.append)
    assert seen == pytest.approx([1 / 3, 2 / 3, 1.0])
    assert result.info["spp"] == 3 and result.info["max_bounces"] == 2 and result.info["seed"] == 4
    explicit = render_path(volume, scene, 8, 8, device, None, spp=3, max_bounces=2, seed=4)
    np.testing.assert_array_equal(result.radiance, explicit.radiance)
    with pytest.raises(ValueError, match="spp"):
        render_path(volume, scene, 8, 8, device, None, spp=0)
    with pytest.raises(ValueError, match="max_bounces"):
        render_path(volume, scene, 8, 8, device, None, max_bounces=1.5)
    with pytest.raises(ValueError, match="spp"):
        render_path(volume, scene, 8, 8, device, None, spp="many")
    with pytest.raises(ValueError, match="unknown option"):
        render_path(volume, scene, 8, 8, device, None, step_size=0.1)
    with pytest.raises(ValueError, match="Camera"):
        PathTracer(volume, scene, 8, 8, device=device).reset(camera=(0, 0, 5))


def _scattered_power(volume, scene, device, max_bounces, passes=96):
    """Power scattered out of the cube (quarter-sphere quadrature of parallel views)."""
    half, size = 0.9, 24
    total, variance = 0.0, 0.0
    for i, (direction, weight) in enumerate(quarter_sphere_quadrature()):
        scene.camera = parallel_camera_towards(direction, half)
        tracer = PathTracer(volume, scene, size, size, device=device, seed=100 + i,
                            max_bounces=max_bounces)
        tracer.run(passes)
        pixel_area = (2 * half / size) ** 2
        total += 4 * weight * tracer.radiance[..., 0].astype(np.float64).sum() * pixel_area
        variance += (4 * weight * pixel_area) ** 2 * tracer.radiance_variance[..., 0].sum()
    return total, np.sqrt(variance)


def test_default_is_unbiased_in_a_thick_conservative_cube(device):
    """Albedo 1, optical thickness 8: photons scatter dozens of times before they leave.
    The default (no bounce limit, Russian roulette only) conserves the power; the old default
    of 16 bounces loses a visible part of it, so the test can tell the two apart."""
    tau = 8.0
    volume, scene = cube_scene(tau, 1.0, 0.0, n=8)
    exact = SIDE**2 * (1 - np.exp(-tau))
    total, sigma = _scattered_power(volume, scene, device, max_bounces=0)
    assert abs(total - exact) < 4 * sigma + 0.005 * exact, (total, exact, sigma)
    capped, _ = _scattered_power(volume, scene, device, max_bounces=16, passes=32)
    assert capped < 0.95 * exact, (capped, exact)  # measured: 0.90 of it


def test_safety_cap_is_counted_and_reported(device, monkeypatch):
    from vtkillum.core import pathtrace

    volume, scene = cube_scene(8.0, 1.0, 0.0, n=8)
    scene.camera = parallel_camera_towards(np.array([1.0, 0.0, 0.0]), 0.9)
    tracer = PathTracer(volume, scene, 8, 8, device=device, seed=1)
    assert render_path(volume, scene, 8, 8, device, None, spp=2).info["capped_paths"] == 0
    monkeypatch.setattr(pathtrace, "MAX_PATH_VERTICES", 2)
    with pytest.warns(RuntimeWarning, match="safety cap"):
        info = tracer.run(2).result().info
    assert info["capped_paths"] > 0 and info["max_bounces"] == 0
    with pytest.raises(ValueError, match="non-negative"):
        render_path(volume, scene, 8, 8, device, None, spp=1, max_bounces=-1)
