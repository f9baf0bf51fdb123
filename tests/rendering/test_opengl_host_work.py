"""What a camera move costs on the host: no texture upload, no shader build (issue 35).

The OpenGL calls VTK makes are counted by swapping its loader's function pointers
(:class:`vtkillum.mappers.gl_trace.GLCallCounter`): exact counts, whatever the driver. A
camera move must draw with the textures and the program it has: a re-upload of the data or
of an illumination grid would make every frame cost a transfer of the whole volume, and a
rebuilt shader a compile. A transfer-function edit re-uploads only the small optics image
(table and occupancy), never the data or the illumination grids. The tests also check
that a camera move's host work does not grow with the volume (the calls counted are the
same at two sizes), and that the 16-bit illumination textures and the empty-block leaps
keep the picture.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import offscreen_window, read_window_rgb

from vtkillum.core.camera import Camera
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.data import procedural

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")
from vtkmodules.vtkRenderingCore import vtkRenderer

from vtkillum.io.convert import image_data_from_volume
from vtkillum.mappers import IlluminatedVolume
from vtkillum.mappers.gl_trace import GLCallCounter
from vtkillum.mappers.illuminated_volume_mapper import OPTICS_ROW


def scene_for(volume, opacity_scale: float = 1.0) -> Scene:
    lo, hi = volume.value_range
    tf = TransferFunction([lo, lo + 0.3 * (hi - lo), hi],
                          [0.0, 0.2 * opacity_scale, 0.45 * opacity_scale],
                          [[1, 1, 1], [1, 0.8, 0.6], [1, 1, 1]])
    return Scene(transfer_function=tf, lights=[DirectionalLight((1, -1, -1), (3, 3, 3))])


def illumination_for(volume, shape) -> IlluminationVolume:
    """A transmittance (1 light) and a scattered fluence on a grid of ``shape`` points."""
    x = np.linspace(0.2, 1.0, shape[0], dtype=np.float32)[:, None, None]
    t = np.broadcast_to(x, shape).copy()
    phi = np.stack([t * 0.3, t * 0.2, t * 0.1], axis=-1)
    return IlluminationVolume.for_volume(volume, transmittance=t[None], scattered=phi)


def shown(size: int, image: int = 48):
    volume = procedural.smoke_plume((size, size, size))
    scene = scene_for(volume)
    actor = IlluminatedVolume(image_data_from_volume(volume), scene,
                              illumination=illumination_for(volume, (size // 2,) * 3),
                              jitter=False, exposure=4.0)
    renderer = vtkRenderer()
    renderer.AddVolume(actor)
    c = np.asarray(volume.bounds).reshape(3, 2).mean(axis=1)
    camera = Camera(position=tuple(np.asarray(c) + [0.0, -4.0 * volume.extent.max(), 0.0]),
                    focal_point=tuple(c), view_up=(0, 0, 1), view_angle=30)
    window = offscreen_window(renderer, camera, image, image)
    window.Render()  # builds the shader, uploads the textures, loads the GL functions
    window.Render()
    return window, renderer, actor, volume


def camera_moves(window, renderer, moves: int = 2) -> GLCallCounter:
    with GLCallCounter() as gl:
        for _ in range(moves):
            renderer.GetActiveCamera().Azimuth(5.0)
            renderer.ResetCameraClippingRange()
            window.Render()
    return gl


def test_camera_move_uploads_nothing_and_builds_no_shader():
    window, renderer, _actor, _ = shown(24)
    gl = camera_moves(window, renderer)
    assert gl.calls["glTexImage3D"] == 0 and gl.calls["glTexSubImage3D"] == 0, gl.uploads_3d
    assert gl.texture_uploads == 0, dict(gl.calls)
    assert gl.shader_builds == 0 and gl.calls["glCompileShader"] == 0, dict(gl.calls)
    assert gl.calls["glReadPixels"] == 0  # frame 0 of the accumulation reads nothing back


def test_counter_sees_uploads_and_builds():
    """The counter is not blind: a new illumination re-uploads its grids (16-bit), a
    shading change rebuilds the program, a data change re-uploads the data."""
    window, _renderer, actor, volume = shown(24)
    with GLCallCounter() as gl:
        actor.set_illumination(illumination_for(volume, (10, 10, 10)))
        window.Render()
    sizes = [u[:3] for u in gl.uploads_3d]
    assert (10, 10, 10) in sizes, gl.uploads_3d
    assert (24, 24, 24) not in sizes, "the data were re-uploaded for an illumination change"
    grid_bytes = [u[4] for u in gl.uploads_3d if u[:3] == (10, 10, 10)]
    assert all(b == 10 ** 3 * 4 * 2 for b in grid_bytes), gl.uploads_3d  # RGBA, 16 bit

    with GLCallCounter() as gl:
        scene = scene_for(volume)
        scene.shading = dict(scene.shading, diffuse=0.8)
        actor.set_scene(scene)
        window.Render()
    assert gl.shader_builds >= 1

    with GLCallCounter() as gl:
        image = actor.inputs.GetInputDataObject(0, 0)
        image.GetPointData().GetScalars().Modified()
        window.Render()
    assert (24, 24, 24) in [u[:3] for u in gl.uploads_3d], gl.uploads_3d


def test_transfer_function_edit_uploads_only_the_optics():
    window, _renderer, actor, volume = shown(24)
    with GLCallCounter() as gl:
        actor.set_scene(scene_for(volume, opacity_scale=2.0))
        window.Render()
    # only the optics image (table and occupancy: OPTICS_ROW x rows x 2, RGBA float32),
    # never the data (24^3) or the grids (12^3); VTK 9.7 may upload it twice in one render
    sizes = {u[:3] for u in gl.uploads_3d}
    assert len(sizes) == 1, gl.uploads_3d
    assert sizes.pop()[0] == OPTICS_ROW, gl.uploads_3d
    assert gl.shader_builds == 0


def test_new_light_grids_are_packed_into_the_arrays_of_the_last():
    """A new illumination of the same size: packed into the image arrays VTK uploaded the
    last grids from (no new gigabyte to fault in at 512³), uploaded, and drawn as a fresh
    volume draws it."""
    window, _renderer, actor, volume = shown(24)
    before = read_window_rgb(window)
    images = (actor.inputs.direct_images[0], actor.inputs.scattered_image)
    arrays = [image.GetPointData().GetScalars() for image in images]
    edited = illumination_for(volume, (12, 12, 12))
    edited = IlluminationVolume.for_volume(volume, transmittance=edited.transmittance ** 2,
                                           scattered=edited.scattered * 0.5)
    with GLCallCounter() as gl:
        actor.set_illumination(edited)
        window.Render()
    assert [image.GetPointData().GetScalars() for image in images] == arrays
    assert sum(u[:3] == (12, 12, 12) for u in gl.uploads_3d) >= 2  # both grids uploaded
    fresh_window, _r, _a, _v = shown(24)
    _a.set_illumination(edited)
    fresh_window.Render()
    assert np.abs(read_window_rgb(window) - read_window_rgb(fresh_window)).max() == 0.0
    assert np.abs(read_window_rgb(window) - before).max() > 0.05


def test_camera_move_host_work_independent_of_size():
    small = shown(16)
    large = shown(40)
    counts = []
    for window, renderer, _, _ in (small, large):
        gl = camera_moves(window, renderer)
        counts.append(dict(gl.calls))
    assert counts[0] == counts[1]


def test_sixteen_bit_grids_and_leaps_keep_the_picture():
    """16-bit illumination textures and empty-block leaps against float32 and no leaps."""
    window, _renderer, actor, _ = shown(32, image=64)
    pictures = {}
    for sixteen, skip in ((False, False), (True, False), (True, True)):
        actor.illumination_16bit = sixteen
        actor.skip_empty = skip
        window.Render()
        pictures[sixteen, skip] = np.rint(255 * read_window_rgb(window)).astype(np.int32)
    reference = pictures[False, False]
    assert reference.max() > 50  # something is drawn
    assert np.abs(pictures[True, False] - reference).max() <= 1
    assert np.abs(pictures[True, True] - pictures[True, False]).max() <= 1


def test_leaps_are_taken():
    """A volume that is empty but for one corner: the empty blocks are marked empty."""
    from vtkillum.mappers.illuminated_volume_mapper import BlockRanges

    volume = procedural.smoke_plume((33, 33, 33))
    scalars = np.zeros_like(volume.scalars)
    scalars[:9, :9, :9] = 1.0
    volume = dataclasses.replace(volume, scalars=scalars)
    blocks = BlockRanges(volume)
    sigma = np.maximum(np.linspace(-0.1, 1.0, 4096), 0.0)  # 0 below a value of ~0.09
    occupied = blocks.occupied(sigma, 0.0, 1.0)
    assert occupied.shape == (4, 4, 4)
    # block (0..1) along each axis touch points 0..16; block 0 and block 1 (sharing point 8)
    assert occupied[:2, :2, :2].all()
    assert occupied.sum() == 8
