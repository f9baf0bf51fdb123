"""The ray equation (paper eqs. 6–8) against analytic gradient-index optics."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.preintegration import (
    RefractiveMedium,
    data_value,
    make_refractive_medium,
)
from vtkillum.core.refraction.ray_equation import eta_of_value, sample_and_gradient, trace_rays
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.core.warp_common import MAX_TEXTURE_EXTENT, sample_scalar


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


@wp.kernel
def _sample_kernel(m: RefractiveMedium, points: wp.array(dtype=wp.vec3),
                   value: wp.array(dtype=float), exact: wp.array(dtype=float),
                   gradient: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    value[i] = data_value(m, points[i])
    exact[i] = sample_scalar(m.scalars, m.inv_spacing, points[i])
    _s, g, _inside = sample_and_gradient(m, points[i])
    gradient[i] = g


def test_data_samples_are_trilinear_and_the_gradient_central_differences(device):
    """The data texture (CUDA: hardware filtering, 8-bit weights) and the CPU's array give
    the trilinear value, also clamped beyond the faces; ∇η is the central difference of η_tf
    of the samples one voxel either side."""
    rng = np.random.default_rng(3)
    data = rng.random((9, 7, 11)).astype(np.float32)
    spacing = np.array([1.0, 2.0, 0.5])
    volume = Volume(data, spacing=spacing)
    optics = RefractiveOptics([0.0, 0.5, 1.0], [1.0, 1.3, 1.4])  # a kink at 0.5
    m = make_refractive_medium(volume, TransferFunction([0.0], [0.0]), optics, 1.0,
                               device=device)
    n = 400
    points = rng.uniform(-0.2, 1.2, (n, 3)) * volume.extent  # some beyond the faces
    out = [wp.zeros(n, dtype=t, device=device) for t in (float, float, wp.vec3)]
    wp.launch(_sample_kernel, dim=n, device=device,
              inputs=[m, wp.array(points.astype(np.float32), dtype=wp.vec3, device=device),
                      *out])
    value, exact, gradient = (a.numpy() for a in out)
    # 8-bit weights: at most 1/256 of the largest neighbour difference per axis, three axes.
    tol = 1e-6 if device == "cpu" else 3.0 / 256.0
    assert np.abs(value - exact).max() <= tol
    inside = np.all((points >= 0) & (points <= volume.extent), axis=1)
    h = spacing

    def eta(p):
        u = np.clip(p / h, 0, np.array(data.shape) - 1)
        i0 = np.minimum(np.floor(u).astype(int), np.array(data.shape) - 2)
        f = u - i0
        s = 0.0
        for corner in np.ndindex(2, 2, 2):
            w = np.prod([f[a] if corner[a] else 1 - f[a] for a in range(3)])
            s += w * data[tuple(i0 + np.array(corner))]
        return optics.eta_at(s)

    expected = np.array([[(eta(p + e * h) - eta(p - e * h)) / (2 * h[a])
                          for a, e in enumerate(np.eye(3))] for p in points[inside]])
    err = np.abs(gradient[inside] - expected).max() / np.abs(expected).max()
    assert err < (1e-4 if device == "cpu" else 0.05)
    assert np.all(gradient[~inside] == 0.0)


@wp.kernel
def _eta_kernel(m: RefractiveMedium, values: wp.array(dtype=float), eta: wp.array(dtype=float)):
    i = wp.tid()
    eta[i] = eta_of_value(m, values[i])


def test_eta_of_value_interpolates_the_table(device):
    """η_tf(s) is the 4096-entry table interpolated linearly, constant beyond its ends (to the
    float32 rounding of the table coordinate, a thousandth of an entry)."""
    optics = RefractiveOptics([0.0, 0.3, 0.31, 1.0], [1.0, 1.1, 1.5, 1.52])  # a steep step
    volume = Volume(np.linspace(0.0, 1.0, 64, dtype=np.float32).reshape(4, 4, 4))
    m = make_refractive_medium(volume, TransferFunction([0.0], [0.0]), optics, 1.0,
                               device=device)
    table = m.eta.numpy().astype(np.float64)
    entries = np.arange(table.size) / m.table_scale + m.table_lo
    rng = np.random.default_rng(5)
    s = np.concatenate([rng.uniform(-0.2, 1.2, 2000), entries[::97]]).astype(np.float32)
    out = wp.zeros(s.size, dtype=float, device=device)
    wp.launch(_eta_kernel, dim=s.size, device=device,
              inputs=[m, wp.array(s, dtype=float, device=device), out])
    x = np.clip((s.astype(np.float64) - m.table_lo) * m.table_scale, 0, table.size - 1)
    expected = np.interp(x, np.arange(table.size), table)
    step = np.abs(np.diff(table)).max()
    tol = 1e-6 + 1e-3 * step
    assert np.abs(out.numpy() - expected).max() <= tol
    assert np.abs(out.numpy()[-len(entries[::97]):] - table[::97]).max() <= tol


def test_a_volume_beyond_the_texture_extent_is_refused_on_cuda(device):
    volume = Volume(np.zeros((MAX_TEXTURE_EXTENT + 1, 2, 2), np.float32))
    tf = TransferFunction([0.0], [0.0])
    if device == "cpu":  # the CPU samples the array: no limit
        make_refractive_medium(volume, tf, RefractiveOptics(), 1.0, device=device)
        return
    with pytest.raises(ValueError, match="at most 16384 points per axis"):
        make_refractive_medium(volume, tf, RefractiveOptics(), 1.0, device=device)
