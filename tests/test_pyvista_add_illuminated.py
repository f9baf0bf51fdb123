"""``add_illuminated_volume`` shows every light filter's output, ambient extinction included.

A dense ball seen along -z in an off-screen pyvista plotter (OSMesa), lit from +x and
then from -x. For each method of the accessor (``transmittance``, ``convection_diffusion``,
``photon_density``, ``many_lights``, ``ambient_extinction``), given as its output and by
name, the picture must be lit (the ball covers pixels well above the black background)
and follow the light: the half of the ball facing the light is the brighter one, and
moving the light to the other side swaps the halves. (Issue 34: the ambient output gave
VTK error spam and a ValueError.)
"""

import os

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

pv = pytest.importorskip("pyvista")
pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")

import vtkillum.pyvista_accessor as accessor  # noqa: E402
from vtkillum.core.lights import DirectionalLight  # noqa: E402
from vtkillum.mappers import AmbientScatteringVolume, IlluminatedVolume  # noqa: E402

N = 20
SIZE = 96
OPACITY = [0.0, 0.6, 0.95]
#: Small settings where a method has costly defaults (the CPU runs these).
SETTINGS = {"transmittance": {}, "convection_diffusion": {},
            "photon_density": {"photons": 20_000}, "many_lights": {"count": 32},
            "ambient_extinction": {}}


@pytest.fixture(scope="module")
def grid():
    """A ball of radius 0.7 (density 1 inside, a soft edge) in a 2 x 2 x 2 box."""
    image = pv.ImageData(dimensions=(N, N, N), spacing=(2 / (N - 1),) * 3, origin=(-1, -1, -1))
    x = np.linspace(-1.0, 1.0, N)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    r = np.sqrt(X ** 2 + Y ** 2 + Z ** 2)
    image["density"] = np.clip((0.8 - r) / 0.2, 0.0, 1.0).ravel(order="F")
    return image


def light(travel_x: float):
    """A white directional light travelling along +x (from -x) or -x (from +x)."""
    return DirectionalLight((travel_x, 0.0, 0.0), (3.0, 3.0, 3.0))


