"""OpticalPropertiesFilter: sigma_t, scattering colour, sigma_s and sigma_a per grid point."""

import numpy as np
import pytest

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters import OpticalPropertiesFilter
from vtkillum.io.convert import point_array


def ramp_image(make_image, dims=(9, 7, 5)):
    """Scalars equal to world x - 1 (linear, so trilinear resampling is exact)."""
    x = np.arange(dims[0]) * 0.25
    return make_image(dims=dims, spacing=(0.25, 0.5, 0.5), origin=(1.0, 0.0, 0.0),
                      values=np.broadcast_to(x[:, None, None], dims))


def model():
    return TransferFunction([0.0, 2.0], [0.1, 0.9], [[1.0, 0.5, 0.0], [0.0, 0.5, 1.0]])


def test_values_follow_the_optical_model(make_image):
    f = OpticalPropertiesFilter()
    f.SetTransferFunction(model())
    f.SetAlbedo(0.8)
    f.SetScalarOpacityUnitDistance(0.5)
    img = ramp_image(make_image)
    out = f.execute(img)
    s = point_array(img, "density")
    tf = model()
    sigma_t = -np.log(1 - tf.alpha(s)) / 0.5
    np.testing.assert_allclose(point_array(out, "sigma_t"), sigma_t, rtol=1e-5)
    np.testing.assert_allclose(point_array(out, "scattering_color"), 0.8 * tf.color(s), rtol=1e-5)
    np.testing.assert_allclose(point_array(out, "sigma_s"), 0.8 * tf.color(s) * sigma_t[..., None],
                               rtol=1e-5, atol=1e-6)
    total = point_array(out, "sigma_s") + point_array(out, "sigma_a")
    np.testing.assert_allclose(total, np.repeat(sigma_t[..., None], 3, -1), rtol=1e-5)
    assert out.GetPointData().GetScalars().GetName() == "sigma_t"


def test_lower_resolution_classifies_trilinear_samples(make_image):
    f = OpticalPropertiesFilter()
    f.SetTransferFunction(model())
    f.SetOutputDimensions(5, 4, 3)
    out = f.execute(ramp_image(make_image))
    assert out.GetDimensions() == (5, 4, 3)
    x = np.linspace(0.0, 2.0, 5)  # data value at the new points (world x - 1)
    expected = -np.log(1 - model().alpha(x)) / (1.25 / 3)  # u = mean spacing of the input
    np.testing.assert_allclose(point_array(out, "sigma_t")[:, 2, 1], expected, rtol=1e-5)


def test_needs_no_lights(make_image):
    f = OpticalPropertiesFilter()
    f.RemoveAllLights()
    out = f.execute(ramp_image(make_image))
    assert out.GetPointData().GetArray("sigma_t") is not None
    with pytest.raises(ValueError, match="Albedo"):
        f.SetAlbedo(-0.1)
