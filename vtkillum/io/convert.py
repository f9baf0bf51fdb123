"""Conversion between VTK objects and the core's numpy types.

Image data
    :func:`volume_from_image_data` turns a ``vtkImageData`` (also
    ``pyvista.ImageData``, ``vtkStructuredPoints``, ``vtkUniformGrid``) into a
    :class:`~vtkillum.core.volume.Volume`; :func:`image_data_from_volume`,
    :func:`image_like` and :func:`add_point_array` go the other way. Arrays are
    indexed ``[i, j, k]``: VTK's point order (x fastest) reshaped with
    ``order='F'``.

Transfer functions
    :func:`transfer_function_from_vtk` and :func:`transfer_function_to_vtk`
    convert between ``vtkColorTransferFunction`` + ``vtkPiecewiseFunction`` and
    :class:`~vtkillum.core.transfer_function.TransferFunction`.

Cell data
    The core is point-centred. An image whose chosen array lives on the cells is
    converted with ``vtkCellDataToPointData``: each point gets the average of the
    cells around it, so the data are smoothed by one cell while the geometry
    (points, bounds) is kept. Resample with point data yourself for other choices.
"""

from __future__ import annotations

import numpy as np
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
from vtkmodules.vtkCommonCore import vtkDataArray
from vtkmodules.vtkCommonDataModel import (
    vtkDataObject,
    vtkDataSet,
    vtkImageData,
    vtkPiecewiseFunction,
)
from vtkmodules.vtkFiltersCore import vtkCellDataToPointData
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

#: Uniform samples per control-point interval where VTK's interpolation is not linear in RGB
#: and opacity (midpoint/sharpness, HSV/Lab/diverging colour space, log scale) ...
DENSE_SAMPLES = 32
#: ... each then bisected where linear interpolation is off by more than this (opacity, RGB) ...
REFINE_TOLERANCE = 2e-3
#: ... at most this many times.
REFINE_DEPTH = 8

_RESAMPLE_HINT = (
    "resample it onto a uniform grid first: vtkResampleToImage (ParaView: 'Resample To "
    "Image') or pyvista's `pv.ImageData(dimensions=..., spacing=..., origin=...).sample(mesh)`"
)


# --- image data -> Volume ------------------------------------------------------------------------
def volume_from_image_data(image, array_name: str | None = None, component=None,
                           nan_policy: str = "raise", association: str | None = None) -> Volume:
    """A :class:`~vtkillum.core.volume.Volume` from VTK image data.

    Parameters
    ----------
    image : vtkImageData
        Also ``pyvista.ImageData``, ``vtkStructuredPoints`` or ``vtkUniformGrid``. Other
        datasets raise ``TypeError``: resample them with ``vtkResampleToImage``.
    array_name : str, optional
        Array to render. Default: the active point scalars; else the only point
        array; else the active (or only) cell array, converted to point data.
    component : int or "magnitude", optional
        Required for multi-component arrays: the component index, or ``"magnitude"``
        for the Euclidean norm of each tuple.
    nan_policy : {"raise", "fill"}
        NaN/Inf samples raise ``ValueError`` or are replaced by the smallest finite value.
    association : {"points", "cells"}, optional
        Where to look for ``array_name``; default points, then cells.

    Returns
    -------
    Volume
        Scalars ``(nx, ny, nz)`` float32 indexed ``[i, j, k]``; spacing, origin (world
        position of the first point of the extent) and direction from the image.

    Raises
    ------
    TypeError
        Not image data, or a non-numeric array.
    ValueError
        Empty image, non-positive spacing, missing or ambiguous array, multi-component
        array without ``component``, NaN/Inf with ``nan_policy="raise"``.
    """
    check_image_data(image)
    dims = tuple(int(n) for n in image.GetDimensions())
    if min(dims) < 1 or image.GetNumberOfPoints() == 0:
        raise ValueError(
            f"the image is empty (dimensions {dims}, extent {tuple(image.GetExtent())}); "
            "update the algorithm that produces it (Update()) or check the reader's file name"
        )
    spacing = np.array(image.GetSpacing(), dtype=np.float64)
    if np.any(spacing <= 0):
        raise ValueError(
            f"image spacing {tuple(spacing)} must be positive along every axis; a negative "
            "spacing mirrors an axis: flip that axis (vtkImageFlip, or np.flip and move the "
            "origin to the other end) and use a positive spacing"
        )
    array = _select_array(image, array_name, association)
    values = _component_values(array, component)
    scalars = np.ascontiguousarray(values.reshape(dims, order="F"), dtype=np.float32)
    direction = direction_matrix(image)
    origin = first_point(image.GetOrigin(), image.GetExtent(), spacing, direction)
    return Volume(scalars, spacing, origin, direction, nan_policy=nan_policy)


