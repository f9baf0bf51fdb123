"""The ambient-scattering preintegration table: boundary condition, energy, anisotropy, MC error."""

import numpy as np
import pytest

from vtkillum.core.ambient import table as table_module
from vtkillum.core.ambient.table import (
    FORMAT_VERSION,
    PreintegrationTable,
    generate_table,
    load_table,
)


def hg(cos_theta, g):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * np.asarray(cos_theta)) ** 1.5)


@pytest.fixture(scope="module")
def shipped():
    return load_table(0.9, generate=False)


def test_shipped_table_parameters(shipped):
    assert shipped.albedo == pytest.approx(0.9)
    assert shipped.theta[0] == 0 and shipped.theta[-1] == pytest.approx(np.pi)
    assert shipped.sigma[0] == 0 and shipped.sigma_max == pytest.approx(20.0)
    assert shipped.g[0] == pytest.approx(-0.9) and shipped.g[-1] == pytest.approx(0.9)
    assert shipped.g.size == 19 and shipped.samples >= 1000
    assert np.all(np.isfinite(shipped.radiance)) and np.all(shipped.radiance >= 0)


def test_zero_extinction_gives_the_boundary_condition(device):
    # sigma -> 0: nothing scatters, every path crosses the sphere and reads eq. 11 at the
    # antipode, so L~o(theta, 0, g) = p(cos theta; g) exactly.
    th = np.linspace(0, np.pi, 9)
    t = generate_table(theta=th, sigma=[0.0, 1e-3], g=[-0.6, 0.0, 0.6], samples=64, seed=3,
                       device=device, progress=False)
    for k, g in enumerate(t.g):
        np.testing.assert_allclose(t.radiance[:, 0, k], hg(np.cos(th), g), rtol=1e-5)
        np.testing.assert_allclose(t.radiance[:, 1, k], hg(np.cos(th), g), rtol=0.02)
    assert np.all(t.rel_stderr[:, 0] == 0)
    np.testing.assert_allclose(t.transmittance[0], 1.0)


def test_shipped_zero_extinction_column(shipped):
    for k, g in enumerate(shipped.g):
        # float16 storage of ln L: relative quantisation below 0.3 %
        np.testing.assert_allclose(shipped.radiance[:, 0, k], hg(np.cos(shipped.theta), g),
                                   rtol=3e-3)


def test_absorbing_sphere_is_analytic(device):
    # Albedo 0: only unscattered light leaves; the path crosses 2 radii and the boundary
    # value carries exp(-d sigma) with d = max(0, -2 cos theta) at the antipode.
    th = np.linspace(0, np.pi, 7)
    sg = np.array([0.0, 0.25, 0.5, 0.75])
    g = 0.4
    t = generate_table(theta=th, sigma=sg, g=[g], samples=4000, albedo=0.0, seed=5,
                       device=device, progress=False)
    ref = (np.exp(-(2 + np.maximum(0, -2 * np.cos(th)))[:, None] * sg[None])
           * hg(np.cos(th), g)[:, None])
    se = t.stderr[:, :, 0]
    assert np.all(np.abs(t.radiance[:, :, 0] - ref) <= 5 * se + 1e-7)
    # Front transmittance of an absorbing sphere along its axis: Beer-Lambert over 2 radii.
    tt, tse = t.transmittance[:, 0], t.transmittance_stderr[:, 0]
    assert np.all(np.abs(tt - np.exp(-2 * sg)) <= 5 * tse + 1e-7)


