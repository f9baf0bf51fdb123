"""Transfer functions: piecewise linear, constant outside, σt per DESIGN.md."""

import numpy as np
import pytest

from vtkillum.core.transfer_function import MAX_ALPHA, TransferFunction


def test_piecewise_linear_and_constant_outside():
    tf = TransferFunction([0.0, 1.0, 3.0], [0.0, 0.5, 0.1], [[0, 0, 0], [1, 0, 0], [0, 0, 1]])
    assert np.allclose(tf.alpha([-5, 0, 0.5, 1, 2, 3, 9]), [0, 0, 0.25, 0.5, 0.3, 0.1, 0.1])
    assert np.allclose(tf.color(2.0), [0.5, 0, 0.5])
    assert np.allclose(tf.color(10.0), [0, 0, 1])


def test_sigma_t_matches_opacity_correction():
    """exp(-σt Δ) must equal VTK's opacity correction (1 - α)^(Δ/u)."""
    tf = TransferFunction([0, 1], [0.0, 0.8])
    u, step = 2.0, 0.37
    for s in (0.2, 0.6, 1.0):
        a = tf.alpha(s)
        assert np.isclose(np.exp(-tf.sigma_t(s, u) * step), (1 - a) ** (step / u))


def test_opaque_is_clamped_finite():
    tf = TransferFunction([0, 1], [1.0, 1.0])
    assert np.isfinite(tf.sigma_t(0.5, 1.0))
    assert np.isclose(tf.sigma_t(0.5, 1.0), -np.log1p(-MAX_ALPHA))


def test_lookup_table_covers_data_range():
    tf = TransferFunction([0.2, 0.4], [0.1, 0.9])
    sig, col, lo, hi = tf.lookup_tables(1.0, value_range=(-1.0, 2.0), size=301)
    assert lo == -1.0 and hi == 2.0 and sig.shape == (301,) and col.shape == (301, 3)
    x = np.linspace(lo, hi, 301)
    assert np.allclose(sig, tf.sigma_t(x, 1.0), rtol=1e-6)


@pytest.mark.parametrize("kw, msg", [
    (dict(scalars=[0, 0], opacity=[0, 1]), "strictly increasing"),
    (dict(scalars=[1, 0], opacity=[0, 1]), "strictly increasing"),
    (dict(scalars=[0, 1], opacity=[0, 1, 1]), "one opacity per"),
    (dict(scalars=[0, np.nan], opacity=[0, 1]), "finite"),
    (dict(scalars=[0, 1], opacity=[0, -0.1]), r"\[0, 1\]"),
    (dict(scalars=[0, 1], opacity=[0, 1], colors=[[1, 1]]), "RGB"),
    (dict(scalars=[], opacity=[]), "at least one"),
])
def test_bad_transfer_functions(kw, msg):
    with pytest.raises(ValueError, match=msg):
        TransferFunction(**kw)


def test_bad_unit_distance():
    with pytest.raises(ValueError, match="opacity_unit_distance"):
        TransferFunction([0, 1], [0, 1]).sigma_t(0.5, 0.0)


@pytest.mark.parametrize("field,value", [
    ("scalars", ["0.0", 1.0]),
    ("opacity", [0.0, "0.5"]),
    ("colors", [[1, 1, 1], [1, "0.5", 1]]),
    ("scalars", [False, True]),
    ("opacity", [0.0, None]),
])
def test_strings_and_other_non_numbers_are_refused(field, value):
    """Issue 15 row 10: numpy turned "0.5" into 0.5, while the scene refused "albedo": "0.5"."""
    d = {"scalars": [0.0, 1.0], "opacity": [0.0, 0.5], "colors": [[1, 1, 1], [1, 1, 1]]}
    d[field] = value
    with pytest.raises(ValueError, match=rf"transfer_function\.{field} must hold numbers"):
        TransferFunction.from_dict(d)
    with pytest.raises(ValueError, match=rf"transfer_function\.{field} must hold numbers"):
        TransferFunction(**d)


