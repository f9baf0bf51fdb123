"""``add_computed_volume`` / ``grid.illum.add_computed``: the compute path in a pyvista window.

A dense ball (20³, away from the origin so that framing it is not VTK's default view) in
an off-screen 64² plotter (OSMesa). What the window shows must be the compute mapper's
own picture (8-bit, within one level), show the volume (not the plain background),
follow the camera, use the scene :func:`render` builds from the same arguments, and bad
arguments must fail in the call with a message naming them, leaving the plotter as it
was.
"""

import os

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

pv = pytest.importorskip("pyvista")

import vtkillum.pyvista_accessor as accessor
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.tonemap import read_png, tonemap
from vtkillum.mappers import ComputeVolumeRenderer

N = 20
SIZE = 64
CENTRE = np.array([10.0, -5.0, 3.0])
OPACITY = [0.0, 0.6, 0.95]
STYLE = {"cmap": "bone", "opacity": OPACITY, "device": "cpu"}
#: Exposures that show each method's ball well inside the 8-bit range.
EXPOSURE = {"emission": 1.0, "transmittance": 4.0, "illumination": 4.0, "path": 4.0}


@pytest.fixture(scope="module")
def grid():
    """A ball of radius 0.7 (density 1 inside, a soft edge) in a 2 x 2 x 2 box at CENTRE."""
    image = pv.ImageData(dimensions=(N, N, N), spacing=(2 / (N - 1),) * 3,
                         origin=tuple(CENTRE - 1.0))
    x = np.linspace(-1.0, 1.0, N)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    r = np.sqrt(X ** 2 + Y ** 2 + Z ** 2)
    image["density"] = np.clip((0.8 - r) / 0.2, 0.0, 1.0).ravel(order="F")
    return image


@pytest.fixture
def plotter():
    pl = pv.Plotter(off_screen=True, window_size=(SIZE, SIZE))
    pl.set_background("black")
    yield pl
    pl.close()


def look_down_z(pl):
    """Camera on +z of the ball looking at -z, parallel projection framing it."""
    pl.camera_position = [tuple(CENTRE + (0, 0, 6)), tuple(CENTRE), (0.0, 1.0, 0.0)]
    pl.camera.parallel_projection = True
    pl.camera.parallel_scale = 1.1


def covered(image) -> float:
    """Fraction of pixels clearly above the black background."""
    return float((np.asarray(image).max(axis=2) > 10).mean())


def level_difference(a, b) -> int:
    return int(np.abs(np.asarray(a, dtype=int) - np.asarray(b, dtype=int)).max())


@pytest.mark.parametrize("method", ["emission", "transmittance"])
def test_window_shows_the_mappers_picture(grid, plotter, tmp_path, method):
    shown = accessor.add_computed_volume(plotter, grid, method, exposure=EXPOSURE[method],
                                         **STYLE)
    assert isinstance(shown, ComputeVolumeRenderer) and shown.method == method
    path = tmp_path / "shot.png"
    plotter.show(screenshot=str(path), auto_close=False)
    expected = shown.display_image()
    picture = read_png(path)
    assert picture.shape == expected.shape == (SIZE, SIZE, 3)
    assert level_difference(picture, expected) <= 1
    # the ball is in view (the camera framed the grid, not VTK's default box at the origin)
    assert 0.05 < covered(picture) < 0.9, covered(picture)
    plotter.render()
    assert level_difference(plotter.screenshot(), shown.display_image()) <= 1


@pytest.mark.parametrize("method", ["emission", "transmittance"])
def test_orbiting_the_camera_re_renders(grid, plotter, method):
    shown = grid.illum.add_computed(plotter, method, exposure=EXPOSURE[method], **STYLE)
    plotter.render()
    before = plotter.screenshot()
    first = shown.result
    # the ball is symmetric: orbit about a point off its centre so that the view changes
    plotter.camera.focal_point = tuple(CENTRE + (0.4, 0.0, 0.0))
    plotter.camera.azimuth += 10
    plotter.render()
    after = plotter.screenshot()
    assert shown.result is not first                     # the mapper re-rendered
    assert level_difference(after, shown.display_image()) <= 1
    assert level_difference(after, before) > 20          # and the window shows the new view
    assert covered(after) > 0.05


