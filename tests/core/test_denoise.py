"""Optional denoising (``vtkillum[denoise]``, Intel Open Image Denoise through ``pyoidn``):
what ``vtkillum render --denoise`` denoises, what it keeps raw, and that it removes noise.
The tests that run the denoiser are skipped without ``pyoidn``."""

import numpy as np
import pytest

from vtkillum import cli
from vtkillum.core import denoise as dn
from vtkillum.core.render import RenderResult


def noisy_image(seed=0, n=64):
    """A smooth HDR gradient with 30 % pixel noise (and a fixed seed)."""
    y, x = np.mgrid[0:n, 0:n] / n
    clean = np.stack([1.0 + x, 0.5 + y, 0.8 + 0.5 * x * y], -1).astype(np.float32)
    noise = np.random.default_rng(seed).normal(1.0, 0.3, clean.shape).astype(np.float32)
    return clean, np.maximum(clean * noise, 0.0)


def test_what_is_denoised_and_what_stays_raw(tmp_path):
    clean, noisy = noisy_image()
    result = RenderResult(noisy, np.ones(noisy.shape[:2], np.float32), {"method": "path"})
    assert dn.for_output(result, tmp_path / "a.png", "path", False) is result  # not asked
    assert dn.for_output(result, tmp_path / "a.npy", "photon", True) is result  # raw .npy
    assert dn.for_output(result, tmp_path / "a.npz", "many-lights", True) is result
    with pytest.raises(ValueError, match="--denoise applies to path, photon, many-lights"):
        dn.for_output(result, tmp_path / "a.png", "single", True)


def test_missing_denoiser_is_refused_before_rendering(monkeypatch, capsys):
    monkeypatch.setattr(dn, "available", lambda: False)
    code = cli.main(["render", "builtin:plume:16", "-m", "path", "--denoise", "-o", "x.png"])
    assert code != 0
    assert "pip install 'vtkillum[denoise]'" in capsys.readouterr().err


def test_denoiser_removes_pixel_noise(tmp_path):
    pytest.importorskip("pyoidn")
    clean, noisy = noisy_image()
    out = dn.denoise(noisy)
    assert out.dtype == np.float32 and out.shape == noisy.shape and out.min() >= 0.0

    def err(image):
        return float(np.sqrt(np.mean((image - clean) ** 2)) / np.sqrt(np.mean(clean**2)))

    assert err(out) < 0.5 * err(noisy), (err(out), err(noisy))
    result = RenderResult(noisy, np.ones(noisy.shape[:2], np.float32), {"method": "path"})
    png = dn.for_output(result, tmp_path / "a.png", "path", True)
    assert png.info["denoised"] and np.array_equal(png.radiance, out)
    assert np.array_equal(png.alpha, result.alpha)


def test_command_line_denoises_the_png_only(tmp_path):
    pytest.importorskip("pyoidn")
    common = ["render", "builtin:plume:16", "-m", "path", "--spp", "1", "--size", "24", "24",
              "--device", "cpu", "-q"]
    assert cli.main(common + ["--denoise", "-o", str(tmp_path / "d.npy")]) == 0
    assert cli.main(common + ["-o", str(tmp_path / "r.npy")]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "d.npy"), np.load(tmp_path / "r.npy"))
    assert cli.main(common + ["--denoise", "-o", str(tmp_path / "d.png")]) == 0
    assert cli.main(common + ["-o", str(tmp_path / "r.png")]) == 0
    assert (tmp_path / "d.png").read_bytes() != (tmp_path / "r.png").read_bytes()
