"""Light grids on a warp device reach VTK's textures without the host (issue 35).

``IlluminatedVolume.device_upload`` packs device-resident grids to 16 bit where they live
(:mod:`vtkillum.core.texels`) and copies them through an OpenGL pixel buffer into the
textures VTK made (:mod:`vtkillum.mappers.texture_upload`). Here the device is warp's CPU
and the OpenGL is llvmpipe, so the pixel buffer is filled from host memory; on CUDA the
same buffer is mapped into the GPU: ``VTKILLUM_TEST_WARP_DEVICE=cuda:0`` runs these tests
so, on a GPU whose OpenGL is NVIDIA's (EGL). What they
prove: the texels are ``pack_channels``' bit for bit; the picture is the host path's bit
for bit; the images are not touched and VTK uploads nothing else; every case the writer
cannot take (first grids, another size, a failed write, textures made anew) still draws
the right picture.
"""

import os

import numpy as np
import pytest
from helpers import read_window_rgb
from test_illumination_images import SHAPE, skewed_blobs
from test_mappers import blob_lights, direct_light, make_scene, render_opengl, slab_fluence

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
import warp as wp  # noqa: E402
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402

from vtkillum.core import texels  # noqa: E402
from vtkillum.core.device_arrays import TRAFFIC  # noqa: E402
from vtkillum.core.illumination import IlluminationVolume  # noqa: E402
from vtkillum.core.resample import resample_points  # noqa: E402
from vtkillum.io.convert import image_data_from_volume  # noqa: E402
from vtkillum.mappers.gl_trace import GLCallCounter  # noqa: E402
from vtkillum.mappers.illuminated_volume_mapper import (  # noqa: E402
    DIRECT_PORT_A,
    pack_channels,
)

#: warp's device holding the grids (CUDA runs the interop path; see the module docstring)
DEVICE = os.environ.get("VTKILLUM_TEST_WARP_DEVICE", "cpu")


def test_device_texels_are_pack_channels_bit_for_bit():
    rng = np.random.default_rng(7)
    t = rng.random((6, 5, 7, 4)).astype(np.float32)
    t[0, 0, 0, 0], t[1, 0, 0, 1], t[2, 0, 0, 2] = 1.0, 0.0, 0.5 / 65535  # ends, a half-way tie
    for lights in ([0, 1, 2, 3], [4, 5], [2]):
        ref, q = pack_channels(np.moveaxis(t, 0, -1), True, unit_range=True, channels=lights)
        out = wp.empty(texels.texel_shape(t.shape[1:]), dtype=wp.uint16, device=DEVICE)
        assert texels.pack_transmittance(wp.array(t, dtype=wp.float32, device=DEVICE),
                                         lights, out) == q
        assert np.array_equal(out.numpy().reshape(ref.shape), ref)
    s = (rng.random((5, 7, 4, 3)) * np.array([3.0, 0.2, 0.0])).astype(np.float32)  # B all 0
    ref, q = pack_channels(s, True, channels=[0, 1, 2])
    out = wp.empty(texels.texel_shape(s.shape[:3]), dtype=wp.uint16, device=DEVICE)
    assert texels.pack_fluence(wp.array(s, dtype=wp.vec3, device=DEVICE), out) == q
    assert np.array_equal(out.numpy().reshape(ref.shape), ref)
    with pytest.raises(ValueError, match="uint16"):
        texels.pack_fluence(wp.array(s, dtype=wp.vec3, device=DEVICE), out[:-1])


