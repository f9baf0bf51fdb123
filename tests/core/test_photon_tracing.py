"""Photon tracing: first interactions in a homogeneous slab (χ²), energy conservation, and
retracing from a stored interaction repeats a trace from scratch bit for bit."""

import numpy as np
import pytest
import warp as wp
from scipy.stats import chisquare

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.photon.emission import make_emitters
from vtkillum.core.photon.storage import ABSORBED, ESCAPED, ORDER_LIMIT
from vtkillum.core.photon.tracing import PhotonMap, photon_medium
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

SIGMA = 3.0  # 1/world units
THICKNESS = 0.75  # slab depth along z (world units)


def slab(n=(8, 8, 16), color=(1.0, 1.0, 1.0)):
    """A homogeneous slab [0, 0.7] x [0, 0.7] x [0, THICKNESS] with extinction SIGMA."""
    spacing = (0.1, 0.1, THICKNESS / (n[2] - 1))
    values = np.full(n, 0.5, np.float32)
    values[0, 0, 0] = 0.0  # a data range for the Historygram bins; opacity is flat anyway
    values[-1, -1, -1] = 1.0
    u = 0.1
    alpha = 1.0 - np.exp(-SIGMA * u)
    tf = TransferFunction([0.0, 1.0], [alpha, alpha], [color, color])
    return Volume(values, spacing=spacing), tf, u


def trace(volume, tf, u, lights, n, albedo=0.9, g=0.0, max_order=0, seed=3, device="cpu",
          step=None):
    medium, _ = photon_medium(volume, tf, u, albedo, g, device)
    emitters, info = make_emitters(lights, volume, n, device)
    pm = PhotonMap(n, device, seed=seed, max_order=max_order,
                   step=step or 0.5 * float(volume.spacing.min()))
    pm.trace(medium, emitters, volume.value_range)
    return pm, info, medium, emitters


def test_first_interactions_follow_exponential(device):
    """Depth of first interactions below the top face: σt exp(-σt z), escapes exp(-σt L)."""
    volume, tf, u = slab()
    n = 40_000
    pm, _, _, _ = trace(volume, tf, u, [DirectionalLight((0.0, 0.0, -1.0))], n, max_order=1,
                        device=device)
    d = pm.numpy()
    assert np.all(d["order"] == 1)
    depth = THICKNESS - d["pos"][:, 2].astype(np.float64)
    edges = np.linspace(0.0, THICKNESS, 21)
    observed, _ = np.histogram(depth, bins=edges)
    observed = np.append(observed, n - len(depth))  # escaped through the bottom
    cdf = 1.0 - np.exp(-SIGMA * edges)
    expected = np.append(np.diff(cdf), np.exp(-SIGMA * THICKNESS)) * n
    assert expected.min() > 20
    p = chisquare(observed, expected).pvalue
    assert p > 1e-3, f"first-interaction depths do not follow σt exp(-σt z): p = {p:.2e}"
    # Every interaction's incoming direction is the light's and its flux E A / N.
    np.testing.assert_allclose(d["dir"], np.tile([0.0, 0.0, -1.0], (len(depth), 1)), atol=1e-6)
    np.testing.assert_allclose(d["flux"], 0.7 * 0.7 / n, rtol=1e-5)


def test_first_interactions_fail_for_wrong_sigma():
    """The χ² test above can fail: the same depths tested against 1.2 σt are rejected."""
    volume, tf, u = slab()
    n = 40_000
    pm, _, _, _ = trace(volume, tf, u, [DirectionalLight((0.0, 0.0, -1.0))], n, max_order=1)
    depth = THICKNESS - pm.numpy()["pos"][:, 2].astype(np.float64)
    edges = np.linspace(0.0, THICKNESS, 21)
    observed = np.append(np.histogram(depth, bins=edges)[0], n - len(depth))
    sigma = 1.2 * SIGMA
    cdf = 1.0 - np.exp(-sigma * edges)
    expected = np.append(np.diff(cdf), np.exp(-sigma * THICKNESS)) * n
    assert chisquare(observed, expected).pvalue < 1e-6


def photon_balance(pm, medium_color, albedo, n, flux0):
    """Per photon: escaped flux + expected absorbed flux - emitted flux (RGB)."""
    d = pm.numpy()
    a = albedo * np.asarray(medium_color, np.float64)
    q = a.max()
    balance = np.zeros((n, 3))
    absorbed = d["flux"].astype(np.float64) * (1.0 - a)
    np.add.at(balance, d["owner"], absorbed)
    count, start, end = d["count"], d["start"], d["end"]
    escaped = end == ESCAPED
    none = escaped & (count == 0)
    balance[none] += flux0
    last = start + count - 1
    some = escaped & (count > 0)
    balance[some] += d["flux"][last[some]].astype(np.float64) * a / q
    return balance - flux0, d


