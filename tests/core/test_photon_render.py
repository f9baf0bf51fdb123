"""The ``photon`` render method: agreement with ``single`` (S_n = 1) and convergence to the
path tracer (S_n unbounded), and bad input.

The path-traced reference of the convergence test is stored (``data/photon_ball_path.npz``,
16384 samples per pixel, relative noise 0.95 %); regenerate it with
``python tests/core/test_photon_render.py``.
"""

from pathlib import Path

import numpy as np
import pytest

from vtkillum.core.render import METHODS, render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.data.accuracy_suite import _medium_scene, _side_light, smooth_ball

REFERENCE = Path(__file__).parent / "data" / "photon_ball_path.npz"
SIZE = 24


def ball(optical_diameter):
    """A smooth ball, 24³, albedo 0.95, g 0.3, one directional light: mean free path
    1.4 / optical_diameter world units (2.2 voxels at 8)."""
    volume = smooth_ball(24)
    return volume, _medium_scene(volume, optical_diameter, 0.95, 0.3, [_side_light()])


def rel_rmse(image, reference):
    return float(np.sqrt(np.mean((image - reference) ** 2)) / np.sqrt(np.mean(reference ** 2)))


def test_registered():
    assert METHODS["photon"] == "vtkillum.core.photon.render:render_photon"
    scene = Scene.from_dict({"photon": {"photons": 1000, "direct": "photons"}})
    assert scene.options["photon"]["photons"] == 1000
    assert Scene.from_dict(scene.to_dict()).options["photon"] == scene.options["photon"]
    with pytest.raises(ValueError, match="photon: unknown field"):
        Scene.from_dict({"photon": {"photon_count": 3}})


def test_exact_direct_light_with_single_order_is_single():
    """S_n = 1 with exact direct light: no photon contributes; the image is ``single``'s
    (same samples without jitter)."""
    volume, scene = ball(3.0)
    single = render(volume, scene, "single", SIZE, SIZE, "cpu", jitter=False)
    photon = render(volume, scene, "photon", SIZE, SIZE, "cpu", photons=500, max_order=1,
                    jitter=False)
    np.testing.assert_allclose(photon.radiance, single.radiance, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(photon.alpha, single.alpha, atol=1e-5)


def test_photons_for_single_scattering_match_single():
    """S_n = 1 with the paper's all-photon estimate (eq. 8) agrees with ``single`` within
    5 % (ball of optical diameter 3, 16 progressive passes of 64000 photons)."""
    volume, scene = ball(3.0)
    single = render(volume, scene, "single", SIZE, SIZE, "cpu")
    photon = render(volume, scene, "photon", SIZE, SIZE, "cpu", photons=64000, passes=16,
                    radius=1.5, max_order=1, direct="photons")
    err = rel_rmse(photon.radiance, single.radiance)
    assert err < 0.05, err
    energy = photon.radiance.sum() / single.radiance.sum()
    assert 0.95 < energy < 1.05, energy


def test_converges_to_path_tracer():
    """S_n unbounded, thick high-albedo ball (optical diameter 8, albedo 0.95: 76 % of the
    light has scattered more than once): the error against the path tracer falls with the
    photon count and ends below 5 %."""
    volume, scene = ball(8.0)
    ref = np.load(REFERENCE)["radiance"]
    single = render(volume, scene, "single", SIZE, SIZE, "cpu").radiance
    assert single.sum() < 0.3 * ref.sum()  # multiple scattering dominates
    errors = []
    for photons, passes, radius in ((2000, 1, 2.0), (8000, 4, 2.0), (32000, 16, 1.5)):
        result = render(volume, scene, "photon", SIZE, SIZE, "cpu", photons=photons,
                        passes=passes, radius=radius)
        assert result.info["passes"] == passes
        errors.append(rel_rmse(result.radiance, ref))
    assert errors[0] > errors[1] > errors[2], errors
    assert errors[-1] < 0.05, errors


def test_transparent_transfer_function_gives_black_image():
    volume, scene = ball(3.0)
    scene.transfer_function = TransferFunction([0.0, 1.0], [0.0, 0.0])
    result = render(volume, scene, "photon", 16, 16, "cpu", photons=2000)
    assert np.all(np.isfinite(result.radiance)) and not result.radiance.any()
    assert result.info["photon_update"]["interactions"] == 0
    assert not result.alpha.any()


@pytest.mark.parametrize("option, value, match", [
    ("photons", -1, "integer >= 0"), ("photons", 2.5, "integer >= 0"),
    ("radius", -1.0, "radius must be a number >= 0"), ("max_order", -1, "max_order"),
    ("kernel_photons", 0, "kernel_photons must be a positive integer"),
    ("segments", 0, "segments"), ("direct", "both", "direct"), ("passes", 0, "passes"),
    ("photon_count", 5, "unknown photon option"),
])
def test_bad_options(option, value, match):
    volume, scene = ball(3.0)
    with pytest.raises(ValueError, match=match):
        render(volume, scene, "photon", 8, 8, "cpu", **{option: value})


def test_too_many_photons_says_how_many_fit():
    volume, scene = ball(3.0)
    with pytest.raises(MemoryError, match=r"at most about [\d,]+ photons fit"):
        render(volume, scene, "photon", 8, 8, "cpu", photons=10_000_000, memory_limit_mb=64)


def make_reference(spp: int = 16384) -> None:
    """Path-trace the convergence test's reference and store it."""
    volume, scene = ball(8.0)
    result = render(volume, scene, "path", SIZE, SIZE, spp=spp, seed=1)
    noise = float(np.sqrt(np.mean(result.info["radiance_variance"]))
                  / np.sqrt(np.mean(result.radiance ** 2)))
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, radiance=result.radiance, noise=noise, spp=spp)
    print(f"{REFERENCE}: {spp} spp, relative noise {noise:.4f}")


