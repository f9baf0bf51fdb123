"""Optional hardware texture filtering of the ambient-scattering grids (CUDA only)."""

import numpy as np
import pytest

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.ambient.render import parse_options
from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render
from vtkillum.core.scene import METHOD_OPTIONS, Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

#: Hardware filtering uses 8-bit interpolation weights: mean difference from the exact
#: software path, relative to the maximum (and the largest single difference).
MEAN_TOL = 2e-3
MAX_TOL = 3e-2


def blobby(n=(34, 30, 28)):
    """Two overlapping soft blobs with a ripple, non-cubic and anisotropically spaced."""
    x, y, z = (np.linspace(-1, 1, k) for k in n)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    s = (np.exp(-((X - 0.3) ** 2 + Y**2 + Z**2) / 0.15)
         + 0.7 * np.exp(-((X + 0.35) ** 2 + (Y - 0.2) ** 2 + (Z + 0.1) ** 2) / 0.08)
         + 0.1 * np.sin(7 * X) * np.cos(5 * Y))
    vol = Volume(np.clip(s, 0, 1).astype(np.float32), spacing=(0.5, 0.6, 0.7))
    tf = TransferFunction([0.0, 0.2, 0.6, 1.0], [0.0, 0.1, 0.5, 0.8],
                          [[1, 1, 1], [1, 0.7, 0.5], [0.6, 0.8, 1], [1, 1, 1]])
    lights = [DirectionalLight((1, -0.5, -1), (1.0, 0.9, 0.8)),
              PointLight(vol.extent * np.array([0.8, 0.2, 0.5]), (30.0, 40.0, 50.0))]
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, albedo=0.9, anisotropy=0.4,
                  lights=lights,
                  camera=Camera.looking_at_bounds(vol.bounds, direction=(-0.3, -0.2, -1.0)))
    return vol, tf, scene


def test_off_by_default():
    vol, _, scene = blobby((8, 8, 8))
    assert METHOD_OPTIONS["ambient_scattering"]["hardware_filtering"] is False
    assert parse_options({}, vol, scene)["hardware_filtering"] is False
    assert AmbientScatteringCache("cpu").hardware_filtering is False
    with pytest.raises(ValueError, match="hardware_filtering must be true or false"):
        parse_options({"hardware_filtering": 1}, vol, scene)
    with pytest.raises(ValueError, match="hardware_filtering must be true or false"):
        AmbientScatteringCache("cpu", hardware_filtering="yes")


def test_cpu_falls_back_to_the_exact_path():
    vol, tf, scene = blobby((12, 10, 9))
    cache = AmbientScatteringCache("cpu", hardware_filtering=True)
    assert cache.hardware_filtering is False  # no texture units on the CPU
    st = cache.update(vol, tf, 1.0, 0.9, 0.4, scene.lights, 2.0)
    assert st.textures is None and st.radiance.texture is None
    res = render(vol, scene, "ambient-scattering", 12, 10, device="cpu", jitter=False,
                 hardware_filtering=True)
    assert res.info["hardware_filtering"] is False


def test_hardware_filtering_matches_software(device):
    if device == "cpu":
        pytest.skip("hardware texture filtering needs a CUDA device")
    vol, tf, scene = blobby()
    soft = AmbientScatteringCache(device, data_textures=False)
    hard = AmbientScatteringCache(device, hardware_filtering=True)
    assert hard.hardware_filtering
    a = soft.update(vol, tf, 1.0, 0.9, 0.4, scene.lights, 2.0)
    b = hard.update(vol, tf, 1.0, 0.9, 0.4, scene.lights, 2.0)
    assert a.textures is None and b.textures is not None
    ca, cb = a.radiance.numpy(), b.radiance.numpy()
    assert ca.shape == cb.shape and ca.shape[0] == 2
    for light in range(2):  # each light's slab of the stacked texture on its own
        scale = ca[light].max()
        assert scale > 0
        diff = np.abs(ca[light] - cb[light]) / scale
        assert diff.mean() < MEAN_TOL and diff.max() < MAX_TOL
        assert diff.max() > 0  # the textures really were sampled

    # a light edit rewrites the textures in place (no reallocation)
    moved = [scene.lights[0], PointLight(vol.extent * 0.5, (30.0, 40.0, 50.0))]
    radiance_texture = b.textures.radiance
    b2 = hard.update(vol, tf, 1.0, 0.9, 0.4, moved, 2.0)
    assert b2.recomputed == ["radiance"] and b2.textures.radiance is radiance_texture
    a2 = soft.update(vol, tf, 1.0, 0.9, 0.4, moved, 2.0)
    diff = np.abs(a2.radiance.numpy() - b2.radiance.numpy()) / a2.radiance.numpy().max()
    assert diff.mean() < MEAN_TOL

    # images: the delay line (radius a whole number of steps) and the x_o look-up
    for step in (None, 0.37):
        opts = {"jitter": False, "radius": 2.0}
        if step is not None:
            opts["step_size"] = step
        ra = render(vol, scene, "ambient-scattering", 40, 32, device=device, cache=soft, **opts)
        rb = render(vol, scene, "ambient-scattering", 40, 32, device=device, cache=hard, **opts)
        assert rb.info["hardware_filtering"] and not ra.info["hardware_filtering"]
        assert rb.info["data_textures"] and not ra.info["data_textures"]
        scale = ra.radiance.max()
        assert scale > 0
        diff = np.abs(ra.radiance - rb.radiance) / scale
        assert diff.mean() < MEAN_TOL and diff.max() < MAX_TOL
        assert np.abs(ra.alpha - rb.alpha).mean() < MEAN_TOL


