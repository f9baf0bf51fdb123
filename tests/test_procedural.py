"""Procedural datasets, their recommended scenes, and ``builtin:`` specs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from vtkillum.core.scene import Scene
from vtkillum.core.volume import Volume
from vtkillum.data import builtin, procedural
from vtkillum.data.procedural import (
    VALUE_RANGES,
    cornell_box,
    ct_phantom,
    default_scene,
    marschner_lobb,
    plume_series,
    smoke_plume,
)


def value_at(volume: Volume, point) -> float:
    """Sample at the grid point nearest to a world point."""
    idx = np.rint(volume.to_local(point) / volume.spacing).astype(int)
    return float(volume.scalars[tuple(idx)])


def test_imports_without_vtk():
    code = ("import sys, vtkillum.data, vtkillum.data.procedural, vtkillum.data.builtin; "
            "bad = [m for m in sys.modules if m == 'vtk' or m.startswith(('vtkmodules', "
            "'pyvista', 'paraview'))]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("make", [
    lambda: smoke_plume((16, 14, 24)),
    lambda: cornell_box(20),
    lambda: ct_phantom(20),
    lambda: marschner_lobb(12),
])
def test_volumes_are_normalised_float32(make):
    vol = make()
    assert vol.scalars.dtype == np.float32
    lo, hi = vol.value_range
    assert 0.0 <= lo and hi <= 1.0 and hi > lo
    assert np.allclose(vol.spacing, vol.spacing[0])  # isotropic
    assert np.allclose(vol.direction, np.eye(3))


def assert_close_dicts(a, b):
    """Equal nested dicts/lists, numbers to rounding (light directions are renormalised)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys()
        for key in a:
            assert_close_dicts(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_close_dicts(x, y)
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-12, abs=1e-12)
    else:
        assert a == b


# --- plume ----------------------------------------------------------------------------------------
def test_plume_geometry_and_value_ranges():
    vol = smoke_plume((32, 32, 48))
    np.testing.assert_allclose(vol.bounds, [-1, 1, -1, 1, 0, 47 * 2 / 31], atol=1e-12)
    s = vol.scalars
    assert s.max() > VALUE_RANGES["plume"]["core"][0]  # a dense core near the source
    assert np.all(s[:, :, 0] < 1e-6)  # faded out at the source plane and the top
    assert np.all(s[:, :, -1] < 1e-6)
    smoke = s[s > VALUE_RANGES["plume"]["wisps"][0]]
    assert 0.03 < smoke.size / s.size < 0.5  # a plume, not a filled box
    # Documented ranges: thin wisps, body and core all occur.
    for lo, hi in VALUE_RANGES["plume"].values():
        if hi > lo:
            assert np.any((s >= lo) & (s <= hi))


def test_plume_is_a_resolution_independent_field():
    """A finer grid samples the same function: every other point coincides."""
    coarse = smoke_plume((16, 16, 25), seed=3, time=0.4)
    fine = smoke_plume((31, 31, 49), seed=3, time=0.4)
    np.testing.assert_allclose(fine.scalars[::2, ::2, ::2], coarse.scalars, atol=2e-4)


def test_plume_seed_and_time():
    a, b = smoke_plume((16, 16, 24), seed=1), smoke_plume((16, 16, 24), seed=1)
    np.testing.assert_array_equal(a.scalars, b.scalars)
    c = smoke_plume((16, 16, 24), seed=2)
    assert np.abs(a.scalars - c.scalars).max() > 0.1


def test_plume_evolves_smoothly_and_rises():
    shape = (24, 24, 36)
    v0 = smoke_plume(shape, time=0.5).scalars
    d1 = np.abs(smoke_plume(shape, time=0.52).scalars - v0).mean()
    d2 = np.abs(smoke_plume(shape, time=0.54).scalars - v0).mean()
    assert d1 > 0
    assert 1.5 < d2 / d1 < 2.5  # changes linearly for small steps: smooth in time
    far = np.abs(smoke_plume(shape, time=1.5).scalars - v0).mean()
    assert far > 5 * d1  # and does change over a longer time
    # No flicker of the overall amount (no per-frame normalisation).
    mean1 = smoke_plume(shape, time=1.5).scalars.mean()
    assert abs(mean1 - v0.mean()) < 0.3 * v0.mean()
    # The pattern rises: the frame a little later matches this one shifted upwards
    # better than unshifted (speed 1 world unit per time unit).
    h = 2.0 / (shape[0] - 1)
    dt = 3 * h  # three voxels of rise
    v1 = smoke_plume(shape, time=0.5 + dt).scalars
    shifted = np.corrcoef(v0[:, :, 8:-8].ravel(), v1[:, :, 11:-5].ravel())[0, 1]
    unshifted = np.corrcoef(v0[:, :, 8:-8].ravel(), v1[:, :, 8:-8].ravel())[0, 1]
    assert shifted > unshifted


