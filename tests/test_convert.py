"""VTK <-> core conversion: index order, geometry, array choice and bad input."""

import numpy as np
import pytest
from vtkmodules.util.numpy_support import numpy_to_vtk
from vtkmodules.vtkCommonCore import vtkStringArray
from vtkmodules.vtkCommonDataModel import (
    vtkImageData,
    vtkPiecewiseFunction,
    vtkPolyData,
    vtkStructuredPoints,
    vtkUniformGrid,
)
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.io.convert import (
    add_point_array,
    image_data_from_volume,
    image_like,
    point_array,
    transfer_function_from_vtk,
    transfer_function_to_vtk,
    volume_from_image_data,
)


def make_image(dims=(5, 4, 3), cls=vtkImageData, spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3)):
    image = cls()
    image.SetDimensions(*dims)
    image.SetSpacing(*spacing)
    image.SetOrigin(*origin)
    return image


def ijk(dims):
    i, j, k = np.meshgrid(*(np.arange(n) for n in dims), indexing="ij")
    return (i + 10 * j + 100 * k).astype(np.float32)


@pytest.mark.parametrize("cls", [vtkImageData, vtkStructuredPoints, vtkUniformGrid])
def test_index_order_and_geometry(cls):
    image = make_image(cls=cls)
    values = ijk((5, 4, 3))
    add_point_array(image, "s", values, set_active=True)
    # VTK point id = i + nx * (j + ny * k), and its value is i + 10 j + 100 k.
    assert image.GetPointData().GetScalars().GetValue(1 + 5 * (2 + 4 * 1)) == 1 + 20 + 100
    v = volume_from_image_data(image)
    np.testing.assert_array_equal(v.scalars, values)
    np.testing.assert_allclose(v.spacing, (0.5, 1.0, 2.0))
    np.testing.assert_allclose(v.origin, (1, 2, 3))
    np.testing.assert_allclose(v.bounds, image.GetBounds())


def test_extent_offset_and_direction_matrix():
    image = vtkImageData()
    image.SetExtent(2, 6, -1, 2, 3, 5)
    image.SetSpacing(0.5, 1.0, 2.0)
    image.SetOrigin(1.0, 2.0, 3.0)
    c, s = np.cos(0.3), np.sin(0.3)
    image.SetDirectionMatrix(c, -s, 0, s, c, 0, 0, 0, 1)
    add_point_array(image, "s", ijk((5, 4, 3)), set_active=True)
    v = volume_from_image_data(image)
    np.testing.assert_allclose(v.direction, [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    # The volume's origin is the world position of the extent's first point.
    first = [0.0, 0.0, 0.0]
    image.TransformIndexToPhysicalPoint(2, -1, 3, first)
    np.testing.assert_allclose(v.origin, first)
    np.testing.assert_allclose(v.bounds, image.GetBounds(), atol=1e-12)


def test_pyvista_image_data():
    pv = pytest.importorskip("pyvista")
    grid = pv.ImageData(dimensions=(6, 5, 4), spacing=(0.1, 0.2, 0.3), origin=(-1, 0, 1))
    values = ijk((6, 5, 4))
    grid.point_data["density"] = values.ravel(order="F")
    v = volume_from_image_data(grid)
    np.testing.assert_array_equal(v.scalars, values)
    np.testing.assert_allclose(v.bounds, grid.bounds)


def test_round_trip_through_image_data():
    rng = np.random.default_rng(1)
    v = Volume(rng.random((7, 5, 4)), spacing=(0.3, 0.2, 0.1), origin=(1, 1, 1))
    image = image_data_from_volume(v)
    back = volume_from_image_data(image)
    np.testing.assert_array_equal(back.scalars, v.scalars)
    np.testing.assert_allclose(back.origin, v.origin)
    rgb = rng.random((7, 5, 4, 3)).astype(np.float32)
    add_point_array(image, "rgb", rgb)
    np.testing.assert_array_equal(point_array(image, "rgb"), rgb)
    assert image.GetPointData().GetArray("rgb").GetTuple3(1 + 7 * 2) == pytest.approx(rgb[1, 2, 0])


def test_image_like_covers_the_same_box_at_lower_resolution():
    v = Volume(np.zeros((33, 17, 9)), spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3),
               direction=np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]))
    half = image_like(v, (17, 9, 5))
    assert half.GetDimensions() == (17, 9, 5)
    np.testing.assert_allclose(half.GetSpacing(), (1.0, 2.0, 4.0))
    np.testing.assert_allclose(half.GetOrigin(), (1, 2, 3))
    np.testing.assert_allclose(half.GetBounds(), v.bounds)
    odd = image_like(v, (5, 4, 3))
    np.testing.assert_allclose(odd.GetBounds(), v.bounds)
    with pytest.raises(ValueError, match=">= 2"):
        image_like(v, (1, 4, 4))


