"""Reference-image regression tests: every render method on the procedural datasets.

Each case of ``make_references.CASES`` renders a built-in dataset
(``smoke_plume`` 32×32×48, ``ct_phantom`` 40³ with the camera 1.4× closer,
``cornell_box`` 32³) with its ``default_scene`` on the ``device`` fixture and
compares linear radiance and alpha with ``references/<case>.npz`` (float16);
``references/<case>.png`` is the same image tone-mapped for humans (the exposure,
a power of two, is in the npz). Methods: ``emission``, ``single``,
``transmittance`` (which covers ``illumination``, the ray caster it feeds),
``convection-diffusion`` (diffusion length 3 voxels) and ``ambient-scattering``
(the plume at albedo 0.9, the shipped table's) at 64×64 with the default jitter
and seed; ``path`` at 48×48, 64 samples per pixel, seed 7.

Regenerate the references (CPU; prints a table of the images with mean and max;
look at the PNGs before committing them)::

    python tests/rendering/make_references.py [case ...] [--montage /tmp/refs.png]

Tolerances
----------
Deterministic methods. Radiance errors are relative to the reference's 99.5th
percentile ``s`` over pixels and channels (a robust maximum: the Cornell box's
point light makes a few pixels about 100 times brighter than the mean): mean
``|Δ|/s < 1e-3``, 99.9th percentile ``< 2e-2``; alpha: mean ``|Δα| < 1e-3``, 99.9th
percentile ``< 2e-2``. Measured: the same device reproduces the reference to its
float16 rounding (mean ≤ 1.3e-4, 99.9th percentile ≤ 5.5e-4, alpha ≤ 1.5e-4 and
2.6e-4); a float-order stand-in for CPU vs CUDA (σt × (1 + 2e-6) and the camera
moved by 1e-6 of its distance; both devices use the same jitter hash) changes
none of these beyond that. Deliberate changes, as the largest measure over its
tolerance: σt × 1.1 gives 2.0-9.7 in all 15 cases; swapping red and blue 2.7-84;
flipping the sign of g (the plume's 0.3) 156 (single) and 25 (ambient); a
directional light turned by 2° 1.5-6.6 (single, transmittance, ambient), while
convection-diffusion, whose light volume is diffused and half-resolution, needs
5° (1.4, 2.2; 2° gives 0.5, 0.8); the Cornell point light moved by 0.05 (0.8
voxel) 7-33. (Emission ignores lights and g, transmittance and
convection-diffusion ignore g: those pass unchanged, as designed.)

``path``. Both images carry per-pixel Monte-Carlo standard errors (the
reference's in the npz), and their noise is treated as independent, so the test
holds for any seed and hence any device. Measures: per channel, ``z`` of the
whole-image sum (``|z| < PATH_Z_TOTAL``: brightness and colour); over 16×16-pixel
blocks that received light, mean ``z²`` (``< PATH_CHI2``) and ``max |z|``
(``< PATH_MAX_Z``) of the block means (structure); blocks without light must agree
(``PATH_EMPTY`` of ``s``); alpha (ratio tracking, low noise) as block means
(``PATH_ALPHA_BLOCK``) and image mean (``PATH_ALPHA_MEAN``). Measured over 20
independent seeds per case: at most 0.58 of a tolerance (the same seed with the
float-order perturbation: 0.03). Deliberate changes: red-blue swap 14-550, g
flipped (plume) 130, σt × 1.1 1.8 (plume, through alpha) and 6.6 (CT), the
Cornell point light moved by 0.05 1.7. Below the noise of 64 samples, and
left to the deterministic methods: σt × 1.1 in the Cornell box (0.6: its alpha
is 1 everywhere) and directional lights turned by 2-5° (≤ 0.85).
``test_tolerances_catch_perturbations`` re-checks a selection of these.

On failure the test writes ``<case>_new.npz``, ``<case>_new.png`` and
``<case>_compare.png`` (reference | new | heat map of ``|Δ|``, 4× enlarged) into
its ``tmp_path`` and names that folder in the assertion message.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from vtkillum.core.tonemap import tonemap, write_png


def _load_make_references():
    """``make_references.py`` next to this file, imported by path (tests are no package)."""
    path = Path(__file__).resolve().parent / "make_references.py"
    name = "vtkillum_tests_make_references"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


refs = _load_make_references()

#: Deterministic methods: mean and 99.9th percentile of |Δ radiance| / s, of |Δ alpha|.
MEAN_TOL = 1e-3
P999_TOL = 2e-2
ALPHA_MEAN_TOL = 1e-3
ALPHA_P999_TOL = 2e-2
#: Percentile of the reference radiance that sets the scale s.
SCALE_PERCENTILE = 99.5

#: Path tracing: block size (pixels); bounds on |z| of the per-channel image sums, on the
#: mean z² and max |z| of the block means, on |Δ alpha| of block means and of the image mean.
PATH_BLOCK = 16
PATH_Z_TOTAL = 6.0
PATH_CHI2 = 3.5
PATH_MAX_Z = 6.0
PATH_ALPHA_BLOCK = 8e-3
PATH_ALPHA_MEAN = 1.5e-3
#: Blocks without noise (no light reached them): |Δ| / s of their means.
PATH_EMPTY = 1e-3

DETERMINISTIC = [name for name, case in refs.CASES.items() if case.method != "path"]
PATH = [name for name, case in refs.CASES.items() if case.method == "path"]


# --- comparisons -----------------------------------------------------------------------------
def compare_deterministic(reference: dict, radiance, alpha) -> dict:
    """Error measures of a deterministic render against its reference, and what failed."""
    ref_l = reference["radiance"]
    scale = max(float(np.percentile(ref_l, SCALE_PERCENTILE)), 1e-12)
    err = np.abs(np.asarray(radiance, np.float64) - ref_l) / scale
    err_a = np.abs(np.asarray(alpha, np.float64) - reference["alpha"])
    m = {"scale": scale,
         "mean": float(err.mean()), "p99.9": float(np.percentile(err, 99.9)),
         "alpha_mean": float(err_a.mean()), "alpha_p99.9": float(np.percentile(err_a, 99.9))}
    limits = {"mean": MEAN_TOL, "p99.9": P999_TOL, "alpha_mean": ALPHA_MEAN_TOL,
              "alpha_p99.9": ALPHA_P999_TOL}
    return _judge(m, limits)


def block_means(image, block: int = PATH_BLOCK):
    """Means over ``block`` × ``block`` pixel tiles of an (H, W[, C]) image (H, W multiples)."""
    a = np.asarray(image, dtype=np.float64)
    h, w = a.shape[:2]
    if h % block or w % block:
        raise ValueError(f"image {h}x{w} is not a multiple of the block size {block}")
    return a.reshape(h // block, block, w // block, block, *a.shape[2:]).mean(axis=(1, 3))


def compare_path(reference: dict, radiance, alpha, std) -> dict:
    """Noise-normalised differences of a path-traced render from its reference, and what failed.

    ``std`` is the per-pixel standard error of ``radiance`` (``reference["radiance_std"]``
    that of the reference); the two images' noise is taken as independent.
    """
    new = np.asarray(radiance, np.float64)
    ref = reference["radiance"]
    var_new, var_ref = np.square(np.asarray(std, np.float64)), np.square(reference["radiance_std"])
    # Whole image, per channel: a global brightness or colour change.
    z_total = (new.sum((0, 1)) - ref.sum((0, 1))) / np.sqrt(
        var_new.sum((0, 1)) + var_ref.sum((0, 1)) + 1e-300)
    # Block means (their variance: sum of the pixel variances / n²), over blocks with noise
    # (light reached them): a change of the picture's structure.
    n = PATH_BLOCK * PATH_BLOCK
    var = (block_means(var_new) + block_means(var_ref)) / n
    covered = var > 0
    z = (block_means(new) - block_means(ref))[covered] / np.sqrt(var[covered])
    scale = max(float(np.percentile(ref, SCALE_PERCENTILE)), 1e-12)
    empty = np.abs(block_means(new) - block_means(ref))[~covered] / scale
    d_alpha = block_means(alpha) - block_means(reference["alpha"])
    m = {"z_total": float(np.abs(z_total).max()),
         "chi2": float(np.mean(z * z)) if z.size else 0.0,
         "max_z": float(np.abs(z).max()) if z.size else 0.0,
         "empty": float(empty.max()) if empty.size else 0.0,
         "alpha_block": float(np.abs(d_alpha).max()),
         "alpha_mean": float(abs(d_alpha.mean()))}
    limits = {"z_total": PATH_Z_TOTAL, "chi2": PATH_CHI2, "max_z": PATH_MAX_Z,
              "empty": PATH_EMPTY, "alpha_block": PATH_ALPHA_BLOCK,
              "alpha_mean": PATH_ALPHA_MEAN}
    return _judge(m, limits)


def _judge(m: dict, limits: dict) -> dict:
    """Add ``failed`` (messages) and ``worst`` (largest measure / limit) to the measures."""
    m["failed"] = [f"{k} {m[k]:.3g} > {v:g}" for k, v in limits.items() if not m[k] <= v]
    m["worst"] = max(m[k] / v for k, v in limits.items())
    return m


def write_failure(folder: Path, name: str, reference: dict, result, background) -> Path:
    """Write the new image, its PNG and a reference | new | |Δ| comparison; return the folder."""
    folder = Path(folder)
    exposure = reference["exposure"]
    refs.save_reference(f"{name}_new", result, background, folder, device="test",
                        exposure=exposure)
    old = tonemap(reference["radiance"], reference["alpha"], background, exposure)
    new = tonemap(result.radiance, result.alpha, background, exposure)
    diff = np.abs(np.asarray(result.radiance, np.float64) - reference["radiance"]).max(axis=-1)
    scale = max(float(np.percentile(reference["radiance"], SCALE_PERCENTILE)), 1e-12)
    # Heat map of max-channel |Δ|: black below 0.2 % of s, red at 2 %, yellow from 20 %.
    t = np.clip(np.log10(np.maximum(diff / scale, 1e-6) / 0.02) + 1.0, 0.0, 2.0) / 2.0
    heat = np.stack([np.clip(2 * t, 0, 1), np.clip(2 * t - 1, 0, 1), np.zeros_like(t)], -1)
    heat = np.round(255 * heat).astype(np.uint8)
    side = np.concatenate([old, new, heat], axis=1)
    write_png(folder / f"{name}_compare.png", np.repeat(np.repeat(side, 4, 0), 4, 1))
    return folder


def _check(name, metrics, reference, result, background, tmp_path):
    if metrics["failed"]:
        folder = write_failure(tmp_path, name, reference, result, background)
        shown = {k: round(v, 6) for k, v in metrics.items() if isinstance(v, float)}
        pytest.fail(
            f"{name} differs from references/{name}.npz: {'; '.join(metrics['failed'])} "
            f"(all: {shown}). New image, PNG and reference|new|diff picture written to "
            f"{folder}. If the change is intended, regenerate with "
            f"python tests/rendering/make_references.py {name} and look at the PNG."
        )


# --- tests -----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", DETERMINISTIC)
def test_deterministic_method_matches_reference(name, device, tmp_path):
    case = refs.CASES[name]
    reference = refs.load_reference(name)
    volume, scene = refs.build(case)
    result = refs.render_case(case, device, volume, scene)
    assert result.radiance.shape == reference["radiance"].shape
    metrics = compare_deterministic(reference, result.radiance, result.alpha)
    _check(name, metrics, reference, result, scene.background, tmp_path)


@pytest.mark.parametrize("name", PATH)
def test_path_tracer_matches_reference_within_noise(name, device, tmp_path):
    case = refs.CASES[name]
    reference = refs.load_reference(name)
    volume, scene = refs.build(case)
    result = refs.render_case(case, device, volume, scene)
    assert result.radiance.shape == reference["radiance"].shape
    metrics = compare_path(reference, result.radiance, result.alpha, refs.radiance_std(result))
    _check(name, metrics, reference, result, scene.background, tmp_path)


def _perturbed(name, perturbation):
    """Render case ``name`` on the CPU with one deliberate change; return the result."""
    from vtkillum.core.lights import DirectionalLight, PointLight

    case = refs.CASES[name]
    volume, scene = refs.build(case)
    if perturbation == "sigma_t x1.1":
        scene.opacity_unit_distance = scene.resolved_unit_distance(volume) / 1.1
    elif perturbation == "light turned 2 deg":
        light = scene.lights[0]
        c, s = np.cos(np.radians(2.0)), np.sin(np.radians(2.0))
        d = light.direction
        scene.lights[0] = DirectionalLight((c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]),
                                           light.irradiance)
    elif perturbation == "point light moved 0.05":
        light = scene.lights[0]
        scene.lights[0] = PointLight(light.position + (0.05, 0.0, 0.0), light.intensity)
    elif perturbation == "g flipped":
        scene.anisotropy = -scene.anisotropy
    result = refs.render_case(case, "cpu", volume, scene)
    if perturbation == "red-blue swapped":
        result.radiance = np.ascontiguousarray(result.radiance[..., ::-1])
    return result


@pytest.mark.parametrize("name, perturbation", [
    ("single-plume", "light turned 2 deg"),
    ("single-plume", "g flipped"),
    ("single-cornell", "point light moved 0.05"),
    ("transmittance-ct", "sigma_t x1.1"),
    ("convection-diffusion-plume", "red-blue swapped"),
    ("ambient-scattering-ct", "sigma_t x1.1"),
    ("path-ct", "sigma_t x1.1"),
    ("path-plume", "g flipped"),
])
def test_tolerances_catch_perturbations(name, perturbation):
    """The tolerances are tight enough: a small deliberate change of the scene fails them."""
    reference = refs.load_reference(name)
    result = _perturbed(name, perturbation)
    if refs.CASES[name].method == "path":
        metrics = compare_path(reference, result.radiance, result.alpha, refs.radiance_std(result))
    else:
        metrics = compare_deterministic(reference, result.radiance, result.alpha)
    assert metrics["failed"], f"{name} with {perturbation} passed: {metrics}"


def test_references_are_complete_small_and_consistent():
    """Every case has its npz and PNG, nothing stale, under 1 MiB, PNG = tone map of the npz."""
    folder = refs.REFERENCE_DIR
    files = {p.name for p in folder.iterdir()}
    expected = {f"{n}.{ext}" for n in refs.CASES for ext in ("npz", "png")}
    assert files == expected, (f"missing: {sorted(expected - files)}, stale: "
                               f"{sorted(files - expected)}; run make_references.py")
    total = sum(p.stat().st_size for p in folder.iterdir())
    assert total < 1 << 20, f"references take {total / 1024:.0f} KiB; keep them under 1 MiB"
    from vtkillum.core.tonemap import read_png

    for name, case in refs.CASES.items():
        reference = refs.load_reference(name)
        assert reference["radiance"].shape == (case.size, case.size, 3)
        assert np.all(np.isfinite(reference["radiance"])) and reference["radiance"].max() > 0
        assert ("radiance_std" in reference) == (case.method == "path")
        _, scene = refs.build(case)
        png = read_png(folder / f"{name}.png").astype(int)
        # float16 storage moves a value by at most one 8-bit level.
        again = tonemap(reference["radiance"], reference["alpha"], scene.background,
                        reference["exposure"]).astype(int)
        assert np.abs(png - again).max() <= 1, f"{name}.png is not the tone map of {name}.npz"