def test_ambient_texels_are_the_host_images_bit_for_bit():
    """σ̃t and the grey radiance cache laid out on the device equal what the host path
    hands VTK (``add_point_array`` of ``grey_radiance``), and a cache that is not grey
    times its light's colour is refused as on the host."""
    from vtkillum.core.lights import DirectionalLight, PointLight, pack_lights
    from vtkillum.core.volume import Volume
    from vtkillum.io.convert import add_point_array, image_like
    from vtkillum.mappers.ambient_volume_mapper import grey_radiance

    rng = np.random.default_rng(3)
    sigma = rng.random((5, 6, 7)).astype(np.float32)
    volume = Volume(sigma)
    out = wp.empty(texels.texel_shape(sigma.shape, 1, x_fastest=True), dtype=wp.float32,
                   device=DEVICE)
    texels.pack_scalar(wp.array(sigma, dtype=wp.float32, device=DEVICE), out)
    assert np.array_equal(out.numpy().reshape(-1), vtk_to_numpy(add_point_array(image_like(volume), "s",
                                                                     sigma)))
    lights = [DirectionalLight((1.0, 0.0, 0.0), (3.0, 2.4, 1.8)),
              PointLight((5.0, 5.0, 5.0), (800.0, 800.0, 900.0)),
              DirectionalLight((0.0, 1.0, 0.0), (0.0, 0.0, 0.0))]  # a dark light: 0
    _, _, rgb = pack_lights(lights)
    grey = rng.random((3, 5, 6, 7))
    cache = (grey[..., None] * rgb.astype(np.float64)[:, None, None, None, :]).astype(np.float32)
    expected = add_point_array(image_like(volume), "g", grey_radiance(cache, lights, volume))
    device_cache = wp.array(cache, dtype=wp.vec3, device=DEVICE)
    texels.check_grey(device_cache, rgb)
    out = wp.empty(texels.texel_shape(sigma.shape, 4, x_fastest=True), dtype=wp.float32,
                   device=DEVICE)
    texels.pack_grey(device_cache, rgb, out)
    assert np.array_equal(out.numpy().reshape(-1), vtk_to_numpy(expected).reshape(-1))
    cache[1, 2, 3, 4, 0] *= 1.01  # no longer grey times the colour
    with pytest.raises(RuntimeError, match="light 1 is not grey"):
        texels.check_grey(wp.array(cache, dtype=wp.vec3, device=DEVICE), rgb)
    with pytest.raises(RuntimeError, match="light 1 is not grey"):
        grey_radiance(cache, lights, volume)


@pytest.fixture(scope="module")
def grids():
    volume = skewed_blobs()
    scene = make_scene(volume, lights=blob_lights(volume))
    transmittance = direct_light(volume, scene, shape=SHAPE, device=DEVICE)
    scattered = resample_points(slab_fluence(volume, scene.transfer_function),
                                SHAPE).astype(np.float32)
    return volume, scene, transmittance, scattered


def on_device(volume, scattered, transmittance):
    """An IlluminationVolume whose grids are warp arrays (on :data:`DEVICE`)."""
    return IlluminationVolume.for_volume(
        volume, None if scattered is None else wp.array(scattered, dtype=wp.vec3, device=DEVICE),
        None if transmittance is None else wp.array(transmittance, dtype=wp.float32,
                                                    device=DEVICE))


def host_picture(volume, scene, scattered, transmittance):
    picture, _actor, window = render_opengl(
        image_data_from_volume(volume), scene,
        IlluminationVolume.for_volume(volume, scattered, transmittance), 1.5)
    window.Finalize()
    return picture


def break_pending_writes(writer) -> None:
    """Make the scheduled writes fail as they would without CUDA–OpenGL interop."""
    def broken(out):
        raise RuntimeError("interop unavailable")

    for job in writer.pending.values():
        job.pack = broken


def assert_drawn_through_host(writer, window, expected, error: str) -> None:
    """No write was made (``error`` says why), the picture is ``expected`` (the host
    path's) bit for bit; the window is closed."""
    assert writer.writes == 0 and error in writer.last_error
    assert np.abs(read_window_rgb(window) - expected).max() == 0.0
    window.Finalize()


def writing(volume, scene, scattered, transmittance, watched: bool = True):
    """``(first picture, actor, window, writer)``: device grids drawn with ``device_upload``
    off, then turned on and (``watched``) one frame drawn with the writer watching."""
    first, actor, window = render_opengl(image_data_from_volume(volume), scene,
                                         on_device(volume, scattered, transmittance), 1.5,
                                         accumulate=1, device_upload=False)
    actor.device_upload = True
    if watched:
        window.Render()
    return first, actor, window, actor.inputs.writer


