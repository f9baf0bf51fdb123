"""ConvectionDiffusionSolver (Algorithm 1), composition, rendering, and the path-tracer comparison."""

import numpy as np
import pytest

from vtkillum.core.camera import Camera
from vtkillum.core.convection_diffusion import ConvectionDiffusionSolver
from vtkillum.core.convection_diffusion.diffusion import diffuse_dct, diffusion_length_squared
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import METHODS, render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def blob(n=20, radius=0.6, shift=0.0):
    """A soft ball in [-1, 1]^3 (scalar 1 inside, 0 outside, linear over 0.2)."""
    g = np.linspace(-1.0, 1.0, n)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    r = np.sqrt((x - shift) ** 2 + y**2 + z**2)
    return Volume(np.clip((radius - r) / 0.2 + 0.5, 0.0, 1.0), spacing=(2.0 / (n - 1),) * 3,
                  origin=(-1.0, -1.0, -1.0))


TF = TransferFunction([0.0, 1.0], [0.0, 0.6])
LIGHTS = [DirectionalLight((1.0, -0.5, 0.2), (1.0, 0.6, 0.3)),
          PointLight((0.1, 0.2, -0.1), (0.2, 0.4, 0.8))]


def solver(device, **kw):
    kw.setdefault("scattering", (0.01, 0.02, 0.04))
    return ConvectionDiffusionSolver(device=device, **kw)


def test_composition_is_the_irradiance_weighted_transmittance(device):
    vol = blob()
    cd = solver(device, scattering=(0.0, 0.0, 0.0), light_volume_scale=1.0)
    stats = cd.update(vol, TF, 0.1, LIGHTS)
    assert stats.opacity and stats.convected == [0, 1] and stats.composed
    T0, T1 = cd.transmittance(0, LIGHTS, vol), cd.transmittance(1, LIGHTS, vol)
    h = vol.spacing
    idx = np.stack(np.meshgrid(*(np.arange(n) for n in vol.dims), indexing="ij"), -1)
    d = np.linalg.norm(idx * h + vol.origin - LIGHTS[1].position, axis=-1)
    r_s = 2.0 * h.max()
    expected = T0[..., None] * LIGHTS[0].irradiance + \
        T1[..., None] * LIGHTS[1].intensity / np.maximum(d, r_s)[..., None] ** 2
    np.testing.assert_allclose(cd.fluence, expected, rtol=1e-5)
    np.testing.assert_array_equal(cd.fluence, cd.composed)  # sigma_hat_s = 0: no diffusion


def test_colored_lights_add_linearly(device):
    vol = blob()
    both = solver(device)
    both.update(vol, TF, 0.1, LIGHTS)
    parts = []
    for light in LIGHTS:
        single = solver(device, tolerance=1e-6)
        single.update(vol, TF, 0.1, [light])
        parts.append(single.fluence)
    np.testing.assert_allclose(both.fluence, parts[0] + parts[1], rtol=2e-3,
                               atol=1e-3 * both.fluence.max())
    # ... and the colour of each light scales only its own channel.
    red = solver(device)
    red.update(vol, TF, 0.1, [DirectionalLight(LIGHTS[0].direction, (1.0, 0.0, 0.0))])
    assert red.fluence[..., 1:].max() == 0.0


def test_diffusion_of_the_composed_light_is_the_exact_screened_poisson_solution(device):
    vol = blob()
    cd = solver(device, tolerance=1e-6)
    cd.update(vol, TF, 0.1, LIGHTS)
    exact = diffuse_dct(cd.composed, cd.scattering, cd.spacing)
    np.testing.assert_allclose(cd.fluence, exact, atol=2e-4 * exact.max())
    np.testing.assert_allclose(cd.fluence.sum((0, 1, 2)), cd.composed.sum((0, 1, 2)), rtol=1e-4)