@pytest.mark.parametrize("light", ["directional", "point"])
def test_energy_conservation(device, light):
    """Absorbed + escaped flux equals emitted flux (albedo 0.7, coloured medium, g = 0.5)."""
    volume, tf, u = slab(color=(1.0, 0.6, 0.3))
    n = 20_000
    lights = ([DirectionalLight((0.3, -0.2, -1.0), (2.0, 1.5, 1.0))] if light == "directional"
              else [PointLight((0.35, 0.35, 0.3), (1.0, 2.0, 3.0))])
    pm, info, _, _ = trace(volume, tf, u, lights, n, albedo=0.7, g=0.5, device=device)
    flux0 = info["power"][0] / n
    balance, d = photon_balance(pm, (1.0, 0.6, 0.3), 0.7, n, flux0)
    assert set(np.unique(d["end"])) <= {ESCAPED, ABSORBED}
    assert d["order"].max() > 5  # multiple scattering happened
    mean = balance.mean(axis=0)
    err = balance.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(mean) < 4.0 * err + 1e-9 * flux0), (mean / flux0, err / flux0)
    # Emitted power is what reaches the box: E A (directional) or I Ω (point).
    total = n * flux0
    if light == "directional":
        assert np.all(info["power"][0] > 0)
    else:
        np.testing.assert_allclose(total, np.array([1.0, 2.0, 3.0]) * 4 * np.pi, rtol=1e-6)


def test_energy_balance_detects_missing_roulette_weight():
    """The balance test can fail: dropping the 1/q weight of survivors breaks it."""
    volume, tf, u = slab(color=(1.0, 0.6, 0.3))
    n = 20_000
    pm, info, _, _ = trace(volume, tf, u, [DirectionalLight((0.3, -0.2, -1.0))], n, albedo=0.7,
                           g=0.5)
    flux0 = info["power"][0] / n
    balance, _ = photon_balance(pm, (1.0, 0.6, 0.3), 0.7, n, flux0)
    # Claim the survivors carried Φ a instead of Φ a / q: the books no longer balance.
    wrong, _ = photon_balance(pm, (1.0, 0.6, 0.3), 0.7 * 1.15, n, flux0)
    err = wrong.std(axis=0) / np.sqrt(n)
    assert np.any(np.abs(wrong.mean(axis=0)) > 4.0 * err)
    assert np.all(np.abs(balance.mean(axis=0)) < 4.0 * balance.std(axis=0) / np.sqrt(n))


def test_order_limit_and_retrace_repeats_full_trace(device):
    """S_n bounds the stored orders; retracing photons from stored interactions (or from the
    light) with the stored random state reproduces the full trace exactly."""
    volume, tf, u = slab()
    lights = [DirectionalLight((0.2, 0.1, -1.0))]
    n = 3000
    pm2, _, _, _ = trace(volume, tf, u, lights, n, max_order=2, device=device)
    d2 = pm2.numpy()
    assert d2["order"].max() == 2 and np.any(d2["end"] == ORDER_LIMIT)

    pm, _, medium, emitters = trace(volume, tf, u, lights, n, device=device)
    ref = pm.numpy()
    rng = np.random.default_rng(0)
    photons = np.sort(rng.choice(n, size=500, replace=False)).astype(np.int32)
    restart = np.full(len(photons), -1, np.int32)
    for i, p in enumerate(photons):
        if ref["count"][p] > 0 and i % 3:
            restart[i] = ref["start"][p] + rng.integers(0, ref["count"][p])
    # Change the tails first (retrace them through a more absorbing medium), then retrace
    # them again through the original one from the same interactions.
    other, _ = photon_medium(volume, tf, u, 0.5, 0.0, device)
    rel = np.where(restart >= 0, restart - ref["start"][photons], -1)
    args = (wp.array(photons, dtype=wp.int32, device=device),)
    pm.retrace(other, emitters, volume.value_range, *args,
               wp.array(restart, dtype=wp.int32, device=device))
    changed = pm.numpy()
    assert pm.total != len(ref["pos"])
    restart2 = np.where(rel >= 0, changed["start"][photons] + rel, -1).astype(np.int32)
    stats = pm.retrace(medium, emitters, volume.value_range, *args,
                       wp.array(restart2, dtype=wp.int32, device=device))
    assert stats["photons"] == len(photons)
    got = pm.numpy()
    for key in ("pos", "dir", "flux", "value", "hist", "chist", "rng", "order", "owner", "start",
                "count", "path_hist", "path_chist", "end"):
        np.testing.assert_array_equal(got[key], ref[key], err_msg=key)