def test_new_grids_are_written_into_vtks_textures(grids):
    volume, scene, transmittance, scattered = grids
    first, actor, window, writer = writing(volume, scene, scattered, transmittance)
    assert writer.writes == 0 and writer.can_write(DIRECT_PORT_A, SHAPE[::-1])
    assert np.abs(read_window_rgb(window) - first).max() == 0.0
    # a TF edit: new grids of the same size, on the device
    edited_t, edited_s = transmittance ** 2, scattered * 0.6
    images = (*actor.inputs.direct_images, actor.inputs.scattered_image)
    stamps = [image.GetMTime() for image in images]
    edited = on_device(volume, edited_s, edited_t)
    TRAFFIC.reset()
    actor.set_illumination(edited)
    with GLCallCounter() as gl:
        window.Render()
    drawn = read_window_rgb(window)
    assert writer.writes == 2 and writer.last_error is None  # 2 lights: port A; scattered
    # no grid went to the host on the way (on a GPU a download is most of a 512³ edit)
    assert TRAFFIC.downloads == 0
    # the grids' only uploads are the two writes (the optics table is re-made as ever)
    grid_uploads = [u for u in gl.uploads_3d if u[:3] == SHAPE[::-1]]
    assert gl.calls["glTexSubImage3D"] == 2 and len(grid_uploads) == 2
    assert [image.GetMTime() for image in images] == stamps  # the host images untouched
    expected = host_picture(volume, scene, edited_s, edited_t)
    assert np.abs(drawn - first).max() > 0.05
    assert np.abs(drawn - expected).max() == 0.0
    # the host images are brought up to date in the background: what the host path packs
    writer.sync_host()
    _, host_actor, host_window = render_opengl(
        image_data_from_volume(volume), scene,
        IlluminationVolume.for_volume(volume, edited_s, edited_t), 1.5)
    for mine, theirs in zip(images[:1] + images[2:], (*host_actor.inputs.direct_images[:1],
                                     host_actor.inputs.scattered_image)):
        assert np.array_equal(vtk_to_numpy(mine.GetPointData().GetScalars()),
                              vtk_to_numpy(theirs.GetPointData().GetScalars()))
    host_window.Finalize()
    assert [image.GetMTime() for image in images] == stamps
    # so VTK's textures made anew (as after a lost context) hold the new grids
    actor.mapper.ReleaseGraphicsResources(window)
    window.Render()
    assert np.abs(read_window_rgb(window) - expected).max() == 0.0
    # the new textures (their names are the old ones again, their labels gone) are found
    # again by their texels, which the background copy made the new grids'
    again_t = transmittance ** 3
    actor.set_illumination(on_device(volume, edited_s, again_t))
    window.Render()
    assert writer.writes == 4
    expected = host_picture(volume, scene, edited_s, again_t)
    assert np.abs(read_window_rgb(window) - expected).max() == 0.0
    # grids of another size: through the host once (VTK makes the textures of that size),
    # then written again (new pixel buffers; the old ones freed)
    small_t = direct_light(volume, scene, shape=(12, 9, 7), device=DEVICE)
    small_s = resample_points(edited_s, (12, 9, 7)).astype(np.float32)
    actor.set_illumination(on_device(volume, small_s, small_t))
    window.Render()
    assert writer.writes == 4
    actor.set_illumination(on_device(volume, small_s * 0.5, small_t ** 2))
    window.Render()
    assert writer.writes == 6 and writer.last_error is None
    expected = host_picture(volume, scene, small_s * 0.5, small_t ** 2)
    assert np.abs(read_window_rgb(window) - expected).max() == 0.0
    # off: the host path, which packs the current grids again
    actor.device_upload = False
    window.Render()
    assert np.abs(read_window_rgb(window) - expected).max() == 0.0
    window.Finalize()


def test_what_the_writer_cannot_take_goes_through_the_host(grids):
    volume, scene, transmittance, scattered = grids
    _first, actor, window, writer = writing(volume, scene, None, transmittance)
    # grids of another size: the host path (VTK makes textures of the new size)
    smaller = direct_light(volume, scene, shape=(12, 9, 7), device=DEVICE)
    actor.set_illumination(on_device(volume, None, smaller))
    window.Render()
    assert writer.writes == 0
    assert np.abs(read_window_rgb(window) - host_picture(volume, scene, None, smaller)).max() \
        == 0.0
    # scattered fluence where the previous grids had none (its texture is a placeholder)
    actor.set_illumination(on_device(volume, resample_points(scattered, (12, 9, 7))
                                     .astype(np.float32), smaller))
    window.Render()
    assert writer.writes == 0
    # numpy grids: the host path
    actor.set_illumination(IlluminationVolume.for_volume(volume, None, smaller * 0.5))
    window.Render()
    assert writer.writes == 0
    # a write that fails at the render's start: the host path draws the same frame
    dimmer = smaller * 0.3
    actor.set_illumination(on_device(volume, None, dimmer))
    actor.check()
    assert writer.pending  # scheduled: the textures are known and of this size
    break_pending_writes(writer)
    window.Render()
    assert_drawn_through_host(writer, window, host_picture(volume, scene, None, dimmer),
                              "interop unavailable")


