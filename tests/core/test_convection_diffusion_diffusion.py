"""Diffusion step (Zhang & Ma eq. 23): conservation, smoothing, solvers against the exact DCT solve."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.convection_diffusion.diffusion import (
    SOLVERS,
    DiffusionSolver,
    dct2,
    diffuse_dct,
    diffusion_length_squared,
    idct2,
)
from vtkillum.core.convection_diffusion.multigrid import Multigrid

SHAPE = (18, 15, 11)
SPACING = np.array([1.0, 1.2, 0.9])
SCATTERING = np.array([0.0, 2.0, 9.0])  # red channel does not diffuse


def rhs(rng):
    b = rng.random(SHAPE + (3,)).astype(np.float32)
    b[5:9, 4:8, 3:6] += 20.0  # a bright spot
    return b


def vec3(a, device):
    return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=wp.vec3, device=device)


def test_dct_matches_the_textbook_definition(rng):
    x = rng.random((7, 5, 6))
    n = x.shape[1]
    i = np.arange(n)
    basis = np.cos(np.pi * np.outer(np.arange(n), 2 * i + 1) / (2 * n))
    np.testing.assert_allclose(dct2(x, 1), np.einsum("ki,aic->akc", basis, x), atol=1e-12)
    np.testing.assert_allclose(idct2(dct2(x, 2), 2), x, atol=1e-12)


def test_dct_solution_satisfies_the_discrete_equation(rng, device):
    b = rhs(rng)
    x = diffuse_dct(b, SCATTERING, SPACING)
    solver = DiffusionSolver(SHAPE, SPACING, SCATTERING, "multigrid", device)
    np.testing.assert_allclose(solver.apply(vec3(x, device)).numpy(), b, rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("method", SOLVERS)
def test_solvers_converge_to_the_exact_solution(rng, device, method):
    b = rhs(rng)
    exact = diffuse_dct(b, SCATTERING, SPACING)
    solver = DiffusionSolver(SHAPE, SPACING, SCATTERING, method, device)
    x = vec3(b, device)
    report = solver.solve(vec3(b, device), x, max_iterations=3000, tolerance=1e-5)
    assert report.converged, report.residuals[-5:]
    np.testing.assert_allclose(x.numpy(), exact, atol=2e-4 * np.abs(exact).max())
    assert report.residuals[-1] < report.residuals[0] * 1e-3
    # The red channel has sigma_hat_s = 0: untouched.
    np.testing.assert_allclose(x.numpy()[..., 0], b[..., 0], rtol=1e-5)


def test_multigrid_converges_fastest_per_iteration(rng, device):
    b = vec3(rhs(rng), device)
    iterations = {}
    for method in ("multigrid", "cg", "gauss-seidel"):
        x = wp.clone(b)
        report = DiffusionSolver(SHAPE, SPACING, SCATTERING, method, device).solve(
            b, x, max_iterations=3000, tolerance=1e-4)
        iterations[method] = report.iterations
        # Monotone for the smoothers; CG's residual may wiggle but must end below the start.
        if method != "cg":
            assert np.all(np.diff(report.residuals) < 0)
    assert iterations["multigrid"] <= 10
    assert iterations["multigrid"] < iterations["cg"] < iterations["gauss-seidel"]


def test_diffusion_conserves_energy_and_reduces_variance(rng, device):
    b = rhs(rng)
    scattering = np.array([1.0, 3.0, 10.0])
    x = vec3(b, device)
    DiffusionSolver(SHAPE, SPACING, scattering, "multigrid", device).solve(
        vec3(b, device), x, max_iterations=50, tolerance=1e-6)
    out = x.numpy().astype(np.float64)
    np.testing.assert_allclose(out.sum(axis=(0, 1, 2)), b.sum(axis=(0, 1, 2)), rtol=1e-5)
    var = out.var(axis=(0, 1, 2))
    assert np.all(var < b.var(axis=(0, 1, 2)))
    assert var[0] > var[1] > var[2]  # more diffusion, smoother
    assert out.min() >= -1e-4 and out.max() <= b.max()  # maximum principle


def test_diffusion_length_is_sqrt_sigma_hat_s(device):
    # A point source on a long 1D line: the screened-Poisson kernel decays like exp(-r / l).
    n = 201
    b = np.zeros((n, 2, 2, 3), np.float32)
    b[n // 2] = 1.0
    s = np.array([4.0, 16.0, 64.0])
    x = diffuse_dct(b, s, (1.0, 1.0, 1.0))[:, 0, 0]
    r = np.arange(10, 30)
    for c, l in enumerate(np.sqrt(s)):
        rate = -np.polyfit(r, np.log(x[n // 2 + r, c]), 1)[0]
        # Discrete decay rate: cosh(kappa) = 1 + 1 / (2 sigma_hat_s), kappa ~ 1 / l.
        assert rate == pytest.approx(np.arccosh(1 + 0.5 / s[c]), rel=1e-3)
        assert rate == pytest.approx(1.0 / l, rel=0.05)


def test_zero_scattering_leaves_the_light_unchanged(rng, device):
    b = rhs(rng)
    x = vec3(np.zeros_like(b), device)
    report = DiffusionSolver(SHAPE, SPACING, (0, 0, 0), "multigrid", device).solve(
        vec3(b, device), x)
    np.testing.assert_array_equal(x.numpy(), b)
    assert report.converged


def test_multigrid_handles_odd_and_thin_grids(rng, device):
    for shape in ((31, 7, 3), (5, 40, 9), (2, 2, 600)):
        b = rng.random(shape + (3,)).astype(np.float32)
        exact = diffuse_dct(b, (3.0, 3.0, 3.0), (1.0, 1.0, 1.0))
        solver = DiffusionSolver(shape, (1.0, 1.0, 1.0), (3.0, 3.0, 3.0), "multigrid", device)
        x = vec3(b, device)
        report = solver.solve(vec3(b, device), x, max_iterations=40, tolerance=1e-5)
        assert report.converged and report.iterations <= 15, (shape, report.residuals)
        np.testing.assert_allclose(x.numpy(), exact, atol=1e-4)


def test_multigrid_hierarchy_ends_small():
    mg = Multigrid((126, 126, 57), (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), "cpu")
    assert np.prod(mg.shapes[-1]) <= 512
    assert mg.shapes[1] == (63, 63, 29)


def test_bad_inputs_are_explained():
    with pytest.raises(ValueError, match="non-negative"):
        DiffusionSolver(SHAPE, SPACING, (1.0, -1.0, 0.0))
    with pytest.raises(ValueError, match="solver"):
        DiffusionSolver(SHAPE, SPACING, (1.0, 1.0, 1.0), "jacobi")
    with pytest.raises(ValueError, match="albedo"):
        diffusion_length_squared(1.0, 1.0)
    assert diffusion_length_squared(2.0, 0.9) == pytest.approx(1.0 / (3 * 4.0 * 0.1))