def test_plume_series():
    series = plume_series(steps=3, shape=(12, 12, 18), seed=4, dt=0.5)
    assert [t for t, _ in series] == [0.0, 0.5, 1.0]
    np.testing.assert_array_equal(series[2][1].scalars,
                                  smoke_plume((12, 12, 18), seed=4, time=1.0).scalars)
    with pytest.raises(ValueError, match="steps"):
        plume_series(steps=0)


# --- Cornell box ----------------------------------------------------------------------------------
def test_cornell_box_materials():
    vol = cornell_box(48)
    np.testing.assert_allclose(vol.bounds, [-1, 1] * 3)
    assert value_at(vol, (-0.99, 0.0, 0.0)) == pytest.approx(procedural.CORNELL_RED)
    assert value_at(vol, (0.99, 0.0, 0.0)) == pytest.approx(procedural.CORNELL_GREEN)
    for point in [(0, -0.99, 0), (0, 0.99, 0), (0, 0, -0.99)]:  # floor, ceiling, back
        assert value_at(vol, point) == pytest.approx(procedural.CORNELL_WHITE)
    assert value_at(vol, (-0.33, 0.0, -0.3)) == pytest.approx(procedural.CORNELL_WHITE)  # tall
    assert value_at(vol, (-0.33, 0.5, -0.3)) < 0.25  # above the tall block: fog
    assert value_at(vol, (0.35, -0.6, 0.3)) == pytest.approx(procedural.CORNELL_WHITE)  # short
    low, high = value_at(vol, (0.0, -0.8, 0.7)), value_at(vol, (0.0, 0.8, 0.7))
    assert 0.1 <= high < low <= 0.2  # thin fog, denser near the floor
    assert value_at(vol, (0.0, 0.0, 1.0)) < 0.25  # open front


# --- CT phantom -----------------------------------------------------------------------------------
def test_ct_phantom_materials():
    vol = ct_phantom(96)
    np.testing.assert_allclose(vol.bounds, [-120, 120] * 3)
    assert value_at(vol, (115, 115, 115)) == 0.0  # air
    assert value_at(vol, (35, -20, 60)) == pytest.approx(procedural.CT_TISSUE)  # brain
    assert value_at(vol, (-32, 20, 55)) == pytest.approx(procedural.CT_LESION)
    assert value_at(vol, (30, 68, 20)) == pytest.approx(procedural.CT_FLUID)  # an eye
    assert value_at(vol, (11, -5, 40)) == pytest.approx(procedural.CT_FLUID)  # a ventricle
    assert value_at(vol, (0, -22, -80)) == pytest.approx(procedural.CT_BONE)  # spine
    assert value_at(vol, (0, 10, -100)) == 0.0  # trachea
    # Going down from the top of the head: air, skin, bone, then brain.
    line = np.array([value_at(vol, (0, 0, z)) for z in np.arange(119, 80, -vol.spacing[0])])
    assert line[0] == 0.0
    first = [np.flatnonzero(np.isclose(line, v))[0] for v in (procedural.CT_SKIN,
                                                              procedural.CT_BONE,
                                                              procedural.CT_TISSUE)]
    assert first[0] < first[1] < first[2]
    # Only the documented values occur, apart from one-voxel borders.
    documented = np.array([v for lo, hi in VALUE_RANGES["ct"].values() for v in (lo, hi)])
    exact = np.isclose(vol.scalars[..., None], documented, atol=1e-6).any(-1)
    assert exact.mean() > 0.85


def test_ct_phantom_noise():
    clean, noisy = ct_phantom(24), ct_phantom(24, noise=0.05, seed=1)
    inside = (clean.scalars > 0.2) & (clean.scalars < 0.8)
    diff = (noisy.scalars - clean.scalars)[inside]
    assert 0.04 < diff.std() < 0.06
    np.testing.assert_array_equal(noisy.scalars, ct_phantom(24, noise=0.05, seed=1).scalars)


