"""The tone map: the formula of the module docstring, its special values, and its bands."""

import numpy as np
import pytest

from vtkillum.core.tonemap import CHUNK_PIXELS, tonemap


def reference(radiance, alpha, background, exposure, gamma):
    """``round(255 clip(e (L + (1 - a) bg), 0, 1) ** (1/gamma))`` in float64, NaN -> 0."""
    x = exposure * (radiance.astype(np.float64)
                    + (1.0 - alpha.astype(np.float64))[..., None] * np.asarray(background))
    x = np.clip(np.nan_to_num(x, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    return np.rint(255.0 * x ** (1.0 / gamma)).astype(np.uint8)


@pytest.mark.parametrize("gamma", [1.0, 2.2])
@pytest.mark.parametrize("background", [(0.0, 0.0, 0.0), (0.1, 0.4, 0.7), 0.3])
def test_matches_the_formula_over_several_bands(gamma, background):
    rng = np.random.default_rng(3)
    h = CHUNK_PIXELS // 300 + 7  # more than one band
    radiance = (rng.random((h, 300, 3)) * 1.4).astype(np.float32)
    alpha = rng.random((h, 300)).astype(np.float32)
    out = tonemap(radiance, alpha, background, exposure=0.9, gamma=gamma)
    expected = reference(radiance, alpha, background, 0.9, gamma)
    # float32 arithmetic: at most one level off where the value sits on a rounding edge
    assert np.abs(out.astype(int) - expected).max() <= 1
    assert np.mean(out != expected) < 1e-3


def test_special_values():
    radiance = np.array([[[np.nan, np.inf, -np.inf], [2.0, -1.0, 0.5]]], np.float32)
    out = tonemap(radiance, np.ones((1, 2), np.float32), (0.2, 0.2, 0.2), gamma=1.0)
    assert out.tolist() == [[[0, 255, 0], [255, 0, 128]]]