# --- bad input ------------------------------------------------------------------------------
def test_non_image_datasets_are_told_to_resample():
    with pytest.raises(TypeError, match="vtkResampleToImage"):
        volume_from_image_data(vtkPolyData())
    with pytest.raises(TypeError, match="numpy"):
        volume_from_image_data(np.zeros((4, 4, 4)))


def test_multi_component_needs_a_component():
    image = make_image()
    vec = np.stack([ijk((5, 4, 3)), np.ones((5, 4, 3)), np.zeros((5, 4, 3))], -1)
    add_point_array(image, "v", vec, set_active=True)
    with pytest.raises(ValueError, match="3 components.*component="):
        volume_from_image_data(image)
    np.testing.assert_array_equal(volume_from_image_data(image, component=1).scalars, 1.0)
    mag = volume_from_image_data(image, component="magnitude").scalars
    np.testing.assert_allclose(mag, np.sqrt(ijk((5, 4, 3)) ** 2 + 1), rtol=1e-6)
    with pytest.raises(ValueError, match="out of range"):
        volume_from_image_data(image, component=3)
    with pytest.raises(ValueError, match="magnitude"):
        volume_from_image_data(image, component="norm")


def test_missing_and_ambiguous_arrays_list_what_exists():
    image = make_image()
    with pytest.raises(ValueError, match="no scalar array.*point arrays: none"):
        volume_from_image_data(image)
    add_point_array(image, "a", ijk((5, 4, 3)))
    add_point_array(image, "b", ijk((5, 4, 3)))
    with pytest.raises(ValueError, match="several point arrays.*'a'.*'b'"):
        volume_from_image_data(image)
    with pytest.raises(ValueError, match="no point or cell array named 'c'.*'a'"):
        volume_from_image_data(image, "c")
    np.testing.assert_array_equal(volume_from_image_data(image, "b").scalars, ijk((5, 4, 3)))
    strings = vtkStringArray()
    strings.SetName("labels")
    strings.SetNumberOfValues(60)
    image.GetPointData().AddArray(strings)
    with pytest.raises(TypeError, match="not a numeric array"):
        volume_from_image_data(image, "labels")


def test_cell_data_is_averaged_onto_the_points():
    image = make_image(dims=(4, 3, 3), spacing=(1, 1, 1), origin=(0, 0, 0))
    cells = np.arange(3 * 2 * 2, dtype=np.float32)  # cell id = i + 3 (j + 2 k)
    array = numpy_to_vtk(cells, deep=True)
    array.SetName("c")
    image.GetCellData().AddArray(array)
    v = volume_from_image_data(image)  # no point array: the only cell array is used
    assert v.dims == (4, 3, 3)
    cell = cells.reshape((3, 2, 2), order="F")
    # An interior-edge point (1, 1, 1) touches the 8 cells i in {0,1}, j in {0,1}, k in {0,1}.
    assert v.scalars[1, 1, 1] == pytest.approx(cell[0:2, 0:2, 0:2].mean())
    assert v.scalars[0, 0, 0] == pytest.approx(cell[0, 0, 0])
    np.testing.assert_array_equal(volume_from_image_data(image, "c", association="cells").scalars,
                                  v.scalars)
    with pytest.raises(ValueError, match="no point array named 'c'"):
        volume_from_image_data(image, "c", association="points")


