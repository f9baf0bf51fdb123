"""Bad volumes get clear errors (or the documented NaN handling); good ones keep their geometry."""

import dataclasses

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


# --- issue 15 row 9: in-place edits cannot leave a stale content key ----------------------------
def _render(volume):
    from vtkillum.core.render import render
    from vtkillum.core.scene import Scene
    from vtkillum.core.transfer_function import TransferFunction

    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.8]))
    return render(volume, scene, "transmittance", 8, 8, "cpu").radiance


def test_edits_of_the_input_array_do_not_reach_the_volume():
    """A float32 input was kept by reference: editing it left the cached key (and renders) stale."""
    a = np.zeros((6, 6, 6), np.float32)
    a[2:4, 2:4, 2:4] = 1.0
    v = Volume(a)
    key, before = v.content_key, _render(v)
    a[...] = 0.0  # the caller reuses its buffer
    assert v.scalars.max() == 1.0
    assert v.content_key == key == Volume(v.scalars.copy()).content_key
    np.testing.assert_array_equal(_render(v), before)
    assert before.max() > 0


def test_the_volume_s_arrays_are_read_only():
    v = Volume(np.ones((3, 3, 3), np.float32), spacing=np.array([1.0, 2.0, 3.0]))
    for name in ("scalars", "spacing", "origin", "direction"):
        array = getattr(v, name)
        assert not array.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            array[(0,) * array.ndim] = 5.0
    with pytest.raises(AttributeError, match="make a new one"):
        v.scalars = np.zeros((3, 3, 3), np.float32)
    edited = v.scalars.copy()
    edited[1, 1, 1] = 7.0
    w = dataclasses.replace(v, scalars=edited)  # the documented way to change the data
    assert w.content_key != v.content_key and w.value_range == (1.0, 7.0)


def test_no_copy_of_another_volume_s_data():
    v = Volume(np.ones((3, 3, 3), np.float32))
    moved = dataclasses.replace(v, origin=(1.0, 2.0, 3.0))
    assert np.shares_memory(moved.scalars, v.scalars)  # read-only already: shared, not copied
    view = np.ones((4, 4, 4), np.float32)[:, :, :3]
    assert not np.shares_memory(Volume(view).scalars, view)