def test_device_upload_is_on_by_default_and_takes_a_bool(grids):
    volume, scene, transmittance, _ = grids
    _first, actor, window = render_opengl(image_data_from_volume(volume), scene,
                                          on_device(volume, None, transmittance), 1.5)
    assert actor.device_upload is True and actor.inputs.writer is not None
    with pytest.raises(TypeError, match="device_upload must be True or False"):
        actor.device_upload = "yes"
    assert actor.device_upload is True  # the bad value changed nothing
    actor.device_upload = False
    assert actor.device_upload is False and actor.inputs.writer is None
    window.Finalize()
    _first, actor, window = render_opengl(image_data_from_volume(volume), scene,
                                          on_device(volume, None, transmittance), 1.5,
                                          device_upload=False)
    assert actor.device_upload is False and actor.inputs.writer is None
    window.Finalize()


def test_textures_are_found_by_their_texels(grids):
    """VTK's texture is found among all textures by its texels, which are the port
    image's once the mapper has drawn it with the writer watching (one frame)."""
    volume, scene, transmittance, scattered = grids
    _first, actor, window, writer = writing(volume, scene, scattered, transmittance,
                                            watched=False)
    actor.set_illumination(on_device(volume, scattered, transmittance * 0.9))
    window.Render()  # not seen drawn yet: through the host
    assert writer.writes == 0 and not writer.textures
    edited_t = transmittance * 0.7
    actor.set_illumination(on_device(volume, scattered, edited_t))
    window.Render()
    assert writer.writes == 2 and sorted(writer.textures) == [2, 4]
    assert np.abs(read_window_rgb(window) - host_picture(volume, scene, scattered, edited_t)) \
        .max() == 0.0
    window.Finalize()


def test_a_texture_that_cannot_be_told_apart_is_not_written(grids):
    """Two volumes with the same grids in one window: two textures alike. The writer
    takes neither (the host path draws), never the other volume's."""
    from helpers import offscreen_window
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from vtkillum.mappers import IlluminatedVolume

    volume, scene, transmittance, _ = grids
    data = image_data_from_volume(volume)
    renderer = vtkRenderer()
    actors = [IlluminatedVolume(data, scene, illumination=on_device(volume, None, transmittance),
                                exposure=1.5, jitter=False, accumulate=1) for _ in range(2)]
    for actor in actors:
        renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, 64, 64)
    window.Render()
    mine, other = actors
    mine.device_upload = True
    writer = mine.inputs.writer
    other_texels = vtk_to_numpy(other.inputs.direct_images[0].GetPointData().GetScalars()).copy()
    edited = transmittance * 0.5
    mine.set_illumination(on_device(volume, None, edited))
    window.Render()
    assert writer.writes == 0 and not writer.textures
    ref, _q = pack_channels(np.moveaxis(edited, 0, -1), True, unit_range=True)
    assert np.array_equal(  # the host path packed the new grids into the image
        vtk_to_numpy(mine.inputs.direct_images[0].GetPointData().GetScalars()),
        ref.reshape(-1, 4))
    assert np.array_equal(
        vtk_to_numpy(other.inputs.direct_images[0].GetPointData().GetScalars()), other_texels)
    window.Finalize()


def test_a_volume_not_drawn_yet_never_writes_into_another_volumes_texture(grids):
    """A second volume with the same grids as a drawn one, given new device grids before
    its first frame: its own textures do not exist yet and the first volume's texture has
    the texels of its image, but the writer only looks once its mapper has drawn."""
    from helpers import offscreen_window
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from vtkillum.mappers import IlluminatedVolume

    volume, scene, transmittance, _ = grids
    data = image_data_from_volume(volume)
    renderer = vtkRenderer()
    first = IlluminatedVolume(data, scene, illumination=on_device(volume, None, transmittance),
                              exposure=1.5, jitter=False, accumulate=1)
    renderer.AddVolume(first)
    window = offscreen_window(renderer, scene.camera, 64, 64)
    window.Render()
    texels_before = vtk_to_numpy(first.inputs.direct_images[0].GetPointData().GetScalars()
                                 ).copy()
    second = IlluminatedVolume(data, scene, illumination=on_device(volume, None, transmittance),
                               exposure=1.5, jitter=False, accumulate=1)
    second.device_upload = True
    second.set_illumination(on_device(volume, None, transmittance * 0.5))
    renderer.AddVolume(second)
    window.Render()
    assert second.inputs.writer.writes == 0
    first.SetVisibility(False)
    window.Render()
    alone = read_window_rgb(window)
    renderer.RemoveVolume(second)
    first.SetVisibility(True)
    window.Render()
    assert np.abs(read_window_rgb(window) - host_picture(volume, scene, None, transmittance)) \
        .max() == 0.0  # the first volume's texture untouched
    assert np.array_equal(vtk_to_numpy(first.inputs.direct_images[0].GetPointData()
                                       .GetScalars()), texels_before)
    assert np.abs(alone - host_picture(volume, scene, None, transmittance * 0.5)).max() == 0.0
    window.Finalize()


