"""IlluminatedVolume reads an illumination image's arrays as they are (issue 35).

An illumination filter's output reaches the mapper as a ``vtkImageData``; its grids are
uploaded from the VTK arrays' memory (VTK's point order, no transposed copy), while an
``IlluminationVolume`` object's grids are uploaded from numpy's order (z-major textures).
Both must draw the same picture, bit for bit (the same 16-bit texels, read with the axes
swapped), on a grid whose three axes differ, and bad arrays must be refused with the
checks ``IlluminationVolume`` makes.
"""

import numpy as np
import pytest
from test_mappers import blob_lights, direct_light, make_scene, render_opengl, slab_fluence

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.volume import Volume

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402

from vtkillum.io.convert import add_point_array, image_data_from_volume, image_like  # noqa: E402
from vtkillum.io.illumination_arrays import add_lights_field  # noqa: E402
from vtkillum.mappers.illuminated_volume_mapper import ImageGrids  # noqa: E402

SHAPE = (20, 15, 11)  # light grid: three different axes


def skewed_blobs() -> Volume:
    n = (28, 22, 18)
    x, y, z = (np.linspace(-1.0, 1.0, k) for k in n)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    f = np.exp(-((X + 0.3) ** 2 + 2 * (Y - 0.1) ** 2 + (Z - 0.2) ** 2) / 0.25) + \
        0.7 * np.exp(-((X - 0.5) ** 2 + (Y + 0.45) ** 2 + 3 * (Z + 0.3) ** 2) / 0.08)
    return Volume(f.astype(np.float32), spacing=(1.0, 1.2, 0.9), origin=(2.0, -1.0, 0.5))


def illumination_image(volume, scene, transmittance, scattered):
    image = image_like(volume, shape=SHAPE)
    if transmittance is not None:
        add_point_array(image, "transmittance", np.moveaxis(transmittance, 0, -1))
    if scattered is not None:
        add_point_array(image, "scattered_fluence", scattered)
    add_lights_field(image, scene.lights)
    return image


@pytest.fixture(scope="module")
def scene_and_grids():
    volume = skewed_blobs()
    scene = make_scene(volume, lights=blob_lights(volume))
    transmittance = direct_light(volume, scene, shape=SHAPE)
    scattered = slab_fluence(volume, scene.transfer_function)
    from vtkillum.core.resample import resample_points

    scattered = resample_points(scattered, SHAPE).astype(np.float32)
    return volume, scene, transmittance, scattered


def test_an_image_draws_what_the_same_grids_as_an_object_draw(scene_and_grids):
    volume, scene, transmittance, scattered = scene_and_grids
    data = image_data_from_volume(volume)
    as_object = IlluminationVolume.for_volume(volume, scattered, transmittance)
    first, _a1, w1 = render_opengl(data, scene, as_object, 1.5)
    image = illumination_image(volume, scene, transmittance, scattered)
    second, actor, w2 = render_opengl(data, scene, image, 1.5)
    assert isinstance(actor.inputs.illumination, ImageGrids)
    assert first.max() > 0.2
    assert np.abs(first - second).max() == 0.0
    # no copies: the grids are the image's arrays, read in place
    grids = actor.inputs.illumination
    assert np.shares_memory(grids.transmittance,
                            vtk_to_numpy(image.GetPointData().GetArray("transmittance")))
    # an all-zero scattered fluence beside a transmittance is not drawn (as before)
    zero = illumination_image(volume, scene, transmittance, np.zeros_like(scattered))
    actor.set_illumination(zero)
    actor.check()
    assert actor.inputs.variant == (True, True, False)
    for window in (w1, w2):
        window.Finalize()


@pytest.mark.parametrize("what, edit, message", [
    ("transmittance", lambda t, s: t.__setitem__((0, 3, 4, 5), np.nan), "NaN or Inf"),
    ("transmittance", lambda t, s: t.__setitem__((1, 3, 4, 5), 1.5), r"lie in \[0, 1\]"),
    ("scattered", lambda t, s: s.__setitem__((3, 4, 5, 1), -2.0), "non-negative"),
    ("scattered", lambda t, s: s.__setitem__((3, 4, 5, 2), np.inf), "NaN or Inf"),
])
def test_bad_grids_in_an_image_are_refused(scene_and_grids, what, edit, message):
    volume, scene, transmittance, scattered = scene_and_grids
    t, s = transmittance.copy(), scattered.copy()
    edit(t, s)
    with pytest.raises(ValueError, match=message):  # when the image is set
        render_opengl(image_data_from_volume(volume), scene,
                      illumination_image(volume, scene, t, s), 1.0)


def test_a_grey_fluence_image_is_spread_over_rgb(scene_and_grids):
    volume, scene, _t, scattered = scene_and_grids
    grey = scattered[..., :1]
    image = image_like(volume, shape=SHAPE)
    add_point_array(image, "fluence", grey)
    rgb = IlluminationVolume.for_volume(volume, np.repeat(grey, 3, axis=-1))
    data = image_data_from_volume(volume)
    first, _a1, w1 = render_opengl(data, scene, rgb, 1.5)
    second, _a2, w2 = render_opengl(data, scene, image, 1.5)
    assert first.max() > 0.05
    assert np.abs(first - second).max() == 0.0
    bad = image_like(volume, shape=SHAPE)
    add_point_array(bad, "fluence", np.repeat(grey, 2, axis=-1))
    with pytest.raises(ValueError, match="1 .grey. or 3 .RGB. components"):
        render_opengl(data, scene, bad, 1.0)
    for window in (w1, w2):
        window.Finalize()