if __name__ == "__main__":
    make_reference()


def test_progressive_passes_shrink_the_radius_and_average():
    from vtkillum.core.photon.mapper import PhotonMapper, radius_schedule

    radii = radius_schedule(1.0, 6, 2.0 / 3.0)
    assert radii[0] == 1.0 and all(b < a for a, b in zip(radii, radii[1:]))
    # r_{i+1}^3 = r_i^3 (i + alpha) / (i + 1)
    np.testing.assert_allclose(radii[2] ** 3, radii[1] ** 3 * (2 + 2 / 3) / 3)
    volume, scene = ball(3.0)
    m = PhotonMapper("cpu", 3000, 2.0 * volume.mean_spacing(), segments=2)
    m.update(volume, scene.transfer_function, scene.opacity_unit_distance, scene.albedo,
             scene.anisotropy, scene.lights)
    camera, step = scene.resolved_camera(volume), scene.resolved_step_size(volume)
    first = m.render(volume, camera, 16, 16, step)
    refined = m.refine(volume, camera, 16, 16, step, passes=3)
    assert m.passes == 4 and refined.info["passes"] == 4
    assert not np.array_equal(refined.radiance, first.radiance)
    # Nothing changed: a render keeps the average; a budget of 0 s still adds one pass.
    again = m.render(volume, camera, 16, 16, step)
    np.testing.assert_array_equal(again.radiance, refined.radiance)
    m.refine(volume, camera, 16, 16, step, passes=10, budget_s=0.0)
    assert m.passes == 5


def test_gather_reports_progress_on_the_cpu():
    """A long CPU gather says how far it is (the per-segment launch runs in parts), and
    the parts give the image of one launch."""
    from vtkillum.core.photon import segments

    volume, scene = ball(8.0)
    seen = []
    image = render(volume, scene, "photon", SIZE, SIZE, "cpu", photons=4000, jitter=False,
                   progress=seen.append).radiance
    inner = [f for f in seen if 0.3 < f < 1.0]
    assert len(inner) >= segments.CPU_PROGRESS_STEPS // 2 and np.all(np.diff(seen) >= 0)
    volume2, scene2 = ball(8.0)
    old = segments.CPU_PROGRESS_STEPS
    try:
        segments.CPU_PROGRESS_STEPS = 1
        whole = render(volume2, scene2, "photon", SIZE, SIZE, "cpu", photons=4000,
                       jitter=False).radiance
    finally:
        segments.CPU_PROGRESS_STEPS = old
    np.testing.assert_array_equal(image, whole)