def test_an_opengl_without_the_calls_draws_through_the_host(grids):
    """OpenGL 4.1 (macOS) has no glGetTextureSubImage: the first grids that need it go
    through the host, with the reason kept."""
    volume, scene, transmittance, _ = grids
    _first, actor, window, writer = writing(volume, scene, None, transmittance)
    gl = writer._gl_calls()

    def missing(*args):
        raise RuntimeError("glGetTextureSubImage is not loaded: no OpenGL context was made "
                           "current")

    gl.GetTextureSubImage = missing
    edited = transmittance * 0.4
    actor.set_illumination(on_device(volume, None, edited))
    window.Render()
    assert_drawn_through_host(writer, window, host_picture(volume, scene, None, edited),
                              "glGetTextureSubImage")


def test_the_writer_goes_with_its_volume(grids):
    """A volume let go frees its writer, whose mapper observers refer to it (Python's
    collector sees through VTK's observers), and with it the pixel buffers and texels."""
    import gc
    import weakref

    volume, scene, transmittance, _ = grids
    _first, actor, window, writer = writing(volume, scene, None, transmittance)
    actor.set_illumination(on_device(volume, None, transmittance * 0.5))
    window.Render()
    assert writer.writes == 1
    gone = weakref.ref(writer)
    window.Finalize()
    del actor, window, writer
    gc.collect()
    assert gone() is None


# --- AmbientScatteringVolume: σ̃t and the radiance cache from the cache's device ---------------------
def ambient_window(volume, scene, device_upload: bool, data=None):
    """``(actor, window)``: an AmbientScatteringVolume of ``volume`` (or of ``data``, a
    pipeline connection) on :data:`DEVICE`, one frame drawn."""
    from helpers import offscreen_window
    from test_ambient_mapper import HEIGHT, WIDTH
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from vtkillum.mappers import AmbientScatteringVolume

    actor = AmbientScatteringVolume(data or image_data_from_volume(volume), scene, exposure=2.0,
                                    device=DEVICE, device_upload=device_upload)
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    window = offscreen_window(renderer, scene.camera, WIDTH, HEIGHT)
    window.Render()
    return actor, window


def test_ambient_edits_are_written_into_vtks_textures():
    """A TF edit and a g edit: σ̃t and the radiance cache are laid out on the cache's
    device (x fastest, grey per light) and written into VTK's float textures; the picture
    is the host path's bit for bit, the images are untouched, VTK uploads no grid."""
    from test_ambient_mapper import blob_tf, blob_volume, make_scene

    volume = blob_volume()
    scene = make_scene(volume)
    edited = make_scene(volume)
    edited.transfer_function = blob_tf(0.6)
    actor, window = ambient_window(volume, scene, True)
    writer = actor.inputs.writer
    images = (actor.inputs.data_image, actor.inputs.extinction_image,
              actor.inputs.radiance_image)
    stamps = [image.GetMTime() for image in images]
    grids = {tuple(image.GetDimensions()) for image in images}
    TRAFFIC.reset()
    actor.set_scene(edited)
    with GLCallCounter() as gl:
        window.Render()
    drawn = read_window_rgb(window)
    assert writer.writes == 2 and writer.last_error is None
    assert sorted(writer.textures) == [2, 3]  # EXTINCTION_PORT, RADIANCE_PORT
    assert gl.calls["glTexSubImage3D"] == 2
    assert not [u for u in gl.uploads_3d if u[:3] in grids and u[3] is not None]  # no re-make
    assert [image.GetMTime() for image in images] == stamps
    assert TRAFFIC.downloads == 0
    host, host_window = ambient_window(volume, edited, False)
    expected = read_window_rgb(host_window)
    assert np.abs(drawn - expected).max() == 0.0
    # the images hold the new grids once the background copies end (as the host path's)
    writer.sync_host()
    for mine, theirs in ((actor.inputs.extinction_image, host.inputs.extinction_image),
                         (actor.inputs.radiance_image, host.inputs.radiance_image)):
        assert np.array_equal(vtk_to_numpy(mine.GetPointData().GetScalars()),
                              vtk_to_numpy(theirs.GetPointData().GetScalars()))
    # g: the radiance cache alone
    backward = make_scene(volume, anisotropy=-0.5)
    backward.transfer_function = blob_tf(0.6)
    actor.set_scene(backward)
    window.Render()
    assert writer.writes == 3
    host.set_scene(backward)
    host_window.Render()
    assert np.abs(read_window_rgb(window) - read_window_rgb(host_window)).max() == 0.0
    # turned off: the host path again, the same picture
    actor.device_upload = False
    window.Render()
    assert np.abs(read_window_rgb(window) - read_window_rgb(host_window)).max() == 0.0
    window.Finalize()
    host_window.Finalize()


