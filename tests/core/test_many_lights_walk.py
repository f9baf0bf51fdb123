"""Virtual-light random walks (``vtkillum.core.many_lights.walk``, paper sections 3.1–3.2).

* χ² tests of the distance sampling (Algorithm 1 by ray marching, delta tracking, and
  the mean transmittance of eq. 8) against the transmittance of a heterogeneous 1D
  medium, integrated here with numpy from the same transfer-function table;
* light-path bookkeeping: counted and written paths agree, vertices lie in the box;
* the first vertices deposit the power the light loses in a homogeneous slab
  (checks the emission geometry, the frozen densities and the contribution weights);
* albedo 0: every VL has zero power, no NaN.
"""

import numpy as np
import pytest
import warp as wp
from scipy.stats import chisquare

from vtkillum.core.device import init_warp
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.many_lights.contribution import evaluate, freeze_densities, segment_depths
from vtkillum.core.many_lights.walk import (
    SAMPLING,
    WalkSetup,
    count_vertices,
    make_sources,
    sample_distance,
    walk_params,
    write_vertices,
)
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import Medium, make_lights, make_medium, uniform

init_warp()

N_SAMPLES = 60_000


@wp.kernel
def distances_kernel(ma: Medium, mb: Medium, mixture: int, sampling: int,
                     step: float, o: wp.vec3, d: wp.vec3, t_end: float, seed: int,
                     out: wp.array(dtype=wp.float32)):
    """``wp.tid()`` indexes samples: one sampled collision distance (``t_end``: none)."""
    i = wp.tid()
    state = wp.rand_init(seed, i)
    use_b = int(0)
    if mixture != 0:
        u, state = uniform(state)
        if u >= 0.5:
            use_b = 1
    hit = bool(False)
    t = float(0.0)
    if use_b != 0:
        hit, t, state = sample_distance(mb, o, d, 0.0, t_end, sampling, step, state)
    else:
        hit, t, state = sample_distance(ma, o, d, 0.0, t_end, sampling, step, state)
    if hit:
        out[i] = t
    else:
        out[i] = t_end


def medium_1d(n=24, seed=5):
    """Heterogeneous along x, constant across: random values per grid plane."""
    rng = np.random.default_rng(seed)
    profile = rng.random(n).astype(np.float32)
    scalars = np.repeat(np.repeat(profile[:, None, None], 3, 1), 3, 2)
    h = 1.0 / (n - 1)
    volume = Volume(scalars, (h, h, h), (0.0, 0.0, 0.0))
    tf = TransferFunction([0.0, 0.3, 1.0], [0.0, 0.08, 0.25])
    return volume, tf, 0.1


def tau_of_t(volume, tf, u, t, scale=1.0):
    """Optical depth from x = 0 along +x to each ``t`` (numpy, fine trapezoid)."""
    sig, _col, lo, hi = tf.lookup_tables(u, volume.value_range)
    xs = np.linspace(0.0, volume.extent[0], 400_001)
    profile = volume.scalars[:, 1, 1].astype(np.float64)
    s = np.interp(xs, np.arange(len(profile)) * volume.spacing[0], profile)
    sigma = scale * np.interp(s, np.linspace(lo, hi, len(sig)), sig)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (sigma[1:] + sigma[:-1]) * np.diff(xs))])
    return np.interp(t, xs, cum)


def draw(device, sampling, scales=(1.0,), step=0.004, seed=11):
    volume, tf, u = medium_1d()
    ma = make_medium(volume, tf, u / scales[0], device=device)
    mb = make_medium(volume, tf, u / scales[-1], device=device)
    out = wp.zeros(N_SAMPLES, dtype=wp.float32, device=device)
    t_end = float(volume.extent[0])
    wp.launch(distances_kernel, dim=N_SAMPLES,
              inputs=[ma, mb, int(len(scales) > 1), SAMPLING[sampling], float(step),
                      wp.vec3(0.0, 0.05, 0.05), wp.vec3(1.0, 0.0, 0.0), t_end, seed, out],
              device=device)
    return volume, tf, u, out.numpy().astype(np.float64), t_end