def check_image_data(image) -> None:
    """Raise ``TypeError`` with advice unless ``image`` is VTK image data."""
    if isinstance(image, vtkImageData):
        return
    if isinstance(image, vtkDataSet):
        raise TypeError(
            f"{image.GetClassName()} is not image data (a uniform grid is needed); {_RESAMPLE_HINT}"
        )
    if isinstance(image, vtkDataObject):
        raise TypeError(
            f"{image.GetClassName()} is not image data; for a composite dataset extract one "
            f"image block (e.g. vtkExtractBlock, or `multiblock[0]` in pyvista), otherwise "
            f"{_RESAMPLE_HINT}"
        )
    raise TypeError(
        f"expected vtkImageData or pyvista.ImageData, got {type(image).__name__}; for a numpy "
        "array use vtkillum.Volume(array, spacing, origin) or pyvista.wrap(array)"
    )


def direction_matrix(image) -> np.ndarray:
    """The image's 3x3 direction matrix (columns: the grid axes in world space)."""
    m = image.GetDirectionMatrix()
    return np.array([[m.GetElement(r, c) for c in range(3)] for r in range(3)], dtype=np.float64)


def first_point(origin, extent, spacing, direction) -> np.ndarray:
    """World position of the point at the start of ``extent``.

    VTK images place point ``(i, j, k)`` at ``origin + direction @ ((i, j, k) * spacing)``,
    and an extent need not start at zero.
    """
    start = np.array(extent[0::2], dtype=np.float64)
    return np.asarray(origin, dtype=np.float64) + np.asarray(direction) @ (
        start * np.asarray(spacing, dtype=np.float64))


def _describe_arrays(image) -> str:
    def names(data):
        out = []
        for i in range(data.GetNumberOfArrays()):
            a = data.GetAbstractArray(i)
            if a is not None:
                out.append(f"{a.GetName()!r} ({a.GetNumberOfComponents()} comp.)")
        return ", ".join(out) or "none"

    return f"point arrays: {names(image.GetPointData())}; cell arrays: {names(image.GetCellData())}"


def _numeric_arrays(data) -> list:
    return [data.GetArray(i) for i in range(data.GetNumberOfArrays())
            if data.GetArray(i) is not None]


def _select_array(image, array_name, association):
    """The point array to convert (cell arrays are converted to point data)."""
    if association not in (None, "points", "cells"):
        raise ValueError(f"association must be 'points' or 'cells', got {association!r}")
    pd, cd = image.GetPointData(), image.GetCellData()
    if array_name is not None:
        if association in (None, "points") and pd.GetAbstractArray(array_name) is not None:
            return _numeric(pd.GetAbstractArray(array_name))
        if association in (None, "cells") and cd.GetAbstractArray(array_name) is not None:
            _numeric(cd.GetAbstractArray(array_name))
            return cell_array_to_points(image, array_name)
        where = {"points": "point", "cells": "cell"}.get(association, "point or cell")
        raise ValueError(
            f"the image has no {where} array named {array_name!r}; {_describe_arrays(image)}"
        )
    if pd.GetScalars() is not None:
        return pd.GetScalars()
    point_arrays = _numeric_arrays(pd)
    if len(point_arrays) == 1:
        return point_arrays[0]
    if len(point_arrays) > 1:
        raise ValueError(
            f"the image has several point arrays and no active scalars; name one with "
            f"array_name=... ({_describe_arrays(image)})"
        )
    cell_arrays = _numeric_arrays(cd)
    cell = cd.GetScalars() or (cell_arrays[0] if len(cell_arrays) == 1 else None)
    if cell is not None:
        return cell_array_to_points(image, cell.GetName())
    raise ValueError(
        "the image has no scalar array to render"
        + ("; several cell arrays: name one with array_name=..." if cell_arrays else "")
        + f" ({_describe_arrays(image)})"
    )


def _numeric(array):
    if not isinstance(array, vtkDataArray) or array.GetDataType() == 1:  # 1: VTK_BIT
        raise TypeError(
            f"array {array.GetName()!r} is a {array.GetClassName()}, not a numeric array; "
            "choose a numeric array (e.g. vtkArrayCalculator can build one)"
        )
    return array


