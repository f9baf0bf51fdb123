"""The host work of a render with a moved camera does not grow with the volume (issue 35).

Renders the same Volume twice, the second time from another camera, on the CPU device,
and watches the second render:

* every warp array made from a numpy array (an upload) and every ``array.numpy()`` (a
  download) of at least a quarter of the volume's voxel count is recorded, by wrapping
  warp's own array constructor and ``numpy`` method -- whatever module does it;
* numpy allocations are traced (``tracemalloc``): a host-side pass over a light grid or
  the data (``np.isfinite``, ``np.maximum``, ``astype``, a stack ...) allocates an array
  of the grid's size.

A moved camera must move no volume-sized data and allocate no volume-sized host arrays,
at two volume sizes (so the bound is not an accident of one size).
"""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest
import warp as wp

from vtkillum.core.camera import Camera
from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

IMAGE = 12

#: Method -> options for a small, quick render (camera-independent state is cached).
METHODS = {
    "emission": {},
    "single": {},
    "photon": {},
    "transmittance": {},
    "convection-diffusion": {},
    "ambient-scattering": {},
    "illumination": None,  # filled in per test: an IlluminationVolume from numpy
}


def _volume(n: int) -> Volume:
    x = np.linspace(-1.0, 1.0, n, dtype=np.float32)
    r = np.sqrt(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2)
    return Volume(np.clip(1.2 - r, 0.0, 1.0).astype(np.float32), spacing=(1.0, 1.0, 1.0))


def _scene(volume: Volume, azimuth: float) -> Scene:
    c = volume.extent / 2.0
    d = 3.0 * float(volume.extent.max())
    pos = c + d * np.array([np.cos(azimuth), 0.3, np.sin(azimuth)])
    tf = TransferFunction([0.0, 0.2, 1.0], [0.0, 0.3, 0.8],
                          [[1, 1, 1], [1, 0.8, 0.6], [1, 1, 1]])
    return Scene(transfer_function=tf,
                 lights=[DirectionalLight((0.3, -1.0, 0.2)),
                         PointLight(tuple(c + np.array([0.0, 0.0, 0.3 * d])), (40.0,) * 3)],
                 camera=Camera(position=tuple(pos), focal_point=tuple(c), view_up=(0, 1, 0),
                               view_angle=30.0))


class Watch:
    """Uploads, downloads and numpy allocations of at least ``threshold`` elements."""

    def __init__(self, monkeypatch, threshold: int):
        self.threshold = threshold
        self.events: list[str] = []
        self.active = False
        array_cls = wp.array
        init, to_numpy = array_cls.__init__, array_cls.numpy
        watch = self

        def counted_init(self, data=None, *args, **kwargs):
            if watch.active and isinstance(data, np.ndarray) and data.size >= watch.threshold:
                watch.events.append(f"upload {data.shape} {data.dtype}")
            init(self, data, *args, **kwargs)

        def counted_numpy(self):
            out = to_numpy(self)
            if watch.active and out.size >= watch.threshold:
                watch.events.append(f"download {out.shape} {out.dtype}")
            return out

        monkeypatch.setattr(array_cls, "__init__", counted_init)
        monkeypatch.setattr(array_cls, "numpy", counted_numpy)

    def run(self, fn):
        """``fn()`` watched; returns the peak of traced host allocations (bytes)."""
        self.events.clear()
        tracemalloc.start()
        self.active = True
        try:
            fn()
        finally:
            self.active = False
            _current, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
        return peak


@pytest.mark.parametrize("n", [48, 64])
@pytest.mark.parametrize("method", sorted(METHODS))
def test_camera_move_moves_no_volume(monkeypatch, method, n):
    volume = _volume(n)
    scene0, scene1 = _scene(volume, 0.3), _scene(volume, 1.4)
    options = dict(METHODS[method] or {})
    if method == "illumination":
        # What the compute mapper holds: one IlluminationVolume made from numpy arrays.
        grid = np.full((n, n, n, 3), 0.05, np.float32)
        t = np.full((2, n, n, n), 0.5, np.float32)
        options["illumination"] = IlluminationVolume.for_volume(volume, grid, t)
    render(volume, scene0, method, IMAGE, IMAGE, "cpu", **options)  # first image: may upload
    # The smallest grid a method keeps is the light grid at light_volume_scale 0.5: n³/8.
    grid = n ** 3 // 8
    watch = Watch(monkeypatch, threshold=grid // 2)
    peak = watch.run(lambda: render(volume, scene1, method, IMAGE, IMAGE, "cpu", **options))
    assert watch.events == [], f"{method} at {n}³: a camera move moved {watch.events}"
    # Image-sized and bookkeeping allocations only: below one float32 copy of that grid.
    assert peak < grid * 4, (
        f"{method} at {n}³: the camera move allocated {peak} bytes of host memory "
        f"(one float32 light grid is {grid * 4})")


def test_transfer_function_edit_keeps_the_data_on_the_device(monkeypatch):
    """A TF edit recomputes the light volume but uploads no data and downloads nothing
    volume-sized (the light grid is made, checked and read on the device)."""
    n = 64  # n³/16 elements: more than a transfer-function table (4096 x 3)
    volume = _volume(n)
    scene = _scene(volume, 0.3)
    render(volume, scene, "transmittance", IMAGE, IMAGE, "cpu")
    tf = scene.transfer_function
    edited = dataclasses.replace(scene, transfer_function=TransferFunction(
        tf.scalars, np.minimum(tf.opacity * 1.5, 0.95), tf.colors))
    watch = Watch(monkeypatch, threshold=n ** 3 // 16)
    watch.run(lambda: render(volume, edited, "transmittance", IMAGE, IMAGE, "cpu"))
    assert watch.events == []


def test_many_lights_camera_move_does_not_grow_with_the_volume(monkeypatch):
    """The progressive many-lights renderer (what the compute mapper keeps across camera
    moves) re-gathers its kept virtual lights: its transfers and host allocations per
    camera move are the same at 48³ and 64³ (they belong to the light sets, not the data)."""
    from vtkillum.core.many_lights.render import ManyLightsRenderer

    seen = {}
    for n in (48, 64):
        volume = _volume(n)
        scene0, scene1 = _scene(volume, 0.3), _scene(volume, 1.4)
        renderer = ManyLightsRenderer(volume, scene0, IMAGE, IMAGE, device="cpu", sets=2)
        renderer.run(1)
        watch = Watch(monkeypatch, threshold=48 ** 3 // 16)
        peak = watch.run(lambda: (renderer.reset(scene1.resolved_camera(volume)),
                                  renderer.run(1), renderer.result()))
        monkeypatch.undo()
        seen[n] = (len(watch.events), peak)
    (events48, peak48), (events64, peak64) = seen[48], seen[64]
    assert events64 == events48
    assert peak64 < 1.2 * peak48 + 16384, seen
