"""χ² tests of Henyey–Greenstein importance sampling (``warp_common.sample_hg``).

``sample_hg(wi, g, u1, u2)`` must draw directions ``w`` whose ``cos θ = wi · w`` follows
the HG density ``2π p(cos θ)`` with CDF

    P(μ) = (1 - g²) / (2g) · [(1 + g² - 2gμ)^(-1/2) - 1 / (1 + g)]     (g ≠ 0)
    P(μ) = (1 + μ) / 2                                                (g = 0)

and an azimuth uniform in [0, 2π) around ``wi``.
"""

import numpy as np
import pytest
import warp as wp
from scipy.stats import chisquare

from vtkillum.core.device import init_warp
from vtkillum.core.warp_common import sample_hg

init_warp()

N_SAMPLES = 200_000
N_BINS = 50
OBLIQUE = (0.3, -0.5, 0.8)


@wp.kernel
def sample_hg_kernel(wi: wp.vec3, g: float, seed: int, out: wp.array(dtype=wp.vec3)):
    """``wp.tid()`` indexes samples; writes one sampled unit direction per sample."""
    i = wp.tid()
    state = wp.rand_init(seed, i)
    u1 = wp.randf(state)
    u2 = wp.randf(state)
    out[i] = sample_hg(wi, g, u1, u2)


def draw(device, wi, g, n=N_SAMPLES, seed=7):
    wi = np.asarray(wi, dtype=np.float64)
    wi /= np.linalg.norm(wi)
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    wp.launch(sample_hg_kernel, dim=n,
              inputs=[wp.vec3(*wi.astype(np.float32)), float(g), seed, out], device=device)
    return wi, out.numpy().astype(np.float64)


def hg_cdf(mu, g):
    """Analytic CDF of cos θ under HG (see module docstring)."""
    mu = np.asarray(mu, dtype=np.float64)
    if abs(g) < 1e-12:
        return (1.0 + mu) / 2.0
    return (1.0 - g * g) / (2.0 * g) * ((1.0 + g * g - 2.0 * g * mu) ** -0.5 - 1.0 / (1.0 + g))


def cos_chi2_pvalue(cos_theta, g):
    edges = np.linspace(-1.0, 1.0, N_BINS + 1)
    observed, _ = np.histogram(np.clip(cos_theta, -1.0, 1.0), bins=edges)
    expected = np.diff(hg_cdf(edges, g)) * cos_theta.size
    assert expected.min() > 5, "bins too sparse for a χ² test"
    return chisquare(observed, expected * observed.sum() / expected.sum()).pvalue


def test_cdf_is_a_cdf():
    for g in (-0.7, 0.0, 0.5, 0.9):
        assert hg_cdf(-1.0, g) == pytest.approx(0.0, abs=1e-12)
        assert hg_cdf(1.0, g) == pytest.approx(1.0, abs=1e-12)
        # derivative equals 2π × the HG phase function
        mu = 0.3
        h = 1e-6
        numeric = (hg_cdf(mu + h, g) - hg_cdf(mu - h, g)) / (2 * h)
        phase = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)
        assert numeric == pytest.approx(2 * np.pi * phase, rel=1e-6)


@pytest.mark.parametrize("g", [-0.7, 0.0, 0.5, 0.9])
def test_cos_theta_follows_hg(device, g):
    wi, w = draw(device, OBLIQUE, g)
    cos_theta = w @ wi
    assert cos_chi2_pvalue(cos_theta, g) > 1e-3
    # the mean cosine of HG is g
    assert cos_theta.mean() == pytest.approx(g, abs=5 * cos_theta.std() / np.sqrt(cos_theta.size))


@pytest.mark.parametrize("g, wrong_g", [(-0.7, 0.7), (0.0, 0.05), (0.5, -0.5), (0.9, -0.9)])
def test_wrong_pdf_is_rejected(device, g, wrong_g):
    """The χ² test has power: the same samples fail against a wrong density."""
    wi, w = draw(device, OBLIQUE, g)
    assert cos_chi2_pvalue(w @ wi, wrong_g) < 1e-10


@pytest.mark.parametrize("wi", [OBLIQUE, (0.0, 0.0, -1.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)])
@pytest.mark.parametrize("g", [0.0, 0.9])
def test_unit_length_and_uniform_azimuth(device, wi, g):
    wi, w = draw(device, wi, g, n=100_000, seed=11)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-5)
    # any orthonormal frame around wi: a uniform azimuth stays uniform under rotation
    helper = np.array([1.0, 0.0, 0.0]) if abs(wi[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(wi, helper)
    t /= np.linalg.norm(t)
    s = np.cross(wi, t)
    phi = np.arctan2(w @ s, w @ t)
    sin_theta = np.sqrt(np.maximum(0.0, 1.0 - (w @ wi) ** 2))
    keep = sin_theta > 1e-3  # the azimuth of a direction along wi is undefined
    observed, _ = np.histogram(phi[keep], bins=36, range=(-np.pi, np.pi))
    assert chisquare(observed).pvalue > 1e-3
    # a deliberately wrong (non-uniform) azimuth density is rejected with the same samples
    edges = np.linspace(-np.pi, np.pi, 37)
    wrong = np.diff(edges + 0.1 * np.sin(edges))
    assert chisquare(observed, wrong / wrong.sum() * observed.sum()).pvalue < 1e-10