@pytest.mark.parametrize("far", [1e30, 1e38, 1e308])
def test_control_points_far_outside_the_data_keep_the_table_finite_and_sharp(far):
    """Issue 15 row 3: points at ±1e308 gave NaN table entries (linspace over an infinite
    range) and far points made the table too coarse to see the function over the data."""
    from vtkillum.core.transfer_function import TABLE_SIZE

    tf = TransferFunction([-far, 0.0, 0.5, 1.0, far], [0.0, 0.0, 0.9, 0.0, 0.0])
    sigma, color, lo, hi = tf.lookup_tables(1.0, value_range=(0.0, 1.0))
    assert np.all(np.isfinite(sigma)) and np.all(np.isfinite(color))
    assert np.isfinite(np.float32(lo)) and np.isfinite(np.float32(hi)) and lo < hi
    assert np.isfinite(np.float32(hi) - np.float32(lo))
    v = np.linspace(lo, hi, TABLE_SIZE)
    peak = int(np.argmin(np.abs(v - 0.5)))
    assert sigma[peak] == pytest.approx(-np.log(1 - 0.9), rel=1e-2)  # the peak is resolved
    assert sigma[np.argmin(np.abs(v - 0.0))] == pytest.approx(0.0, abs=1e-2)


def test_table_range_is_unchanged_for_control_points_near_the_data():
    tf = TransferFunction([0.0, 1.0], [0.0, 0.5])
    assert tf.lookup_tables(1.0, value_range=(0.2, 0.7))[2:] == (0.0, 1.0)
    assert tf.lookup_tables(1.0, value_range=(-3.0, 0.5))[2:] == (-3.0, 1.0)
    # a constant volume: the data value and the control points
    assert tf.lookup_tables(1.0, value_range=(0.5, 0.5))[2:] == (0.0, 1.0)


def test_interpolation_between_control_points_at_the_float64_limits():
    """Points at ±1e308: np.interp's slopes overflowed to 0 and held the left value."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warnings either
        tf = TransferFunction([-1e308, 1e308], [0.1, 0.9], [[0, 0, 0], [1, 1, 1]])
        assert tf.alpha(0.0) == pytest.approx(0.5)
        assert tf.alpha([-1e308, 5e307, 1e308]) == pytest.approx([0.1, 0.7, 0.9])
        np.testing.assert_allclose(tf.color(0.0), [0.5, 0.5, 0.5])
        sigma, _, lo, hi = tf.lookup_tables(1.0, value_range=(-1.0, 1.0))
    assert lo == -3.0 and hi == 3.0
    np.testing.assert_allclose(sigma, -np.log(0.5), rtol=1e-5)


def test_far_control_points_do_not_push_values_out_of_their_range():
    """Found by the property test: np.interp's denormal slope across a 1e308 gap turned
    colours 0.0229 -> 0 into -2e-7 (negative radiance in every method)."""
    tf = TransferFunction([-1e308, -1.0, -0.82], [0.05, 0.05, 0.0],
                          [[1e-5, 0.0229, 0.56], [0.0204, 0.0, 0.0], [0.0, 0.0, 0.0]])
    sigma, color, lo, hi = tf.lookup_tables(1.0, value_range=(-1.0, -1.0))
    assert color.min() >= 0.0 and sigma.min() >= 0.0
    assert 0.0 <= tf.color(-2.0)[1] < 1e-300  # 1e-308 of the way from 0.0229 to 0
    assert tf.color(-5e307)[1] == pytest.approx(0.0229 / 2, rel=1e-12)


def test_tables_of_ordinary_functions_match_np_interp():
    rng = np.random.default_rng(3)
    for _ in range(20):
        s = np.sort(rng.normal(size=rng.integers(2, 7))) * rng.choice([1e-3, 1.0, 1e3])
        tf = TransferFunction(s, rng.random(s.size), rng.random((s.size, 3)))
        x = rng.normal(size=500) * 2 * np.abs(s).max()
        np.testing.assert_allclose(tf.alpha(x), np.interp(x, s, tf.opacity), rtol=1e-12,
                                   atol=1e-15)