def chi2_pvalue(t, t_end, cdf):
    """χ² of the sampled distances: 30 equally likely bins in (0, t_end) plus the escapes."""
    grid = np.linspace(0.0, t_end, 20_001)
    levels = np.linspace(0.0, cdf(t_end), 31)
    edges = np.interp(levels, cdf(grid), grid)
    edges[0], edges[-1] = 0.0, t_end
    inside = t < t_end * (1 - 1e-6)
    observed = np.append(np.histogram(t[inside], bins=edges)[0], (~inside).sum())
    probs = np.diff(cdf(edges))
    expected = np.append(probs, 1.0 - cdf(t_end)) * len(t)
    assert expected.min() > 5
    return chisquare(observed, expected * observed.sum() / expected.sum()).pvalue


@pytest.mark.parametrize("sampling", ["ray-marching", "delta-tracking"])
def test_distance_sampling_follows_transmittance(device, sampling):
    volume, tf, u, t, t_end = draw(device, sampling)

    def cdf(x):
        return 1.0 - np.exp(-tau_of_t(volume, tf, u, x))

    assert 0.3 < cdf(t_end) < 0.995  # a test with both collisions and escapes
    assert chi2_pvalue(t, t_end, cdf) > 1e-3
    # The test has power: a medium 15 % denser is rejected.
    assert chi2_pvalue(t, t_end, lambda x: 1.0 - np.exp(-1.15 * tau_of_t(volume, tf, u, x))) < 1e-6


@pytest.mark.parametrize("sampling", ["ray-marching", "delta-tracking"])
def test_mean_transmittance_mixture_eq8(device, sampling):
    """Sampling with S_min or S_max with probability 1/2 follows (T^Smin + T^Smax) / 2."""
    volume, tf, u, t, t_end = draw(device, sampling, scales=(0.3, 3.0))

    def cdf(x):
        tau = tau_of_t(volume, tf, u, x)
        return 1.0 - 0.5 * (np.exp(-0.3 * tau) + np.exp(-3.0 * tau))

    assert chi2_pvalue(t, t_end, cdf) > 1e-3
    assert chi2_pvalue(t, t_end, lambda x: 1.0 - np.exp(-tau_of_t(volume, tf, u, x))) < 1e-6


def slab(n=12, sigma=3.0, albedo=0.8):
    """A homogeneous unit cube of extinction ``sigma`` (1/world units)."""
    h = 1.0 / (n - 1)
    volume = Volume(np.ones((n, n, n), np.float32), (h, h, h), (0.0, 0.0, 0.0))
    u = min(0.1, 1.0 / sigma)  # opacity stays below the clamp of 1 - 1e-6
    tf = TransferFunction([0.0, 1.0], [1 - np.exp(-sigma * u)] * 2)
    return volume, tf, u, albedo


def setup_for(volume, tf, u, albedo, lights, device, sampling="delta-tracking", g=0.0, seed=3):
    medium = make_medium(volume, tf, u, albedo, g, device)
    lights_dev = make_lights(lights, volume, device)
    sources, _ = make_sources(lights, volume, device)
    params = walk_params(seed, sampling, False, False, g, 0.02)
    return WalkSetup(medium, medium, sources, lights_dev, params, device), medium, lights_dev


def trace(setup, medium, lights_dev, n_paths, device):
    counts, path_light, capped = count_vertices(setup, 0, n_paths)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
    total = int(counts.sum())
    pos, geom, incident = write_vertices(setup, np.arange(n_paths, dtype=np.int32), offsets,
                                         total)
    vertex = np.concatenate([np.arange(c) for c in counts]).astype(np.int32)
    light_of = np.repeat(path_light, counts).astype(np.int32)
    vertex_d = wp.array(vertex, dtype=wp.int32, device=device)
    light_d = wp.array(light_of, dtype=wp.int32, device=device)
    tau = wp.zeros(total, dtype=wp.float32, device=device)
    pdf = wp.zeros(total, dtype=wp.float32, device=device)
    segment_depths(medium, lights_dev, pos, vertex_d, light_d, tau, 0.02, device)
    freeze_densities(medium, 1.0, 1.0, pos, geom, tau, pdf, device)
    power = wp.zeros(total, dtype=wp.vec3, device=device)
    direction = wp.zeros(total, dtype=wp.vec3, device=device)
    ext = wp.zeros(total, dtype=wp.float32, device=device)
    evaluate(medium, 1.0, lights_dev, wp.array(offsets, dtype=wp.int32, device=device),
             wp.array(counts, dtype=wp.int32, device=device),
             wp.array(path_light, dtype=wp.int32, device=device), pos, incident, tau, pdf,
             n_paths, power, direction, ext, device)
    return {"counts": counts, "capped": capped, "vertex": vertex, "pos": pos.numpy()[:total],
            "geom": geom.numpy()[:total], "pdf": pdf.numpy(), "power": power.numpy(),
            "direction": direction.numpy()}