def test_algorithm_1_recomputes_only_what_changed(device):
    vol = blob()
    lights = [DirectionalLight((1.0, 0.0, 0.0)), DirectionalLight((0.0, -1.0, 0.0), (0.5, 0.5, 1.0))]
    cd = solver(device)
    s = cd.update(vol, TF, 0.1, lights)
    assert (s.opacity, s.convected, s.composed, s.diffused) == (True, [0, 1], True, True)
    s = cd.update(vol, TF, 0.1, lights)  # nothing changed
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [], False, False)
    cd.scattering = (0.05, 0.05, 0.05)  # sigma_hat_s: diffusion only
    s = cd.update(vol, TF, 0.1, lights)
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [], False, True)
    lights[1] = DirectionalLight((0.0, -1.0, 0.0), (2.0, 0.0, 0.0))  # colour: recompose only
    s = cd.update(vol, TF, 0.1, lights)
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [], True, True)
    lights[0] = DirectionalLight((1.0, 0.3, 0.0))  # one light moved: that light only
    s = cd.update(vol, TF, 0.1, lights)
    assert (s.opacity, s.convected, s.composed, s.diffused) == (False, [0], True, True)
    edited = TransferFunction([0.0, 1.0], [0.0, 0.9])  # opacity edit: everything
    s = cd.update(vol, edited, 0.1, lights)
    assert (s.opacity, s.convected, s.composed, s.diffused) == (True, [0, 1], True, True)
    cd.update(vol, edited, 0.2, lights).opacity  # unit distance is part of the opacity
    assert cd.update(vol, edited, 0.1, lights).opacity
    # The incrementally updated light volume equals a fresh computation.
    fresh = solver(device, scattering=(0.05, 0.05, 0.05))
    fresh.update(vol, edited, 0.1, lights)
    np.testing.assert_allclose(cd.fluence, fresh.fluence, rtol=1e-3, atol=1e-4)


def test_iteration_budget_refines_progressively(device):
    vol = blob()
    cd = solver(device, scattering=(0.05, 0.05, 0.05), iterations=1, tolerance=1e-5,
                light_volume_scale=1.0)
    first = cd.update(vol, TF, 0.1, LIGHTS)
    assert first.diffusion.iterations == 1 and not first.converged
    residuals = [first.diffusion.residuals[-1]]
    while not cd.converged:
        s = cd.update(vol, TF, 0.1, LIGHTS)  # same inputs: only more diffusion iterations
        assert (s.opacity, s.convected, s.composed) == (False, [], False)
        residuals.append(s.diffusion.residuals[-1])
        assert len(residuals) < 30
    assert np.all(np.diff(residuals) < 0)
    full = solver(device, scattering=(0.05, 0.05, 0.05), tolerance=1e-5, light_volume_scale=1.0)
    full.update(vol, TF, 0.1, LIGHTS)
    np.testing.assert_allclose(cd.fluence, full.fluence, atol=1e-3 * full.fluence.max())


@pytest.mark.parametrize("method", ["cg", "multigrid"])
def test_time_series_warm_start_saves_iterations(device, method):
    steps = [blob(shift=0.02 * t) for t in range(4)]  # a slowly moving ball
    lights = [DirectionalLight((1.0, -0.3, 0.1))]
    opts = dict(scattering=(0.05, 0.05, 0.05), solver=method, tolerance=1e-4,
                light_volume_scale=1.0)
    warm, cold = solver(device, **opts), solver(device, warm_start=False, **opts)
    saved = []
    for t, vol in enumerate(steps):
        w, c = warm.update(vol, TF, 0.1, lights), cold.update(vol, TF, 0.1, lights)
        assert w.converged and c.converged
        assert w.warm_start == (t > 0) and not c.warm_start
        if t > 0:
            saved.append(c.diffusion.iterations - w.diffusion.iterations)
            assert w.diffusion.residuals[0] < 0.5 * c.diffusion.residuals[0]
        np.testing.assert_allclose(warm.fluence, cold.fluence, atol=2e-3 * cold.fluence.max())
    print(f"{method}: diffusion iterations saved per time step by the warm start: {saved}")
    assert min(saved) >= 1


def test_bad_options_are_explained(device):
    vol = blob(8)
    for field, value, match in [("scattering", (1.0, -1.0, 0.0), "scattering"),
                                ("solver", "sor", "solver"), ("tolerance", 0.0, "tolerance"),
                                ("iterations", -1, "iterations"),
                                ("light_volume_scale", 0.0, "light_volume_scale"),
                                ("convection_scheme", "lax", "convection_scheme")]:
        cd = solver(device)
        setattr(cd, field, value)
        with pytest.raises(ValueError, match=match):
            cd.update(vol, TF, 0.1, LIGHTS)
    with pytest.raises(ValueError, match="light"):
        solver(device).update(vol, TF, 0.1, [])
    with pytest.raises(RuntimeError, match="update"):
        solver(device).fluence