def cell_array_to_points(image, name: str):
    """Point data from the cell array ``name`` of ``image`` (vtkCellDataToPointData).

    Each point receives the average of the cells that share it. Only that array is
    converted; ``image`` is not modified.
    """
    if image.GetCellData().GetArray(name) is None:
        raise ValueError(f"the image has no numeric cell array {name!r}; {_describe_arrays(image)}")
    shallow = vtkImageData()
    shallow.CopyStructure(image)
    shallow.GetCellData().AddArray(image.GetCellData().GetArray(name))
    c2p = vtkCellDataToPointData()
    c2p.SetInputData(shallow)
    c2p.ProcessAllArraysOff()
    c2p.AddCellDataArray(name)
    c2p.Update()
    return c2p.GetOutput().GetPointData().GetArray(name)


def _component_values(array, component) -> np.ndarray:
    values = vtk_to_numpy(array)
    ncomp = array.GetNumberOfComponents()
    name = array.GetName()
    if values.ndim == 1:
        values = values[:, None]
    if isinstance(component, str):
        if component != "magnitude":
            raise ValueError(f"component must be an index or 'magnitude', got {component!r}")
        return np.linalg.norm(values.astype(np.float64), axis=1)
    if component is None:
        if ncomp != 1:
            raise ValueError(
                f"array {name!r} has {ncomp} components; choose one with component=<index> "
                "(0 .. {}) or component='magnitude'".format(ncomp - 1)
            )
        return values[:, 0]
    if isinstance(component, bool) or not isinstance(component, (int, np.integer)):
        raise ValueError(f"component must be an index or 'magnitude', got {component!r}")
    if not 0 <= int(component) < ncomp:
        raise ValueError(f"component {component} is out of range for array {name!r} with "
                         f"{ncomp} component(s)")
    return values[:, int(component)]


# --- Volume / numpy -> image data ------------------------------------------------------------
def image_data_from_volume(volume: Volume, name: str = "scalars") -> vtkImageData:
    """A ``vtkImageData`` with ``volume``'s geometry and its scalars as active point scalars."""
    image = image_like(volume)
    add_point_array(image, name, volume.scalars, set_active=True)
    return image


def resampled_geometry(dims, spacing, shape):
    """Spacing of a grid of ``shape`` points covering the same box as ``dims`` points.

    Both grids share their first and last points: ``(shape - 1) * new_spacing =
    (dims - 1) * spacing`` along every axis.
    """
    dims = np.asarray(dims, dtype=np.int64)
    shape = np.asarray(shape, dtype=np.int64).reshape(-1)
    if shape.shape != (3,) or np.any(shape < 2):
        raise ValueError(f"output shape must be three integers >= 2, got {tuple(shape)}")
    return (dims - 1) * np.asarray(spacing, dtype=np.float64) / (shape - 1)


def image_like(reference, shape=None) -> vtkImageData:
    """An empty ``vtkImageData`` covering the same box as ``reference``.

    Parameters
    ----------
    reference : Volume or vtkImageData
        The grid to cover.
    shape : (3,) int, optional
        Points along x, y, z (each >= 2). Default: the reference's dimensions (and, for
        image data, its extent). Otherwise the extent starts at 0, the origin is the
        reference's first point, the direction is the same and the spacing is adjusted
        so that the first and last points coincide with the reference's (e.g. an
        illumination volume at half resolution).
    """
    if isinstance(reference, Volume):
        dims, spacing = np.asarray(reference.dims), reference.spacing
        origin, direction = reference.origin, reference.direction
        extent = None
    else:
        check_image_data(reference)
        dims = np.asarray(reference.GetDimensions())
        spacing = np.asarray(reference.GetSpacing(), dtype=np.float64)
        direction = direction_matrix(reference)
        extent = reference.GetExtent()
        origin = first_point(reference.GetOrigin(), extent, spacing, direction)
    image = vtkImageData()
    if shape is None and extent is not None:
        image.CopyStructure(reference)
        return image
    if shape is None:
        shape = dims
    else:
        spacing = resampled_geometry(dims, spacing, shape)
    image.SetDimensions(*(int(n) for n in shape))
    image.SetSpacing(*spacing)
    image.SetOrigin(*origin)
    image.SetDirectionMatrix(*np.asarray(direction).reshape(-1))
    return image