# --- Marschner-Lobb -------------------------------------------------------------------------------
def test_marschner_lobb_matches_the_formula():
    vol = marschner_lobb()
    assert vol.dims == (41, 41, 41)
    np.testing.assert_allclose(vol.spacing, 0.05)

    def rho(x, y, z, fm=6.0, a=0.25):
        r = np.hypot(x, y)
        return (1 - np.sin(np.pi * z / 2) + a * (1 + np.cos(2 * np.pi * fm * np.cos(np.pi * r / 2)))
                ) / (2 * (1 + a))

    for i, j, k in [(0, 0, 0), (20, 20, 20), (5, 33, 12), (40, 7, 29)]:
        x, y, z = -1 + 0.05 * np.array([i, j, k])
        assert vol.scalars[i, j, k] == pytest.approx(rho(x, y, z), abs=1e-6)
    assert marschner_lobb(9, fM=2, alpha=0.5).scalars[4, 4, 4] == pytest.approx(
        rho(0, 0, 0, 2, 0.5), abs=1e-6)


# --- scenes ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,vol", [
    ("plume", smoke_plume((16, 16, 24))),
    ("cornell", cornell_box(24)),
    ("ct", ct_phantom(24)),
    ("marschner-lobb", marschner_lobb(16)),
])
def test_default_scenes_are_valid_and_frame_the_data(name, vol):
    scene = default_scene(name, vol)
    assert isinstance(scene, Scene)
    assert_close_dicts(Scene.from_dict(scene.to_dict()).to_dict(), scene.to_dict())  # JSON-able
    tf = scene.transfer_function
    lo, hi = vol.value_range
    assert tf.scalars[0] <= lo and tf.scalars[-1] >= hi * 0.999
    assert tf.alpha(vol.scalars).max() > 0.2  # something is visible
    centre = vol.bounds.reshape(3, 2).mean(1)
    cam = scene.camera
    to_centre = centre - cam.position
    cosine = np.clip(cam.forward @ to_centre / np.linalg.norm(to_centre), -1.0, 1.0)
    angle = np.degrees(np.arccos(cosine))
    assert angle < cam.view_angle / 4  # looking at the data


def test_default_scene_renders_something():
    from vtkillum.core.render import render

    vol = builtin.load_builtin("builtin:ct:24")
    scene = builtin.builtin_scene("builtin:ct:24", vol)
    result = render(vol, scene, "emission", 24, 24, device="cpu")
    assert result.alpha[8:16, 8:16].mean() > 0.4  # the head is in the middle of the picture
    assert result.alpha[:3, :3].max() < 0.01  # background in the corner


def test_default_scene_unknown_name():
    with pytest.raises(ValueError, match="known: .*cornell.*plume"):
        default_scene("teapot", marschner_lobb(8))


# --- builtin specs --------------------------------------------------------------------------------
@pytest.mark.parametrize("spec,expected", [
    ("builtin:plume", ("plume", 64)),
    ("builtin:plume:128", ("plume", 128)),
    ("builtin:CT:96", ("ct", 96)),
    ("builtin:cornell", ("cornell", 64)),
    ("builtin:cornell-box:32", ("cornell", 32)),
    ("builtin:marschner-lobb", ("marschner-lobb", 41)),
    ("builtin:ml:", ("marschner-lobb", 41)),
])
def test_parse_builtin(spec, expected):
    assert builtin.parse_builtin(spec) == expected


def test_load_builtin_sizes():
    assert builtin.load_builtin("builtin:plume:16").dims == (16, 16, 24)
    assert builtin.load_builtin("builtin:ct:20").dims == (20, 20, 20)


@pytest.mark.parametrize("spec,message", [
    ("builtin:teapot", "unknown built-in dataset 'teapot'; choose one of plume, cornell, ct, "
                       "marschner-lobb"),
    ("builtin:ct:big", "SIZE must be an integer"),
    ("builtin:ct:8", r"SIZE must lie in \[16, 1024\]"),
    ("builtin:ct:64:2", "expected builtin:NAME"),
    ("builtin:", "expected builtin:NAME"),
    ("plume", "not a built-in dataset spec"),
])
def test_parse_builtin_errors(spec, message):
    with pytest.raises(ValueError, match=message):
        builtin.parse_builtin(spec)


@pytest.mark.parametrize("call", [
    lambda: smoke_plume((16, 16)),
    lambda: smoke_plume((2, 16, 16)),
    lambda: cornell_box(8),
    lambda: ct_phantom(32.5),
    lambda: ct_phantom(20, noise=-1),
    lambda: marschner_lobb(3),
])
def test_bad_sizes(call):
    with pytest.raises(ValueError):
        call()