def test_scattered_part_is_the_table_less_its_unscattered_light(shipped, device):
    """M = L~o - U with U analytic (table.unscattered): 0 for an absorbing sphere (only
    unscattered light leaves it), 0 without extinction, >= 0 and carrying the rest otherwise."""
    from vtkillum.core.ambient.table import unscattered

    th = np.linspace(0, np.pi, 7)
    absorbing = generate_table(theta=th, sigma=[0.0, 1.0, 2.0], g=[-0.5, 0.4], samples=4000,
                               albedo=0.0, seed=5, device=device, progress=False)
    assert np.all(absorbing.scattered <= 5 * absorbing.stderr + 1e-7)
    assert np.all(shipped.scattered >= 0) and np.all(shipped.scattered[:, 0] == 0)
    u = unscattered(*np.meshgrid(shipped.theta, shipped.sigma, shipped.g, indexing="ij"))
    big = shipped.scattered > 0
    np.testing.assert_allclose(shipped.scattered[big] + u[big], shipped.radiance[big],
                               rtol=1e-5, atol=1e-6)
    # where clipped, L~o is within its Monte-Carlo error (and float16 rounding) of U
    clipped = ~big
    clipped[:, 0] = False
    assert np.all(shipped.radiance[clipped] <= u[clipped] * 1.004 + 4 * shipped.stderr[clipped]
                  + 1e-6)
    # thick spheres: M is all there is (the unscattered light has died out)
    np.testing.assert_allclose(shipped.scattered[:, -1], shipped.radiance[:, -1], rtol=1e-5,
                               atol=1e-9)


def energy_with_error(t):
    w = np.sin(t.theta)
    dth = np.gradient(t.theta)
    energy = t.outgoing_energy()
    err = 2 * np.pi * np.sqrt(np.sum((t.stderr * (w * dth)[:, None, None]) ** 2, axis=0))
    return energy, err


def test_energy_bounded_and_decreasing(shipped):
    energy, err = energy_with_error(shipped)
    # sigma = 0: the phase function's normalisation (trapezoidal rule resolves |g| <= 0.5)
    mid = np.abs(shipped.g) <= 0.5 + 1e-9
    np.testing.assert_allclose(energy[0, mid], 1.0, atol=2e-3)
    # never more than what came in (relative to the same quadrature of the sigma = 0 row)
    assert np.all(energy <= energy[0] + 4 * err + 1e-4)
    # albedo < 1: more extinction, less energy out
    step = np.diff(energy, axis=0)
    bound = 4 * np.sqrt(err[1:] ** 2 + err[:-1] ** 2) + 1e-4
    assert np.all(step <= bound)
    assert np.all(energy[-1] < 0.5 * energy[0])


def test_energy_decreases_on_device(device):
    t = generate_table(n_theta=64, sigma=np.linspace(0, 8, 5), g=[0.0], samples=400, seed=9,
                       device=device, progress=False)
    energy, err = energy_with_error(t)
    assert np.all(np.diff(energy[:, 0]) <= 4 * np.sqrt(err[1:, 0] ** 2 + err[:-1, 0] ** 2))
    assert energy[-1, 0] < energy[0, 0] <= 1.0 + 1e-3


def test_forward_scattering_puts_more_radiance_at_small_theta(shipped):
    small = shipped.theta < np.pi / 4
    fwd = shipped.g_slice(0.6)[small].mean(axis=0)
    bwd = shipped.g_slice(-0.6)[small].mean(axis=0)
    thin = shipped.sigma <= 10
    assert np.all(fwd[thin] > bwd[thin])
    # in thin spheres backward scattering sends more light back towards the light
    large = shipped.theta > 3 * np.pi / 4
    very_thin = shipped.sigma <= 0.5
    assert np.all(shipped.g_slice(-0.6)[large].mean(axis=0)[very_thin]
                  > shipped.g_slice(0.6)[large].mean(axis=0)[very_thin])


def test_front_transmittance(shipped):
    t = shipped.transmittance
    np.testing.assert_allclose(t[0], 1.0)
    se = shipped.transmittance_stderr
    assert np.all(np.diff(t, axis=0) <= 4 * np.sqrt(se[1:] ** 2 + se[:-1] ** 2) + 1e-6)
    k_fwd = int(np.argmin(np.abs(shipped.g - 0.6)))
    k_bwd = int(np.argmin(np.abs(shipped.g + 0.6)))
    assert np.all(t[1:40, k_fwd] > t[1:40, k_bwd])
    assert np.all(t <= 1.0)