def add_point_array(image, name: str, array, set_active: bool = False):
    """Attach a numpy array indexed ``[i, j, k(, c)]`` to ``image`` as point data.

    Parameters
    ----------
    image : vtkImageData
    name : str
        Array name (replaces an existing array of that name).
    array : ndarray (nx, ny, nz) or (nx, ny, nz, c)
        Must match the image's dimensions. Copied; booleans become uint8. The masked
        values of a numpy masked array become NaN (a float array), which
        :func:`volume_from_image_data` and the filters treat by their NaN policy.
    set_active : bool
        Make it the active scalars.

    Returns
    -------
    vtkDataArray
        The array added.
    """
    if np.ma.isMaskedArray(array) and np.ma.getmask(array) is not np.ma.nomask:
        # VTK arrays have no mask: masked values become NaN (np.asarray would keep what lies
        # under the mask), which the filters' NaN policy then handles.
        masked = np.ma.asarray(array)
        dtype = np.float64 if masked.dtype.itemsize > 4 else np.float32
        array = masked.astype(dtype).filled(np.nan)
    a = np.asarray(array)
    dims = tuple(int(n) for n in image.GetDimensions())
    if a.ndim not in (3, 4) or a.shape[:3] != dims:
        raise ValueError(
            f"array {name!r} has shape {a.shape}; the image has dimensions {dims}, so give "
            f"{dims} or {dims} + (components,)"
        )
    if a.dtype == bool:
        a = a.astype(np.uint8)
    if a.dtype.kind not in "biuf":
        raise TypeError(f"array {name!r}: dtype {a.dtype} cannot be stored in a VTK data array")
    ncomp = 1 if a.ndim == 3 else a.shape[3]
    # VTK point order has i fastest: transpose to [k, j, i(, c)] and flatten in C order.
    flat = np.ascontiguousarray(a.transpose(2, 1, 0, *range(3, a.ndim))).reshape(-1, ncomp)
    vtk_array = numpy_to_vtk(flat if ncomp > 1 else flat[:, 0], deep=True)
    vtk_array.SetName(name)
    pd = image.GetPointData()
    pd.AddArray(vtk_array)
    if set_active:
        pd.SetActiveScalars(name)
    return vtk_array


def point_array(image, name: str) -> np.ndarray:
    """A point array of ``image`` as numpy ``(nx, ny, nz)`` or ``(nx, ny, nz, c)`` (a copy)."""
    check_image_data(image)
    vtk_array = image.GetPointData().GetArray(name)
    if vtk_array is None:
        raise ValueError(f"the image has no point array {name!r}; {_describe_arrays(image)}")
    dims = tuple(int(n) for n in image.GetDimensions())
    values = vtk_to_numpy(vtk_array)
    if values.ndim == 1:
        return np.array(values.reshape(dims, order="F"))
    c = values.shape[1]
    return np.ascontiguousarray(values.reshape(dims[::-1] + (c,)).transpose(2, 1, 0, 3))