@pytest.mark.parametrize("method", ["transmittance", "illumination"])
def test_scene_is_the_one_render_builds(grid, plotter, method):
    """With the same arguments and the plotter's camera, the picture is render()'s."""
    light = DirectionalLight((-1.0, 0.0, -0.3), (3.0, 3.0, 3.0))
    options = {}
    if method == "illumination":
        options["illumination"] = grid.illum.transmittance(light, cmap="bone",
                                                           opacity=OPACITY, device="cpu")
        lights = None                                    # the illumination's own
    else:
        lights = light
    look_down_z(plotter)
    shown = accessor.add_computed_volume(plotter, grid, method, lights=lights,
                                         exposure=EXPOSURE[method], anisotropy=0.3,
                                         **STYLE, **options)
    plotter.render()
    picture = plotter.screenshot()
    assert plotter.camera.position == pytest.approx(tuple(CENTRE + (0, 0, 6)))  # kept
    (used,) = shown.lights
    assert np.allclose(used.direction, light.direction) and np.allclose(used.irradiance, 3.0)
    reference = grid.illum.render(method, lights=lights, camera=plotter.camera, width=SIZE,
                                  height=SIZE, anisotropy=0.3, **STYLE, **options)
    expected = tonemap(reference.radiance, reference.alpha, (0.0, 0.0, 0.0),
                       exposure=EXPOSURE[method], gamma=1.0)
    assert level_difference(picture, expected) <= 1
    assert covered(picture) > 0.05
    # lit from +x: the right half of the ball is the brighter one
    grey = picture.astype(float).mean(axis=2)
    ball = grey > 2.0
    cols = np.nonzero(ball)[1]
    middle = 0.5 * (cols.min() + cols.max())
    columns = np.arange(SIZE)[None, :].repeat(SIZE, 0)
    assert grey[ball & (columns > middle)].mean() > 1.3 * grey[ball & (columns < middle)].mean()


def test_detach_gives_the_plotter_back(grid, plotter):
    shown = grid.illum.add_computed(plotter, "emission", **STYLE)
    plotter.render()
    assert covered(plotter.screenshot()) > 0.05
    assert len(plotter.renderer.actors) == 1              # the (transparent) bounds actor
    shown.detach()
    plotter.render()
    assert plotter.screenshot().max() == 0                # the black background again
    assert len(plotter.renderer.actors) == 0
    assert not plotter.renderer.GetTexturedBackground()


def test_progressive_path_refines(grid, plotter):
    shown = grid.illum.add_computed(plotter, "path", exposure=EXPOSURE["path"], spp=3,
                                    max_bounces=2, **STYLE)
    assert shown.passes == 1
    assert shown.refine(5) == 3                           # up to spp
    plotter.render()
    assert level_difference(plotter.screenshot(), shown.display_image()) <= 1


@pytest.mark.parametrize("arguments, error, words", [
    ({"method": "bogus"}, ValueError, "method='bogus'"),
    ({"method": "convection_diffusion"}, ValueError, "did you mean 'convection-diffusion'"),
    ({"exposure": -1.0}, ValueError, "exposure must be a positive"),
    ({"exposure": "bright"}, ValueError, "exposure must be a positive"),
    ({"gamma": 0.0}, ValueError, "gamma must be a positive"),
    ({"resolution_scale": 2.0}, ValueError, "resolution_scale must lie in"),
    ({"illumination": np.zeros((N, N, N, 3))}, ValueError, "illumination= is for"),
    ({"method": "illumination"}, ValueError, "needs an illumination volume"),
    ({"bogus_option": 1}, ValueError, "bogus_option"),
    ({"step_size": -1.0}, ValueError, "step_size"),
    ({"albedo": 2.0}, ValueError, "albedo"),
    ({"scalars": "nope"}, ValueError, "no point or cell array 'nope'"),
    ({"clim": (1.0, 0.0)}, ValueError, "clim="),
])
def test_bad_arguments_fail_in_the_call_and_leave_the_plotter(grid, plotter, arguments, error,
                                                              words):
    arguments = {"method": "emission", **arguments}
    with pytest.raises(error) as info:
        grid.illum.add_computed(plotter, **arguments, **STYLE)
    assert words in str(info.value)
    assert len(plotter.renderer.actors) == 0
    assert not plotter.renderer.GetTexturedBackground()
    assert not plotter.renderer.camera_set


def test_a_mesh_that_is_not_image_data_is_refused(plotter):
    mesh = pv.Sphere()
    with pytest.raises(TypeError, match="grid must be a pyvista.ImageData"):
        accessor.add_computed_volume(plotter, mesh, "emission")
    with pytest.raises(AttributeError, match="resample"):
        mesh.illum.add_computed(plotter, "emission")
    with pytest.raises(TypeError, match="plotter must be a pyvista.Plotter"):
        accessor.add_computed_volume("not a plotter", pv.ImageData(dimensions=(4, 4, 4)))


def test_illumination_with_other_lights_is_refused(grid, plotter):
    lit = grid.illum.transmittance(DirectionalLight((1.0, 0.0, 0.0)), cmap="bone",
                                   opacity=OPACITY, device="cpu")
    with pytest.raises(ValueError, match="other lights than lights="):
        grid.illum.add_computed(plotter, "illumination", illumination=lit,
                                lights=DirectionalLight((0.0, 0.0, -1.0)), **STYLE)