def picture(grid, illumination, **kwargs):
    """The plotter's picture (grey, float) and the actor, camera on +z looking at -z."""
    plotter = pv.Plotter(off_screen=True, window_size=(SIZE, SIZE))
    try:
        plotter.set_background("black")
        actor = accessor.add_illuminated_volume(plotter, grid, illumination, cmap="bone",
                                                opacity=OPACITY, render=False, **kwargs)
        plotter.camera_position = [(0.0, 0.0, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
        plotter.camera.parallel_projection = True
        plotter.camera.parallel_scale = 1.1
        plotter.render()
        image = np.asarray(plotter.screenshot(), dtype=np.float64).mean(axis=2)
    finally:
        plotter.close()
    return image, actor


def halves(image):
    """Mean brightness of the left (-x) and right (+x) halves of the ball's pixels."""
    covered = image > 2.0
    columns = np.nonzero(covered)[1]
    middle = 0.5 * (columns.min() + columns.max())
    cols = np.arange(image.shape[1])[None, :].repeat(image.shape[0], 0)
    left = image[covered & (cols < middle)].mean()
    right = image[covered & (cols > middle)].mean()
    return left, right


def check_lit(image, name):
    covered = image > 2.0
    assert covered.mean() > 0.1, f"{name}: the ball covers {covered.mean():.0%} of the picture"
    assert image.max() > 40.0, f"{name}: the brightest pixel is {image.max()} of 255"


@pytest.mark.parametrize("method", list(SETTINGS))
def test_every_filter_output_is_shown_lit_and_follows_the_light(grid, method):
    images = {}
    for travel in (-1.0, 1.0):
        output = getattr(grid.illum, method)(lights=[light(travel)], cmap="bone",
                                             opacity=OPACITY, device="cpu", **SETTINGS[method])
        image, actor = picture(grid, output)
        expected = AmbientScatteringVolume if method == "ambient_extinction" else IlluminatedVolume
        assert isinstance(actor, expected), (method, type(actor).__name__)
        check_lit(image, method)
        images[travel] = image
    # Light from +x (travelling -x): the right half is the lit one; from -x the left.
    left, right = halves(images[-1.0])
    assert right > 1.2 * left, (method, "light from +x", left, right)
    left, right = halves(images[1.0])
    assert left > 1.2 * right, (method, "light from -x", left, right)


@pytest.mark.parametrize("method", ["photon_density", "ambient_extinction"])
def test_a_method_named_is_computed_with_the_lights(grid, method):
    """``illumination="ambient_extinction"`` (and the other names) computes the output
    here with the given lights: the lit side follows them."""
    image, actor = picture(grid, method, lights=[light(-1.0)])
    check_lit(image, method)
    left, right = halves(image)
    assert right > 1.2 * left, (method, left, right)


def test_ambient_output_keeps_its_radius_and_lights(grid):
    """The ambient mapper gets the radius the output was computed with, and its lights
    (other lights are an error, as for the other methods' outputs)."""
    output = grid.illum.ambient_extinction(lights=[light(-1.0)], radius=2.5, cmap="bone",
                                           opacity=OPACITY, device="cpu")
    _, actor = picture(grid, output)
    assert actor.state.radius == pytest.approx(2.5 * 2 / (N - 1), rel=1e-6)  # voxels -> world
    assert [lt.direction.tolist() for lt in actor.scene.lights] == [[-1.0, 0.0, 0.0]]
    with pytest.raises(ValueError, match="other lights"):
        picture(grid, output, lights=[light(1.0)])


def test_ambient_extinction_alone_is_shown_with_the_lights_given(grid):
    """Without its radiance cache (``compute_radiance=False``) the output records no
    lights: ``lights=`` light the picture."""
    output = grid.illum.ambient_extinction(compute_radiance=False, cmap="bone",
                                           opacity=OPACITY, device="cpu")
    image, actor = picture(grid, output, lights=[light(1.0)])
    assert isinstance(actor, AmbientScatteringVolume)
    check_lit(image, "ambient, lights given")
    left, right = halves(image)
    assert left > 1.2 * right, (left, right)


@pytest.mark.parametrize("given", ["filter", "port"])
def test_ambient_extinction_filter_itself_gives_its_radius_and_lights(grid, given):
    """An AmbientExtinctionFilter (or its output port) from a VTK pipeline: the mapper
    takes the filter's Radius, RadiusUnits and lights."""
    from vtkillum.filters import AmbientExtinctionFilter

    algorithm = AmbientExtinctionFilter()
    algorithm.SetInputData(grid)
    algorithm.SetRadius(1.5)
    algorithm.SetRadiusUnits("world")
    algorithm.SetLights([light(-1.0)])
    image, actor = picture(grid, algorithm if given == "filter" else algorithm.GetOutputPort())
    assert isinstance(actor, AmbientScatteringVolume)
    assert actor.state.radius == pytest.approx(1.5)
    check_lit(image, f"ambient {given}")
    left, right = halves(image)
    assert right > 1.2 * left, (left, right)


def test_a_named_illumination_follows_scene_edits(grid):
    """``illumination="transmittance"``: ``set_scene`` with another light (or transfer
    function) computes the shadows again, so the edited volume draws what a volume made
    with the new scene draws; an edit of the shading alone recomputes nothing."""
    import dataclasses

    plotter = pv.Plotter(off_screen=True, window_size=(SIZE, SIZE))
    try:
        plotter.set_background("black")
        actor = accessor.add_illuminated_volume(plotter, grid, "transmittance",
                                                lights=[light(-1.0)], cmap="bone",
                                                opacity=OPACITY, render=False, jitter=False)
        assert actor.relight is not None
        plotter.camera_position = [(0.0, 0.0, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
        plotter.camera.parallel_projection = True
        plotter.camera.parallel_scale = 1.1
        calls = []
        relight = actor.relight
        actor.relight = lambda scene: calls.append(scene) or relight(scene)
        actor.set_scene(dataclasses.replace(actor.scene, shading=dict(actor.scene.shading,
                                                                      ambient=0.3)))
        assert calls == []  # shading only: the light grids stand
        actor.set_scene(dataclasses.replace(actor.scene, lights=[light(1.0)]))
        assert len(calls) == 1
        # a failing recomputation leaves the volume as it was
        kept = actor.scene
        actor.relight = lambda scene: (_ for _ in ()).throw(ValueError("no light volume"))
        with pytest.raises(ValueError, match="no light volume"):
            actor.set_scene(dataclasses.replace(kept, lights=[light(-1.0)]))
        assert actor.scene is kept
        plotter.render()
        edited = np.asarray(plotter.screenshot(), dtype=np.float64).mean(axis=2)
    finally:
        plotter.close()
    left, right = halves(edited)
    assert left > 1.2 * right, ("the edited light comes from -x now", left, right)
    fresh, _ = picture(grid, "transmittance", lights=[light(1.0)], jitter=False,
                       shading=dict(ambient=0.3))
    assert np.abs(edited - fresh).max() <= 1.0