def test_row_regenerated_with_another_seed_agrees(shipped, device):
    k_sigma = int(np.argmin(np.abs(shipped.sigma - 2.0)))
    k_g = int(np.argmin(np.abs(shipped.g - 0.3)))
    row = generate_table(theta=shipped.theta, sigma=[shipped.sigma[k_sigma]],
                         g=[shipped.g[k_g]], albedo=shipped.albedo, samples=4096,
                         seed=shipped.seed + 777, device=device, progress=False)
    a = shipped.radiance[:, k_sigma, k_g]
    b = row.radiance[:, 0, 0]
    quant = 2e-3 * a  # float16 storage of ln L
    sigma = np.sqrt(shipped.stderr[:, k_sigma, k_g] ** 2 + row.stderr[:, 0, 0] ** 2 + quant**2)
    z = (a - b) / sigma
    assert np.max(np.abs(z)) < 5.0
    assert np.mean(z**2) < 2.0
    # and the estimate is not trivially within a huge error bar
    assert np.median(row.rel_stderr[:, 0, 0]) < 0.05


def test_g_slice_interpolates_geometrically(shipped):
    k = int(np.argmin(np.abs(shipped.g - 0.5)))
    np.testing.assert_allclose(shipped.g_slice(shipped.g[k]), shipped.radiance[:, :, k])
    mid = 0.5 * (shipped.g[k] + shipped.g[k + 1])
    sl = shipped.g_slice(mid)
    a, b = shipped.radiance[:, 0, k], shipped.radiance[:, 0, k + 1]
    np.testing.assert_allclose(sl[:, 0], np.sqrt(a * b), rtol=1e-5)
    # the sigma = 0 column follows the HG peak much better than a linear blend would
    exact = hg(1.0, mid)
    assert abs(sl[0, 0] - exact) < 0.5 * abs(0.5 * (a[0] + b[0]) - exact)
    np.testing.assert_allclose(shipped.g_slice(5.0), shipped.radiance[:, :, -1])


def test_device_table_slices_equal_the_host_slices(shipped, device):
    # the slices of a g edit are built on the device; they must be the host's, to rounding
    from vtkillum.core.ambient.device_table import DeviceTable

    dt = DeviceTable(shipped, device)
    for g in (shipped.g[3], 0.37, -0.55, 5.0, -5.0, 0.0):
        dt.set_g(g)
        np.testing.assert_allclose(dt.g_slice.numpy(), shipped.g_slice(g), rtol=2e-6, atol=0)
        np.testing.assert_allclose(dt.scattered_slice.numpy(), shipped.scattered_slice(g),
                                   rtol=2e-6, atol=0)
        np.testing.assert_allclose(dt.transmittance_slice.numpy(),
                                   shipped.transmittance_slice(g), rtol=2e-6, atol=1e-7)
    one = PreintegrationTable(shipped.radiance[:, :, :1], shipped.rel_stderr[:, :, :1],
                              shipped.theta, shipped.sigma, shipped.g[:1], shipped.albedo,
                              shipped.samples, shipped.transmittance[:, :1],
                              shipped.transmittance_stderr[:, :1])
    dt = DeviceTable(one, device)
    dt.set_g(0.4)
    np.testing.assert_array_equal(dt.g_slice.numpy(), one.radiance[:, :, 0])
    np.testing.assert_array_equal(dt.scattered_slice.numpy(), one.scattered[:, :, 0])
    np.testing.assert_array_equal(dt.transmittance_slice.numpy(), one.transmittance[:, 0])


def test_lookup_matches_grid_values(shipped):
    i, j, k = 10, 20, 12
    val = shipped.lookup(shipped.theta[i], shipped.sigma[j], shipped.g[k])
    assert float(val) == pytest.approx(float(shipped.radiance[i, j, k]), rel=1e-6)