# --- rendering ------------------------------------------------------------------------------------
def scene_for(vol, albedo=0.9, lights=None, **cd):
    cam = Camera.looking_at_bounds(vol.bounds, direction=(0.0, 0.0, -1.0))
    sc = Scene(transfer_function=TF, opacity_unit_distance=0.1, albedo=albedo, camera=cam,
               lights=lights or [DirectionalLight((1.0, -0.4, 0.0), (2.0, 2.0, 2.0))],
               options={"convection_diffusion": cd})
    return sc


def test_registered_and_without_diffusion_close_to_single_scattering(device):
    assert METHODS["convection-diffusion"].endswith(":render_convection_diffusion")
    vol = blob(24)
    sc = scene_for(vol, light_volume_scale=1.0)
    cd = render(vol, sc, "convection-diffusion", 32, 32, device=device, jitter=False)
    ref = render(vol, sc, "single", 32, 32, device=device, jitter=False)
    assert cd.info["convection_diffusion"]["shape"] == [24, 24, 24]
    np.testing.assert_allclose(cd.alpha, ref.alpha, atol=1e-5)  # same medium, same rays
    # Upwind shadows are softer than ray-marched ones, but the energy is the same.
    assert cd.radiance.sum() == pytest.approx(ref.radiance.sum(), rel=0.1)
    assert np.abs(cd.radiance - ref.radiance).sum() < 0.2 * ref.radiance.sum()


def test_scene_fields_drive_the_render(device):
    vol = blob(16)
    sc = Scene.from_dict({
        "transfer_function": TF.to_dict(), "opacity_unit_distance": 0.1,
        "lights": [{"type": "point", "position": [0.0, 0.0, 0.0], "intensity": [1, 1, 1]}],
        "convection_diffusion": {"light_volume_scale": 0.5, "scattering": [0.01, 0.02, 0.03],
                                 "solver": "cg", "tolerance": 1e-3, "iterations": 0,
                                 "source_radius": 0.3},
    })
    out = render(vol, sc, "convection-diffusion", 16, 16, device=device)
    info = out.info["convection_diffusion"]
    assert info["shape"] == [8, 8, 8] and info["converged"]
    assert info["residuals"][-1] <= 1e-3 < info["residuals"][0]
    with pytest.raises(ValueError, match="solver"):
        render(vol, sc, "convection-diffusion", 8, 8, device=device, solver="sor")


def test_scattering_makes_a_thick_high_albedo_ball_closer_to_the_path_tracer(device):
    """Optical diameter ~8, albedo 0.98: most light is multiply scattered.

    sigma_hat_s from diffusion theory (no tuning): D / sigma_a = 1 / (3 sigma_t^2 (1 - albedo)).
    Errors: relative L2 over 4x4-pixel blocks (averages out the path tracer's noise).
    """
    n, width = 24, 40
    g = np.linspace(-1.0, 1.0, n)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    vol = Volume(np.clip((0.7 - np.sqrt(x**2 + y**2 + z**2)) / 0.1 + 0.5, 0.0, 1.0),
                 spacing=(2.0 / (n - 1),) * 3, origin=(-1.0, -1.0, -1.0))
    u = vol.mean_spacing()
    tf = TransferFunction([0.0, 1.0], [0.0, 0.4])
    sigma_t = -np.log(1.0 - 0.4) / u
    albedo = 0.98
    sc = Scene(transfer_function=tf, albedo=albedo, lights=[DirectionalLight((1.0, 0.0, 0.0))],
               camera=Camera.looking_at_bounds(vol.bounds, direction=(0.0, 0.0, -1.0)))
    reference = render(vol, sc, "path", width, width, device=device, spp=192, seed=7).radiance

    def blocks(img):
        return img.reshape(width // 4, 4, width // 4, 4, 3).mean(axis=(1, 3))

    def error(img):
        return np.sqrt(((blocks(img) - blocks(reference)) ** 2).sum() / (blocks(reference) ** 2).sum())

    s = diffusion_length_squared(sigma_t, albedo)
    errors = {}
    for name, scattering in (("none", 0.0), ("diffusion", s)):
        img = render(vol, sc, "convection-diffusion", width, width, device=device,
                     scattering=[scattering] * 3).radiance
        errors[name] = error(img)
    print(f"relative L2 vs path tracer: sigma_hat_s=0: {errors['none']:.3f}, "
          f"sigma_hat_s={s:.3f}: {errors['diffusion']:.3f}")
    assert errors["diffusion"] < 0.85 * errors["none"]
