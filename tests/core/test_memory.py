"""Device-memory estimates (:mod:`vtkillum.core.memory`) against warp's allocations, and the
refusal before allocating."""

import gc

import numpy as np
import pytest

from vtkillum.core import memory
from vtkillum.core.render import render
from vtkillum.core.volume import Volume
from vtkillum.data.procedural import default_scene, smoke_plume

#: The estimate must lie within this factor of the measured peak (either way).
FACTOR = 1.25


def _plume(n):
    volume = Volume(smoke_plume(shape=(n, n, n)).scalars)  # spacing 1: canonical units as given
    scene = default_scene("plume", volume)
    scene.lights = scene.lights[:1]
    return volume, scene


@pytest.mark.parametrize("method", ["transmittance", "convection-diffusion"])
@pytest.mark.parametrize("n", [24, 40])
def test_estimate_matches_measured_allocations(method, n):
    volume, scene = _plume(n)
    gc.collect()
    with memory.track_allocations("cpu") as counter:
        render(volume, scene, method, 16, 16, "cpu")
    measured = counter.high
    estimate = memory.estimate_bytes(method, volume.dims, 1, image=(16, 16), device="cpu")
    assert measured > 4 * n**3  # the scalars at least: the counter saw the render
    assert 1 / FACTOR < estimate / measured < FACTOR, (estimate, measured)


def test_estimate_grows_with_lights_scale_and_size():
    base = memory.estimate_bytes("transmittance", (64, 64, 64), 1)
    assert memory.estimate_bytes("transmittance", (64, 64, 64), 2) > base
    assert memory.estimate_bytes("transmittance", (64, 64, 64), 1, 0.5) < base
    growth = memory.estimate_bytes("transmittance", (128, 128, 128), 1) - base
    # 4 + 12 + 4 B a point, and on CUDA (the default) the scalars' and the light grid's
    # textures (4 + 4)
    assert growth == pytest.approx(28 * (128**3 - 64**3), rel=0.02)
    cpu = [memory.estimate_bytes("transmittance", (m, m, m), 1, device="cpu") for m in (64, 128)]
    assert cpu[1] - cpu[0] == pytest.approx(20 * (128**3 - 64**3), rel=0.02)


def test_refused_before_any_allocation(monkeypatch):
    volume, scene = _plume(24)
    need = memory.estimate_bytes("convection-diffusion", volume.dims, 1, image=(16, 16),
                                 device="cpu")
    monkeypatch.setattr(memory, "free_device_bytes", lambda device: need // 2)
    gc.collect()
    with memory.track_allocations("cpu") as counter, \
            pytest.raises(memory.DeviceMemoryError) as info:
        render(volume, scene, "convection-diffusion", 16, 16, "cpu")
    assert counter.high == 0  # nothing was allocated
    text = str(info.value)
    edge = memory.largest_cube("convection-diffusion", need // 2, 1, image=(16, 16),
                               device="cpu")
    assert 2 <= edge < 24
    assert f"{edge}³" in text and "light_volume_scale" in text and "OutputScale" in text
    assert "convection-diffusion" in text and "free" in text


def test_largest_cube_is_the_edge_where_the_estimate_crosses():
    free = 8 * 2**30
    for method in ("transmittance", "ambient-scattering", "photon"):
        edge = memory.largest_cube(method, free)
        fits = memory.estimate_bytes(method, (edge,) * 3)
        over = memory.estimate_bytes(method, (edge + 1,) * 3)
        assert fits <= memory.USABLE_FRACTION * free < over
    table = memory.largest_cubes(free)
    assert set(table) >= {"emission", "transmittance", "convection-diffusion", "refraction"}
    assert table["convection-diffusion"] < table["emission"]


def test_check_fits_passes_when_it_fits():
    need = memory.check_fits("emission", (32, 32, 32), free_bytes=1 << 40)
    assert need == memory.estimate_bytes("emission", (32, 32, 32))
    assert np.isfinite(need)
