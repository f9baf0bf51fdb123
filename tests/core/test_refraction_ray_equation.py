"""The ray equation (paper eqs. 6–8) against analytic gradient-index optics."""

import numpy as np
import pytest

from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.ray_equation import trace_rays
from vtkillum.core.volume import Volume


def grin_slab(eta0=1.2, gradient=0.02, h=0.5):
    """Data = y (world units), η = eta0 + gradient * y: a linear-gradient (GRIN) slab."""
    n = (64, 40, 8)
    y = np.arange(n[1]) * h
    volume = Volume(np.broadcast_to(y[None, :, None], n).astype(np.float32), spacing=(h, h, h))
    return volume, RefractiveOptics([0.0, 100.0], [eta0, eta0 + gradient * 100.0])


@pytest.mark.parametrize("dz", [0.5, 0.25])
def test_grin_slab_bends_rays_along_the_catenary(device, dz):
    """d/ds(η dx/ds) = ∇η with η = η0 + g y and a ray starting along x at height y0:
    y = y0 + (η(y0)/g)(cosh(g x / η(y0)) - 1), the parabola g x² / (2 η) for small g x."""
    eta0, g, y0 = 1.2, 0.02, 4.0
    volume, optics = grin_slab(eta0, g)
    start = np.array([[0.5, y0, 2.0]])
    path = trace_rays(volume, optics, start, [[1.0, 0.0, 0.0]], (1.0, 0.0, 0.0), dz,
                      int(30 / dz), device=device)[:, 0]
    e = eta0 + g * y0
    x = path[:, 0] - 0.5
    catenary = y0 + (e / g) * (np.cosh(g * x / e) - 1.0)
    parabola = y0 + g * x ** 2 / (2.0 * e)
    assert np.abs(path[:, 1] - catenary).max() < 0.01  # world units; voxels are 0.5
    assert np.abs(path[:, 2] - 2.0).max() < 1e-4  # no bending across the gradient
    # The parabola is the paraxial limit: close to it, and measurably bent (7 world units).
    assert np.abs(path[-1, 1] - parabola[-1]) < 0.02 * (parabola[-1] - y0)
    assert path[-1, 1] - y0 > 7.0


def test_constant_index_keeps_rays_straight(device):
    volume, _ = grin_slab()
    optics = RefractiveOptics([0.0], [1.5])  # constant: no gradient anywhere
    d = np.array([[1.0, 0.3, 0.1]])
    path = trace_rays(volume, optics, [[0.5, 4.0, 1.0]], d, (1.0, 0.0, 0.0), 0.5, 40,
                      device=device)[:, 0]
    expected = np.array([0.5, 4.0, 1.0]) + np.outer(path[:, 0] - 0.5, d[0] / d[0, 0])
    np.testing.assert_allclose(path, expected, atol=1e-4)


def test_bending_follows_the_gradient_sign(device):
    """Rays bend towards the higher index (light slows down there)."""
    up_volume, up = grin_slab(1.2, 0.02)
    down = RefractiveOptics([0.0, 100.0], [3.2, 1.2])  # index falling with y
    a = trace_rays(up_volume, up, [[0.5, 8.0, 2.0]], [[1, 0, 0]], (1, 0, 0), 0.5, 40, device=device)
    b = trace_rays(up_volume, down, [[0.5, 8.0, 2.0]], [[1, 0, 0]], (1, 0, 0), 0.5, 40,
                   device=device)
    assert a[-1, 0, 1] > 8.5 and b[-1, 0, 1] < 7.5


def test_bad_plane_spacing():
    volume, optics = grin_slab()
    with pytest.raises(ValueError, match="dz"):
        trace_rays(volume, optics, [[0, 0, 0]], [[1, 0, 0]], (1, 0, 0), 0.0, 4, device="cpu")