def test_counted_and_written_paths_agree(device):
    volume, tf, u, albedo = slab()
    setup, medium, lights_dev = setup_for(volume, tf, u, albedo,
                                          [DirectionalLight((0.3, -1.0, -0.2))], device)
    counts_a, lights_a, _ = count_vertices(setup, 0, 500)
    counts_b, lights_b, _ = count_vertices(setup, 200, 300)  # a later batch: same streams
    np.testing.assert_array_equal(counts_a[200:], counts_b)
    np.testing.assert_array_equal(lights_a[200:], lights_b)
    out = trace(setup, medium, lights_dev, 500, device)
    pos = out["pos"]
    assert len(pos) == counts_a.sum() > 500
    assert np.all(pos >= -1e-5) and np.all(pos <= volume.extent + 1e-5)
    assert np.all(out["geom"] > 0) and np.all(out["pdf"] > 0)
    # Albedo 0.8 with roulette: paths are long enough to scatter several times.
    assert counts_a.max() >= 4


@pytest.mark.parametrize("light", ["directional", "point"])
def test_first_vertices_deposit_the_lost_power(device, light):
    """Sum of first-vertex ``beta sigma_t`` over paths = power that collides once."""
    sigma = 3.0
    volume, tf, u, albedo = slab(sigma=sigma)
    if light == "directional":
        lights = [DirectionalLight((0.0, 0.0, -1.0), (2.0, 2.0, 2.0))]
        expected = 2.0 * 1.0 * (1.0 - np.exp(-sigma * 1.0))  # E * face area * (1 - T)
    else:
        lights = [PointLight((0.5, 0.5, 0.5), (1.5, 1.5, 1.5), radius=1e-6)]
        # 4 pi I (1 - <exp(-sigma d(w))>) over directions from the centre of the cube.
        rng = np.random.default_rng(0)
        w = rng.normal(size=(400_000, 3))
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        exit_d = np.min(0.5 / np.abs(w), axis=1)
        expected = 4 * np.pi * 1.5 * (1.0 - np.mean(np.exp(-sigma * exit_d)))
    setup, medium, lights_dev = setup_for(volume, tf, u, albedo, lights, device)
    n_paths = 20_000
    out = trace(setup, medium, lights_dev, n_paths, device)
    first = out["vertex"] == 0
    # power = beta sigma_s / P = beta sigma_t albedo / P (white)
    deposit = out["power"][first, 0] / albedo * n_paths
    estimate = deposit.sum() / n_paths
    error = deposit.std() / np.sqrt(n_paths)
    assert abs(estimate - expected) < 4 * error + 2e-3 * expected, (estimate, expected, error)
    # Delta tracking, white medium: every first-vertex weight is the same E * A (or 4 pi I).
    assert deposit.std() < 1e-3 * deposit.mean()


def test_albedo_zero_gives_dark_virtual_lights(device):
    volume, tf, u, _ = slab()
    setup, medium, lights_dev = setup_for(volume, tf, u, 0.0,
                                          [DirectionalLight((0.3, -1.0, -0.2))], device)
    out = trace(setup, medium, lights_dev, 300, device)
    assert np.all(np.isfinite(out["power"])) and np.all(out["power"] == 0)
    # The roulette still lets paths go on with probability RR_MIN (edits of the albedo
    # stay unbiased), but they end quickly.
    assert out["counts"].mean() < 3.0


def test_weights_stay_bounded_when_flights_are_below_float_precision(device):
    """Optical depth 1e4 across a unit cube: some delta-tracking flights are shorter than
    the float32 spacing of the positions (a vertex lands on its predecessor). In a white
    homogeneous medium every VL must still carry about the same power."""
    volume, tf, u, albedo = slab(n=6, sigma=1.0e4, albedo=0.99)
    setup, medium, lights_dev = setup_for(volume, tf, u, albedo,
                                          [DirectionalLight((0.3, -1.0, -0.2))], device)
    out = trace(setup, medium, lights_dev, 1500, device)
    pos, vertex = out["pos"], out["vertex"]
    later = np.flatnonzero(vertex > 0)
    assert np.any(np.all(pos[later] == pos[later - 1], axis=1))  # the case is exercised
    power = out["power"][:, 0]
    assert np.all(np.isfinite(power)) and np.all(power > 0)
    assert power.max() / np.median(power) < 1.5, power.max() / np.median(power)
