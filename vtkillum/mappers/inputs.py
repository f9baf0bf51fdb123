"""How the mappers take their inputs: any image source, the one point array they render, and
the check that an illumination image covers the data."""

from __future__ import annotations

import numpy as np
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkAlgorithm, vtkAlgorithmOutput

from vtkillum.core.volume import Volume
from vtkillum.io.convert import direction_matrix, first_point, image_data_from_volume


def connect_input(algorithm, port: int, source, what: str) -> None:
    """Connect ``source`` (data object, output port, algorithm or core Volume) to ``port``."""
    if isinstance(source, Volume):
        source = image_data_from_volume(source)
    if isinstance(source, vtkAlgorithmOutput):
        algorithm.SetInputConnection(port, source)
    elif isinstance(source, vtkAlgorithm):
        algorithm.SetInputConnection(port, source.GetOutputPort())
    elif isinstance(source, vtkImageData):
        algorithm.SetInputDataObject(port, source)
    else:
        raise TypeError(
            f"{what}: expected vtkImageData (or pyvista.ImageData), a pipeline output port, a "
            f"VTK algorithm{' or a vtkillum Volume' if port == 0 else ''}, got "
            f"{type(source).__name__}"
        )


def rendered_point_array(image, array_name):
    """The rendered point array of ``image``, with errors that say what to do."""
    if image is None:
        raise ValueError("the data input produced no image; check the upstream pipeline")
    pd = image.GetPointData()
    array = pd.GetScalars() if array_name is None else pd.GetArray(array_name)
    if array is None:
        names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
        what = "no active point scalars" if array_name is None else f"no point array {array_name!r}"
        raise ValueError(
            f"the data have {what} (point arrays: {names}); pass array_name=... or set the "
            "active scalars. Cell data: convert with vtkCellDataToPointData first"
        )
    if array.GetNumberOfComponents() != 1:
        raise ValueError(
            f"the array {array.GetName()!r} has {array.GetNumberOfComponents()} components; the "
            "illuminated mapper renders one (extract it, e.g. vtkImageExtractComponents)"
        )
    return array


def check_covers(fimage, volume: Volume) -> None:
    """Raise unless the illumination image ``fimage`` covers ``volume``'s box (any resolution)."""
    if fimage is None or fimage.GetNumberOfPoints() == 0:
        raise ValueError("the illumination input produced no image; check its pipeline")
    dims = np.array(fimage.GetDimensions())
    spacing = np.array(fimage.GetSpacing(), dtype=np.float64)
    direction = direction_matrix(fimage)
    first = first_point(fimage.GetOrigin(), fimage.GetExtent(), spacing, direction)
    last = first + direction @ ((dims - 1) * spacing)
    data_last = volume.origin + volume.direction @ volume.extent
    tol = 1e-5 * float(np.linalg.norm(volume.extent)) + 1e-9
    if (min(dims) < 2 or not np.allclose(direction, volume.direction, atol=1e-6)
            or np.abs(first - volume.origin).max() > tol or np.abs(last - data_last).max() > tol):
        raise ValueError(
            f"the illumination image (first point {first.tolist()}, last {last.tolist()}) does "
            f"not cover the data's box (first {volume.origin.tolist()}, last "
            f"{data_last.tolist()}) with the same orientation; compute it from the same data"
        )
