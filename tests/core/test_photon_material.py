"""The optional BRDF of surface-like samples (vtkillum.core.photon.material): its sampling is
unbiased, it conserves energy, and it changes only surface-like samples."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.material import (
    SurfaceParams,
    brdf_lobe,
    no_surface,
    sample_scattering,
)
from vtkillum.core.render import render
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, smooth_ball

init_warp()


def params(kd=0.6, ks=0.4, shininess=20.0):
    sp = SurfaceParams()
    sp.enabled, sp.lo, sp.hi, sp.grad_min = 1, 0.0, 1.0, 0.0
    sp.kd, sp.ks, sp.shininess = kd, ks, shininess
    return sp


@wp.kernel
def sample_kernel(w_in: wp.vec3, n: wp.vec3, sp: SurfaceParams, surface: int, seed: int,
                  dirs: wp.array(dtype=wp.vec3), weights: wp.array(dtype=wp.float32)):
    """``wp.tid()`` indexes samples: one sampled direction and its weight ``s / pdf``."""
    i = wp.tid()
    state = wp.rand_init(seed, i)
    d, w = sample_scattering(w_in, 0.3, surface, n, sp, wp.randf(state), wp.randf(state))
    dirs[i] = d
    weights[i] = w


@wp.kernel
def lobe_kernel(w_in: wp.vec3, n: wp.vec3, sp: SurfaceParams, dirs: wp.array(dtype=wp.vec3),
                out: wp.array(dtype=wp.float32)):
    """``wp.tid()`` indexes directions: the BRDF lobe ``s(w_in -> dirs[i])``."""
    i = wp.tid()
    out[i] = brdf_lobe(w_in, dirs[i], n, sp)


def sphere_quadrature(n_theta=400, n_phi=800):
    t = (np.arange(n_theta) + 0.5) * np.pi / n_theta
    p = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    T, P = np.meshgrid(t, p, indexing="ij")
    dirs = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    return dirs, (np.sin(T) * (np.pi / n_theta) * (2 * np.pi / n_phi)).reshape(-1)


def integral(w_in, n, sp):
    dirs, dw = sphere_quadrature()
    out = wp.zeros(len(dirs), dtype=wp.float32, device="cpu")
    wp.launch(lobe_kernel, dim=len(dirs), inputs=[wp.vec3(*w_in), wp.vec3(*n), sp,
                                                   wp.array(dirs.astype(np.float32), dtype=wp.vec3),
                                                   out], device="cpu")
    return float((out.numpy() * dw).sum())


@pytest.mark.parametrize("kd, ks", [(1.0, 0.0), (0.6, 0.4), (0.0, 1.0)])
def test_lobe_conserves_energy_and_sampling_is_unbiased(kd, ks):
    w_in = np.array([0.3, -0.2, -0.93])
    w_in /= np.linalg.norm(w_in)
    n = np.array([0.1, 0.2, 0.97])
    n /= np.linalg.norm(n)
    sp = params(kd, ks)
    cos_l = abs(float(w_in @ n))
    total = integral(w_in, n, sp)
    assert total <= cos_l * (kd + ks) * 1.01
    if ks == 0.0:
        assert total == pytest.approx(cos_l * kd, rel=2e-3)  # Lambert
    count = 200_000
    dirs = wp.zeros(count, dtype=wp.vec3, device="cpu")
    weights = wp.zeros(count, dtype=wp.float32, device="cpu")
    wp.launch(sample_kernel, dim=count, inputs=[wp.vec3(*w_in), wp.vec3(*n), sp, 1, 5, dirs,
                                                weights], device="cpu")
    w = weights.numpy().astype(np.float64)
    # Photons leave on the lit side (against their travel direction).
    assert np.all(dirs.numpy() @ n * np.sign(-(w_in @ n)) >= -1e-6)
    assert abs(w.mean() - total) < 4 * w.std() / np.sqrt(count) + 1e-4


def test_without_surface_sampling_is_henyey_greenstein():
    count = 1000
    dirs = wp.zeros(count, dtype=wp.vec3, device="cpu")
    weights = wp.zeros(count, dtype=wp.float32, device="cpu")
    wp.launch(sample_kernel, dim=count, inputs=[wp.vec3(0.0, 0.0, 1.0), wp.vec3(1.0, 0.0, 0.0),
                                                no_surface(), 0, 5, dirs, weights], device="cpu")
    np.testing.assert_array_equal(weights.numpy(), 1.0)


def test_surface_option_changes_only_surface_like_samples():
    volume = smooth_ball(24)
    scene = _medium_scene(volume, 6.0, 0.9, 0.0, [_side_light()])
    base = render(volume, scene, "photon", 24, 24, "cpu", photons=4000, jitter=False)
    outside = render(volume, scene, "photon", 24, 24, "cpu", photons=4000, jitter=False,
                     surface_range=[2.0, 3.0])  # no data value there
    np.testing.assert_array_equal(outside.radiance, base.radiance)
    shiny = render(volume, scene, "photon", 24, 24, "cpu", photons=4000, jitter=False,
                   surface_range=[0.0, 1.0], surface_gradient=0.05)
    assert np.all(np.isfinite(shiny.radiance)) and shiny.radiance.max() > 0
    assert not np.allclose(shiny.radiance, base.radiance, rtol=0.05)
    with pytest.raises(ValueError, match="sum"):
        render(volume, scene, "photon", 8, 8, "cpu", surface_range=[0.0, 1.0],
               surface_diffuse=0.8, surface_specular=0.5)
