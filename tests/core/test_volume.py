"""Bad volumes get clear errors (or the documented NaN handling); good ones keep their geometry."""

import numpy as np
import pytest

from vtkillum.core.volume import Volume


def test_geometry_and_local_frame():
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90° about z
    v = Volume(np.zeros((3, 5, 2)), spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3), direction=rot)
    assert v.dims == (3, 5, 2) and np.allclose(v.extent, [1.0, 4.0, 2.0])
    far_corner = v.origin + rot @ v.extent
    assert np.allclose(v.to_local(far_corner), v.extent)
    assert np.allclose(v.bounds, [-3.0, 1.0, 2.0, 3.0, 3.0, 5.0])


def test_single_component_4d_is_accepted():
    assert Volume(np.ones((2, 3, 4, 1))).dims == (2, 3, 4)


@pytest.mark.parametrize("shape", [(1, 1, 1), (4, 4, 1), (0, 4, 4)])
def test_degenerate_dimensions(shape):
    with pytest.raises(ValueError, match="at least 2 points along each axis"):
        Volume(np.zeros(shape))


def test_multi_component_is_refused_with_advice():
    with pytest.raises(ValueError, match="one component"):
        Volume(np.zeros((4, 4, 4, 3)))


def test_not_3d():
    with pytest.raises(ValueError, match="3D array"):
        Volume(np.zeros((4, 4)))


def test_complex_or_object_data():
    with pytest.raises(ValueError, match="real numbers"):
        Volume(np.zeros((2, 2, 2), dtype=complex))
    with pytest.raises(ValueError, match="real numbers"):
        Volume(np.full((2, 2, 2), "a"))


@pytest.mark.parametrize("spacing", [(1, 0, 1), (1, -1, 1), (1, np.inf, 1), (1, 1)])
def test_bad_spacing(spacing):
    with pytest.raises(ValueError, match="spacing"):
        Volume(np.zeros((2, 2, 2)), spacing=spacing)


def test_non_orthonormal_direction():
    with pytest.raises(ValueError, match="orthonormal"):
        Volume(np.zeros((2, 2, 2)), direction=np.diag([1.0, 2.0, 1.0]))


def test_nan_raises_by_default_and_fill_replaces_with_minimum():
    a = np.arange(8, dtype=float).reshape(2, 2, 2)
    a[0, 0, 0], a[1, 1, 1] = np.nan, np.inf
    with pytest.raises(ValueError, match="2 sample"):
        Volume(a)
    v = Volume(a, nan_policy="fill")
    assert v.scalars[0, 0, 0] == 1.0 and v.scalars[1, 1, 1] == 1.0 and np.isfinite(v.scalars).all()
    with pytest.raises(ValueError, match="every sample"):
        Volume(np.full((2, 2, 2), np.nan), nan_policy="fill")


def test_input_array_is_not_modified():
    a = np.array([[[np.nan, 1.0], [2.0, 3.0]], [[4.0, 5.0], [6.0, 7.0]]])
    Volume(a, nan_policy="fill")
    assert np.isnan(a[0, 0, 0])