def test_file_round_trip_and_version_check(tmp_path, device):
    t = generate_table(n_theta=5, n_sigma=4, n_g=3, samples=32, seed=1, device=device,
                       progress=False)
    path = t.save(tmp_path / "t.npz")
    u = PreintegrationTable.load(path)
    # float16 ln L: half a unit in the last place is 2^-11 |ln L|
    pos = t.radiance > 0
    assert np.all(u.radiance[~pos] == 0)
    assert np.all(np.abs(np.log(u.radiance[pos]) - np.log(t.radiance[pos]))
                  <= 2.0**-11 * np.abs(np.log(t.radiance[pos])) + 1e-6)
    np.testing.assert_allclose(u.transmittance, t.transmittance)
    assert (u.albedo, u.samples, u.seed) == (t.albedo, t.samples, t.seed)
    np.testing.assert_array_equal(u.sigma, t.sigma)
    data = dict(np.load(path))
    data["format_version"] = np.int32(FORMAT_VERSION + 1)
    np.savez(tmp_path / "old.npz", **data)
    with pytest.raises(ValueError, match="regenerate"):
        PreintegrationTable.load(tmp_path / "old.npz")
    np.savez(tmp_path / "junk.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not an ambient-scattering table"):
        PreintegrationTable.load(tmp_path / "junk.npz")


def test_generate_progress_and_bad_input(device):
    seen = []
    generate_table(n_theta=3, n_sigma=3, n_g=1, samples=8, device=device, progress=seen.append)
    assert seen and seen[-1] == 1.0
    with pytest.raises(ValueError, match="albedo"):
        generate_table(albedo=1.5, n_theta=3, n_sigma=3, n_g=1, samples=8, device=device)
    with pytest.raises(ValueError, match="samples"):
        generate_table(n_theta=3, n_sigma=3, n_g=1, samples=1, device=device)


def test_missing_albedo_is_generated_on_demand_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("VTKILLUM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(table_module, "ON_DEMAND",
                        {"n_theta": 6, "n_sigma": 5, "n_g": 3, "samples": 16})
    monkeypatch.setattr(table_module, "_LOADED", {})
    monkeypatch.setattr(table_module, "load_albedo_tables", lambda: None)  # none installed
    with pytest.raises(FileNotFoundError, match="python -m vtkillum.core.ambient.table"):
        load_table(0.55, generate=False)
    t = load_table(0.55, device="cpu", progress=False)
    assert t.albedo == pytest.approx(0.55) and t.shape == (6, 5, 3)
    assert (tmp_path / "ambient_table_a0.55.npz").exists()
    monkeypatch.setattr(table_module, "_LOADED", {})
    again = load_table(0.55, generate=False)
    np.testing.assert_array_equal(again.radiance, t.radiance)