def test_nan_policy():
    image = make_image()
    values = ijk((5, 4, 3))
    values[1, 2, 0] = np.nan
    values[0, 0, 2] = np.inf
    add_point_array(image, "s", values, set_active=True)
    with pytest.raises(ValueError, match="2 sample.*NaN or Inf.*nan_policy='fill'"):
        volume_from_image_data(image)
    filled = volume_from_image_data(image, nan_policy="fill").scalars
    assert filled[1, 2, 0] == 0.0 and filled[0, 0, 2] == 0.0 and np.isfinite(filled).all()


def test_empty_image_and_negative_spacing():
    with pytest.raises(ValueError, match="empty"):
        volume_from_image_data(vtkImageData())
    image = make_image(spacing=(1.0, -1.0, 1.0))
    add_point_array(image, "s", ijk((5, 4, 3)), set_active=True)
    with pytest.raises(ValueError, match="spacing.*positive.*flip"):
        volume_from_image_data(image)
    flat = make_image(dims=(5, 4, 1))
    add_point_array(flat, "s", np.zeros((5, 4, 1)), set_active=True)
    with pytest.raises(ValueError, match="at least 2 points"):
        volume_from_image_data(flat)


def test_add_point_array_checks_the_shape():
    with pytest.raises(ValueError, match="dimensions"):
        add_point_array(make_image(), "x", np.zeros((4, 5, 3)))


# --- transfer functions -----------------------------------------------------------------------
def test_transfer_function_round_trip_and_union_of_nodes():
    ctf = vtkColorTransferFunction()
    ctf.AddRGBPoint(0.0, 1.0, 0.0, 0.0)
    ctf.AddRGBPoint(10.0, 0.0, 0.0, 1.0)
    otf = vtkPiecewiseFunction()
    otf.AddPoint(2.0, 0.0)
    otf.AddPoint(6.0, 0.8)
    tf = transfer_function_from_vtk(ctf, otf)
    np.testing.assert_array_equal(tf.scalars, [0.0, 2.0, 6.0, 10.0])
    x = np.linspace(-2, 12, 57)
    np.testing.assert_allclose(tf.alpha(x), [otf.GetValue(v) for v in x], atol=1e-12)
    np.testing.assert_allclose(tf.color(x), [ctf.GetColor(v) for v in x], atol=1e-12)

    back_ctf, back_otf = transfer_function_to_vtk(tf)
    np.testing.assert_allclose([back_otf.GetValue(v) for v in x], tf.alpha(x), atol=1e-12)
    np.testing.assert_allclose([back_ctf.GetColor(v) for v in x], tf.color(x), atol=1e-12)
    white = transfer_function_from_vtk(None, otf)
    np.testing.assert_array_equal(white.colors, 1.0)


def test_midpoint_sharpness_and_hsv_are_sampled_densely():
    otf = vtkPiecewiseFunction()
    otf.AddPoint(0.0, 0.0, 0.2, 0.6)  # midpoint 0.2, sharpness 0.6: not linear
    otf.AddPoint(1.0, 1.0)
    ctf = vtkColorTransferFunction()
    ctf.SetColorSpaceToHSV()
    ctf.AddRGBPoint(0.0, 1.0, 0.0, 0.0)
    ctf.AddRGBPoint(1.0, 0.0, 0.0, 1.0)
    tf = transfer_function_from_vtk(ctf, otf)
    x = np.linspace(0, 1, 201)
    np.testing.assert_allclose(tf.alpha(x), [otf.GetValue(v) for v in x], atol=5e-3)
    np.testing.assert_allclose(tf.color(x), [ctf.GetColor(v) for v in x], atol=5e-3)
    assert tf.scalars.size < 1000
    # HSV interpolation from red to blue is far from the RGB line (0.5, 0, 0.5).
    assert np.abs(tf.color(0.5) - [0.5, 0.0, 0.5]).max() > 0.2


def test_empty_opacity_is_an_error():
    with pytest.raises(ValueError, match="no points"):
        transfer_function_from_vtk(None, vtkPiecewiseFunction())
    with pytest.raises(TypeError):
        transfer_function_from_vtk(None, TransferFunction([0.0], [1.0]))