def test_ambient_data_edits_and_failed_writes_go_through_the_host():
    """New data (a new texture size) and a write that fails draw the host path's picture."""
    from test_ambient_mapper import blob_tf, blob_volume, make_scene
    from vtkmodules.vtkCommonExecutionModel import vtkTrivialProducer

    volume = blob_volume()
    scene = make_scene(volume)
    producer = vtkTrivialProducer()
    producer.SetOutput(image_data_from_volume(volume))
    actor, window = ambient_window(volume, scene, True, producer.GetOutputPort())
    writer = actor.inputs.writer
    # a failing write (interop unavailable): the same render draws through the host
    edited = make_scene(volume)
    edited.transfer_function = blob_tf(0.8)
    actor.set_scene(edited)
    break_pending_writes(writer)
    window.Render()
    assert writer.writes == 0 and "interop unavailable" in writer.last_error
    host, host_window = ambient_window(volume, edited, False)
    assert np.abs(read_window_rgb(window) - read_window_rgb(host_window)).max() == 0.0
    # new data of another size: the host path, then writes again
    smaller = blob_volume(0.9)
    smaller = smaller.__class__(smaller.scalars[:20, :18, :22], spacing=smaller.spacing,
                                origin=smaller.origin, direction=smaller.direction)
    producer.SetOutput(image_data_from_volume(smaller))
    window.Render()
    assert writer.writes == 0
    actor.set_scene(scene)
    window.Render()
    assert writer.writes == 2, writer.last_error
    check, check_window = ambient_window(smaller, scene, False)
    assert np.abs(read_window_rgb(window) - read_window_rgb(check_window)).max() == 0.0
    for w in (window, host_window, check_window):
        w.Finalize()


def test_ambient_writes_read_back_exactly_after_a_single_valued_grid():
    """The shader reads the float texels as they are, not through VTK's normalisation by
    the range of the grid a texture was made from (which a write keeps): after an
    all-zero σ̃t (nothing opaque, a range of one value) the written grids draw the host
    path's picture bit for bit."""
    from test_ambient_mapper import blob_tf, blob_volume, make_scene

    volume = blob_volume()
    clear = make_scene(volume)
    clear.transfer_function = blob_tf(0.0)
    actor, window = ambient_window(volume, clear, True)
    assert vtk_to_numpy(actor.inputs.extinction_image.GetPointData().GetScalars()).max() == 0
    scene = make_scene(volume)
    actor.set_scene(scene)
    window.Render()
    assert actor.inputs.writer.writes == 2
    host, host_window = ambient_window(volume, scene, False)
    assert np.abs(read_window_rgb(window) - read_window_rgb(host_window)).max() == 0.0
    assert read_window_rgb(window).max() > 0.1  # not a black picture
    window.Finalize()
    host_window.Finalize()


def test_ambient_writes_not_made_yet_go_through_the_host_with_the_next_edit():
    """A TF edit schedules both writes; a second edit before any render that must take
    the host path (a radiance cache of another size) fills both images, so the new σ̃t is
    not lost with the dropped write."""
    from test_ambient_mapper import blob_tf, blob_volume, make_scene

    volume = blob_volume()
    actor, window = ambient_window(volume, make_scene(volume), True)
    edited = make_scene(volume)
    edited.transfer_function = blob_tf(0.5)
    actor.set_scene(edited)
    assert sorted(actor.inputs.writer.pending) == [2, 3]
    actor.set_options(radiance_cache_scale=0.25)
    window.Render()
    assert actor.inputs.writer.writes == 0 and not actor.inputs.writer.pending
    host, host_window = ambient_window(volume, edited, False)
    host.set_options(radiance_cache_scale=0.25)
    host_window.Render()
    assert np.abs(read_window_rgb(window) - read_window_rgb(host_window)).max() == 0.0
    window.Finalize()
    host_window.Finalize()