def test_data_textures_are_the_cuda_default_and_match_software(device):
    """On CUDA the gather reads the scalars, σ̃t and the transfer function through textures by
    default, the radiance cache and the table from their arrays: images within the texture
    tolerance of the exact path, and a g or light edit copies nothing into a texture."""
    cuda = device != "cpu"
    assert METHOD_OPTIONS["ambient_scattering"]["data_textures"] is True
    assert AmbientScatteringCache(device).data_textures is cuda
    assert AmbientScatteringCache(device, data_textures=False).data_textures is False
    with pytest.raises(ValueError, match="data_textures"):
        AmbientScatteringCache(device, data_textures="yes")
    vol, tf, scene = blobby()
    with pytest.raises(ValueError, match="ambient_scattering.data_textures must be true or false"):
        parse_options({"data_textures": 1}, vol, scene)
    if not cuda:
        res = render(vol, scene, "ambient-scattering", 12, 10, device="cpu", jitter=False)
        assert res.info["data_textures"] is False
        return
    fast = AmbientScatteringCache(device)
    exact = AmbientScatteringCache(device, data_textures=False)
    st = fast.update(vol, tf, 1.0, 0.9, 0.4, scene.lights, 2.0)
    assert st.textures is not None and st.textures.radiance is None
    scalars = st.textures.scalars
    st = fast.update(vol, tf, 1.0, 0.9, 0.5, scene.lights, 2.0)  # a g edit
    assert st.recomputed == ["radiance"] and st.textures.scalars is scalars
    assert st.radiance.texture is None  # the cache stays an array
    for opts in ({"radius": 2.0}, {"radius": 2.0, "step_size": 0.37}):
        a = render(vol, scene, "ambient-scattering", 40, 32, device=device, jitter=False,
                   cache=exact, **opts)
        b = render(vol, scene, "ambient-scattering", 40, 32, device=device, jitter=False,
                   cache=fast, **opts)
        assert b.info["data_textures"] and not b.info["hardware_filtering"]
        assert not a.info["data_textures"]
        scale = a.radiance.max()
        diff = np.abs(a.radiance - b.radiance) / scale
        assert 0 < diff.max() < MAX_TOL and diff.mean() < MEAN_TOL
        assert np.abs(a.alpha - b.alpha).mean() < MEAN_TOL
    # the render option turns them off
    off = render(vol, scene, "ambient-scattering", 40, 32, device=device, jitter=False,
                 radius=2.0, data_textures=False)
    assert not off.info["data_textures"]


def test_step_field_texture_is_the_cuda_default_and_matches_software(device):
    """The tube march samples the step field through a texture by default on CUDA (it is a box
    average over 2r, smooth at its grid's scale): the radiance cache stays within 1e-3 of its
    maximum on average of the exact software sampling."""
    cuda = device != "cpu"
    assert AmbientScatteringCache(device).field_texture is cuda
    assert AmbientScatteringCache(device, field_texture=True).field_texture is cuda
    with pytest.raises(ValueError, match="field_texture"):
        AmbientScatteringCache(device, field_texture="yes")
    if not cuda:
        return
    vol, tf, scene = blobby()
    exact = AmbientScatteringCache(device, field_texture=False)
    fast = AmbientScatteringCache(device)
    for radius in (2.0, 3.3):
        a = exact.update(vol, tf, 1.0, 0.9, 0.4, scene.lights, radius).radiance.numpy()
        b = fast.update(vol, tf, 1.0, 0.9, 0.4, scene.lights, radius).radiance.numpy()
        assert fast._step_field_texture is not None and exact._step_field_texture is None
        for light in range(2):
            scale = a[light].max()
            diff = np.abs(a[light] - b[light]) / scale
            assert 0 < diff.max() < 1e-2 and diff.mean() < 1e-3