# --- transfer functions -----------------------------------------------------------------------
def transfer_function_from_vtk(color_tf, opacity_tf) -> TransferFunction:
    """A :class:`TransferFunction` from VTK's colour and scalar-opacity functions.

    Parameters
    ----------
    color_tf : vtkColorTransferFunction or None
        Colour; ``None`` or an empty function gives white.
    opacity_tf : vtkPiecewiseFunction
        Opacity per unit distance (at least one point).

    Notes
    -----
    The control points of both functions are merged onto the union of their nodes
    and both are evaluated there with VTK's own ``GetColor``/``GetValue``. Between
    nodes the result is linear in RGB and opacity. Where VTK would interpolate
    otherwise -- a node's midpoint is not 0.5 or its sharpness not 0, the colour
    space is not RGB (HSV, Lab, diverging), or the colour scale is logarithmic --
    the interval is sampled at :data:`DENSE_SAMPLES` points and then bisected
    where linear interpolation between samples is off by more than
    :data:`REFINE_TOLERANCE` (up to :data:`REFINE_DEPTH` times), so the shape is
    kept to about that tolerance. Outside the nodes the functions are constant
    (VTK's default clamping); ``ClampingOff`` (zero outside) and
    below/above-range colours are not represented.
    """
    if opacity_tf is None or not isinstance(opacity_tf, vtkPiecewiseFunction):
        raise TypeError("opacity_tf must be a vtkPiecewiseFunction (the scalar opacity)")
    if opacity_tf.GetSize() == 0:
        raise ValueError("the scalar opacity function has no points; add some with AddPoint(x, a)")
    if color_tf is not None and not isinstance(color_tf, vtkColorTransferFunction):
        raise TypeError("color_tf must be a vtkColorTransferFunction or None")
    has_color = color_tf is not None and color_tf.GetSize() > 0

    def evaluate(x: float) -> np.ndarray:
        rgb = [0.0, 0.0, 0.0]
        if has_color:
            color_tf.GetColor(x, rgb)  # the (x, rgb) overload also works on ParaView's maps
        color = rgb if has_color else (1.0, 1.0, 1.0)
        return np.array([opacity_tf.GetValue(x), *color])

    o_nodes = [_node(opacity_tf, i, 4) for i in range(opacity_tf.GetSize())]
    c_nodes = [_node(color_tf, i, 6) for i in range(color_tf.GetSize())] if has_color else []
    check_finite_nodes(o_nodes, "the scalar opacity function (vtkPiecewiseFunction)",
                       ("x", "opacity", "midpoint", "sharpness"))
    check_finite_nodes(c_nodes, "the colour transfer function (vtkColorTransferFunction)",
                       ("x", "red", "green", "blue", "midpoint", "sharpness"))
    xs = {n[0] for n in o_nodes} | {n[0] for n in c_nodes}
    # Intervals where VTK's interpolation is not piecewise linear get extra samples.
    curved = _curved_intervals(o_nodes, mid_index=2)
    if has_color:
        nonlinear_color = color_tf.GetColorSpace() != 0 or color_tf.GetScale() != 0
        curved += ([(c_nodes[i][0], c_nodes[i + 1][0]) for i in range(len(c_nodes) - 1)]
                   if nonlinear_color else _curved_intervals(c_nodes, mid_index=4))
    for lo, hi in curved:
        grid = np.linspace(lo, hi, DENSE_SAMPLES + 1)
        xs.update(grid[1:-1].tolist())
        for a, b in zip(grid[:-1], grid[1:]):
            xs.update(_refine(evaluate, a, b, evaluate(a), evaluate(b), REFINE_DEPTH))
    xs = np.array(sorted(xs), dtype=np.float64)
    xs = xs[np.concatenate([[True], np.diff(xs) > 0])]

    table = np.array([evaluate(x) for x in xs])
    bad = ~np.all(np.isfinite(table), axis=1)
    if bad.any():  # finite nodes, yet VTK evaluates NaN (e.g. a log scale over values <= 0)
        x = float(xs[np.argmax(bad)])
        raise ValueError(f"VTK evaluates the transfer functions to NaN or infinity at x = {x:g} "
                         f"(opacity, RGB: {table[np.argmax(bad)].tolist()}); transfer "
                         "functions need finite values (a logarithmic colour scale needs "
                         "positive values)")
    return TransferFunction(xs, np.clip(table[:, 0], 0.0, 1.0), np.clip(table[:, 1:], 0.0, 1.0))


def _refine(evaluate, a: float, b: float, fa, fb, depth: int) -> list:
    """Points in (a, b) where linear interpolation misses ``evaluate`` by more than
    :data:`REFINE_TOLERANCE` at interval midpoints (recursive bisection)."""
    m = 0.5 * (a + b)
    fm = evaluate(m)
    if depth == 0 or np.max(np.abs(fm - 0.5 * (fa + fb))) <= REFINE_TOLERANCE:
        return []
    return (_refine(evaluate, a, m, fa, fm, depth - 1) + [m]
            + _refine(evaluate, m, b, fm, fb, depth - 1))


def check_finite_nodes(nodes, what: str, fields) -> None:
    """Refuse a VTK function whose nodes hold NaN or infinity, naming the first such node.

    VTK takes them silently and then evaluates NaN between the nodes; the volume would
    render transparent or not at all, with no hint why.
    """
    for index, node in enumerate(nodes):
        if not np.all(np.isfinite(node)):
            values = ", ".join(f"{name} = {value:g}" for name, value in zip(fields, node))
            raise ValueError(f"{what} has NaN or infinity at node {index} ({values}); transfer "
                             "functions need finite values")


def _node(function, index: int, size: int) -> list:
    values = [0.0] * size
    function.GetNodeValue(index, values)
    return values


def _curved_intervals(nodes, mid_index: int) -> list:
    """Intervals following nodes whose midpoint/sharpness bend the interpolation."""
    out = []
    for a, b in zip(nodes[:-1], nodes[1:]):
        midpoint, sharpness = a[mid_index], a[mid_index + 1]
        if abs(midpoint - 0.5) > 1e-9 or abs(sharpness) > 1e-9:
            out.append((a[0], b[0]))
    return out


def transfer_function_to_vtk(tf: TransferFunction):
    """``(vtkColorTransferFunction, vtkPiecewiseFunction)`` with ``tf``'s control points."""
    color_tf = vtkColorTransferFunction()
    opacity_tf = vtkPiecewiseFunction()
    for x, a, c in zip(tf.scalars, tf.opacity, tf.colors):
        color_tf.AddRGBPoint(float(x), *(float(v) for v in c))
        opacity_tf.AddPoint(float(x), float(a))
    return color_tf, opacity_tf