def test_command_line(tmp_path, capsys):
    out = tmp_path / "cli.npz"
    assert table_module.main(["--device", "cpu", "--theta", "4", "--sigma", "3", "--g", "3",
                              "--samples", "16", "--quiet", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Monte-Carlo error" in text and "paths/s" in text and out.exists()
    assert PreintegrationTable.load(out).shape == (4, 3, 3)


# --- issue 13: tables over albedo, interpolated; chunked, interruptible generation -------------
from vtkillum.core.ambient.table import (  # noqa: E402
    AlbedoTables,
    albedo_zero_table,
    interpolate_albedo,
)


@pytest.fixture(scope="module")
def small_stack():
    """Tables at three albedos (6 theta x 5 sigma x 3 g, 64 paths: fast, noisy)."""
    return AlbedoTables([generate_table(albedo=a, n_theta=6, n_sigma=5, n_g=3, samples=64,
                                        seed=2, device="cpu", progress=False)
                         for a in (0.9, 0.5, 0.8)])


def test_albedo_tables_file_round_trip(small_stack, tmp_path):
    path = small_stack.save(tmp_path / "stack.npz")
    back = AlbedoTables.load(path)
    np.testing.assert_array_equal(back.albedos, [0.5, 0.8, 0.9])  # sorted
    for a, b in zip(small_stack.tables, back.tables):
        pos = a.radiance > 0
        assert np.all(back.at(a.albedo).radiance[~pos] == 0)
        assert np.all(np.abs(np.log(b.radiance[pos]) - np.log(a.radiance[pos]))
                      <= 2.0**-11 * np.abs(np.log(a.radiance[pos])) + 1e-6)
        np.testing.assert_allclose(b.rel_stderr, np.minimum(a.rel_stderr, 0.255), atol=5e-4)
        np.testing.assert_array_equal(b.transmittance, a.transmittance)
        assert (b.albedo, b.samples, b.seed) == (a.albedo, a.samples, a.seed)
    with pytest.raises(ValueError, match="not an ambient-scattering table"):
        PreintegrationTable.load(path)  # a multi-albedo file is not a single table
    np.savez(tmp_path / "junk.npz", x=np.zeros(2))
    with pytest.raises(ValueError, match="multi-albedo"):
        AlbedoTables.load(tmp_path / "junk.npz")


def test_interpolation_between_albedos(small_stack):
    lo, hi = small_stack.tables[1], small_stack.tables[2]  # 0.8, 0.9
    t = small_stack.at(0.85)
    assert t.albedo == pytest.approx(0.85) and "interpolated" in t.info
    both = (lo.radiance > 0) & (hi.radiance > 0)
    np.testing.assert_allclose(t.radiance[both], np.sqrt(lo.radiance * hi.radiance)[both],
                               rtol=1e-4)
    assert small_stack.at(0.9) is hi  # tabulated albedos as they are
    # below the first albedo: towards the exact albedo-0 table
    zero = small_stack.at(0.0)
    np.testing.assert_allclose(zero.radiance, albedo_zero_table(lo).radiance)
    mid = small_stack.at(0.25)
    first = small_stack.tables[0]
    ok = (first.radiance > 0) & (zero.radiance > 0)
    np.testing.assert_allclose(mid.radiance[ok], np.sqrt(zero.radiance * first.radiance)[ok],
                               rtol=1e-4)
    with pytest.raises(ValueError, match="outside"):
        small_stack.at(0.95)
    with pytest.raises(ValueError, match="other axes"):
        AlbedoTables([lo, generate_table(albedo=0.7, n_theta=4, n_sigma=5, n_g=3, samples=8,
                                         device="cpu", progress=False)])
    with pytest.raises(ValueError, match="different axes"):
        interpolate_albedo(lo, albedo_zero_table(generate_table(
            albedo=0.1, n_theta=4, n_sigma=3, n_g=1, samples=4, device="cpu",
            progress=False)), 0.5)


def test_albedo_zero_table_is_what_the_path_tracer_gives():
    t = generate_table(albedo=0.0, n_theta=5, sigma=[0.0, 0.3, 0.6, 0.9], n_g=3,
                       samples=4000, seed=5, device="cpu", progress=False)
    exact = albedo_zero_table(t)
    assert np.all(np.abs(t.radiance - exact.radiance) <= 5 * t.stderr + 1e-5 * exact.radiance)
    np.testing.assert_allclose(t.transmittance, exact.transmittance, atol=0.03)


def test_geometric_interpolation_is_as_good_as_the_noise():
    """Interpolating 0.8 and 0.9 to 0.85 differs from a table made at 0.85 by about the
    tables' own Monte-Carlo noise (L1, radiance-weighted)."""
    kw = dict(n_theta=12, n_sigma=12, n_g=3, samples=2048, device="cpu", progress=False)
    lo, mid, hi = (generate_table(albedo=a, seed=7 + n, **kw)
                   for n, a in enumerate((0.8, 0.85, 0.9)))
    got = interpolate_albedo(lo, hi, 0.85)
    l1 = np.abs(got.radiance - mid.radiance).sum() / mid.radiance.sum()
    noise = np.abs(mid.stderr).sum() / mid.radiance.sum()
    assert l1 < 1.5 * noise + 0.005, (l1, noise)


def test_load_table_interpolates_from_the_shipped_stack(small_stack, tmp_path, monkeypatch):
    data = tmp_path / "data"
    data.mkdir()
    small_stack.save(data / table_module.ALBEDOS_FILENAME)
    monkeypatch.setattr(table_module, "DATA_DIR", data)
    monkeypatch.setenv("VTKILLUM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(table_module, "_LOADED", {})

    def no_generation(*args, **kwargs):
        raise AssertionError("nothing may be generated")

    monkeypatch.setattr(table_module, "generate_table", no_generation)
    t = load_table(0.83)  # generate=True, but the stack covers it
    assert t.albedo == pytest.approx(0.83) and t.shape == small_stack.shape
    assert load_table(0.83) is t  # kept
    with pytest.raises(FileNotFoundError, match="ambient_tables_albedo.npz"):
        load_table(0.97, generate=False)
    lines = table_module.describe_tables()
    assert any("albedos 0.5, 0.8, 0.9" in line for line in lines)
    # a table for exactly that albedo wins over the stack
    small_stack.tables[0].save(data / table_module.table_filename(0.5))
    monkeypatch.setattr(table_module, "_LOADED", {})
    assert load_table(0.5).info.get("interpolated") is None


def test_shipped_single_albedo_table_still_first(shipped):
    assert load_table(0.9) is shipped or load_table(0.9).shape == shipped.shape


def test_generation_is_chunked_and_the_same(monkeypatch):
    """Launches of at most PATHS_PER_LAUNCH paths (Ctrl-C is seen between them); the
    chunking does not change the table."""
    kw = dict(albedo=0.8, n_theta=6, n_sigma=5, n_g=3, samples=16, seed=4, device="cpu")
    # 90 entries: with these budgets one path per entry per pass, entries in chunks of
    # 89, 50 or 37 (seeds depend on the pass and the entry, not on the chunk)
    tables = []
    for budget in (89, 50, 37):
        monkeypatch.setitem(table_module.PATHS_PER_LAUNCH, "cpu", budget)
        seen = []
        tables.append(generate_table(progress=seen.append, **kw))
        assert len(seen) >= 16 * 3  # passes x (two entry chunks at least, a front chunk)
    for t in tables[1:]:
        np.testing.assert_array_equal(t.radiance, tables[0].radiance)
        np.testing.assert_array_equal(t.transmittance, tables[0].transmittance)


def test_ctrl_c_stops_generation_and_writes_nothing(monkeypatch, tmp_path, capsys):
    calls = []

    def interrupt(fraction):
        calls.append(fraction)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_table(n_theta=6, n_sigma=5, n_g=3, samples=16, device="cpu", progress=interrupt)
    assert len(calls) == 2

    def raise_interrupt(**kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(table_module, "generate_table", raise_interrupt)
    out = tmp_path / "t.npz"
    assert table_module.main(["--device", "cpu", "--quiet", "--out", str(out)]) == 130
    assert table_module.main(["--device", "cpu", "--quiet", "--albedos", "0.5,0.9",
                              "--out", str(out)]) == 130
    assert not out.exists() and "interrupted" in capsys.readouterr().err


def test_command_line_writes_a_multi_albedo_file(tmp_path, capsys):
    out = tmp_path / "stack.npz"
    assert table_module.main(["--device", "cpu", "--albedos", "0.6,0.9", "--theta", "4",
                              "--sigma", "3", "--g", "1", "--samples", "8", "--quiet",
                              "--out", str(out)]) == 0
    assert "albedos 0.6, 0.9" in capsys.readouterr().out
    stack = AlbedoTables.load(out)
    assert stack.shape == (4, 3, 1) and stack.at(0.7).albedo == pytest.approx(0.7)
