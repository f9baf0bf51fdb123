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


def test_device_tone_map_equals_the_host_one():
    """The device tone map (the compute mapper's, downloading 8-bit pixels only) gives the
    host map's bytes, NaN / inf / negatives included, at gamma 1 and 2.2, and flips rows."""
    import warp as wp

    from vtkillum.core.tonemap import tonemap_device

    rng = np.random.default_rng(1)
    rad = (rng.random((37, 29, 3)) * 1.5).astype(np.float32)
    rad[0, 0, 0], rad[0, 1, 1], rad[1, 1, 2] = np.nan, np.inf, -1.0
    alpha = rng.random((37, 29)).astype(np.float32)
    dev = (wp.array(rad, dtype=wp.vec3, device="cpu"), wp.array(alpha, device="cpu"))
    for gamma in (1.0, 2.2):
        host = tonemap(rad, alpha, (0.2, 0.1, 0.3), exposure=1.3, gamma=gamma)
        np.testing.assert_array_equal(tonemap_device(*dev, (0.2, 0.1, 0.3), 1.3, gamma), host)
        np.testing.assert_array_equal(
            tonemap_device(*dev, (0.2, 0.1, 0.3), 1.3, gamma, flip=True), host[::-1])


def test_render_result_reads_device_arrays_lazily():
    import warp as wp

    from vtkillum.core.render import RenderResult

    rad = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
    alpha = np.full((2, 4), 0.5, np.float32)
    result = RenderResult(info={"k": 1}, device=(wp.array(rad, dtype=wp.vec3, device="cpu"),
                                                 wp.array(alpha, device="cpu")))
    np.testing.assert_array_equal(result.radiance, rad)
    np.testing.assert_array_equal(result.alpha, alpha)
    np.testing.assert_array_equal(result.composite((1.0, 1.0, 1.0)), rad + 0.5)
    result.radiance = rad * 2  # a host edit makes the host arrays the result
    assert result.device is None
    with pytest.raises(ValueError, match="needs radiance and alpha"):
        RenderResult(rad, None)
