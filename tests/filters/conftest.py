"""Fixtures for filter tests: small images and a time-aware source that counts executions."""

import numpy as np
import pytest
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

from vtkillum.io.convert import add_point_array


class CountingTimeSource(VTKPythonAlgorithmBase):
    """Image source with time steps; scalars are ``time + x`` (world x); counts RequestData.

    ``calls`` lists the time of every execution, so a test can tell whether the
    upstream ran.
    """

    def __init__(self, times=(0.0, 1.0, 2.0), dims=(8, 6, 5), spacing=(0.5, 0.5, 0.5)):
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=0, nOutputPorts=1,
                                        outputType="vtkImageData")
        self.times = list(times)
        self.dims = dims
        self.spacing = spacing
        self.calls = []

    def RequestInformation(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        nx, ny, nz = self.dims
        info.Set(SDDP.WHOLE_EXTENT(), (0, nx - 1, 0, ny - 1, 0, nz - 1), 6)
        info.Set(vtkDataObject.SPACING(), self.spacing, 3)
        info.Set(SDDP.TIME_STEPS(), self.times, len(self.times))
        info.Set(SDDP.TIME_RANGE(), (self.times[0], self.times[-1]), 2)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        t = info.Get(SDDP.UPDATE_TIME_STEP()) if info.Has(SDDP.UPDATE_TIME_STEP()) else 0.0
        # Snap to the nearest step below, as readers do.
        t = max([s for s in self.times if s <= t] or [self.times[0]])
        self.calls.append(t)
        out = vtkImageData.GetData(info)
        out.SetDimensions(*self.dims)
        out.SetSpacing(*self.spacing)
        x = np.arange(self.dims[0]) * self.spacing[0]
        values = np.broadcast_to((t + x)[:, None, None], self.dims).astype(np.float32)
        add_point_array(out, "s", values, set_active=True)
        out.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(), t)
        return 1


@pytest.fixture
def time_source():
    return CountingTimeSource()


def image(dims=(12, 10, 8), spacing=(0.5, 0.4, 0.3), origin=(1.0, -2.0, 0.5), values=None,
          name="density"):
    """A vtkImageData with one active point array (default: a smooth blob)."""
    img = vtkImageData()
    img.SetDimensions(*dims)
    img.SetSpacing(*spacing)
    img.SetOrigin(*origin)
    if values is None:
        grids = np.meshgrid(*(np.linspace(-1, 1, n) for n in dims), indexing="ij")
        values = np.exp(-2.0 * sum(g ** 2 for g in grids))
    add_point_array(img, name, np.asarray(values, dtype=np.float32), set_active=True)
    return img


@pytest.fixture
def make_image():
    return image
