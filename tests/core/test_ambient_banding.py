"""No rings or bands on sharp surfaces (issue 8, item 5).

The scene is the mechanism behind the bands of ``builtin:ct:96``: a sphere whose shell
(0.12 thick, under two voxels of a 32³ grid, optical depth about 3.6 across) is thinner
than the ambient radius, lit obliquely, seen close up (64², about 5 pixels per voxel) so
that rings at the voxel scale are resolved. Its data are trilinearly interpolated, so the
shell's surface is terraced at the voxel scale and the path tracer shows faint stripes
too; what matters is the structure the ambient image has *beyond* the reference's.

Measure (:func:`band_energy`): both images are normalised to their mean over the
covered pixels and lightly smoothed (Gaussian, 1 pixel: pixel noise out, voxel-scale
structure kept); their difference is high-passed (minus a 4-pixel Gaussian blur) and its
RMS taken over the covered pixels. Measured against the stored 1024-sample reference:
another path image (256 samples) 0.015, the ``single`` method 0.038, the centred gather
(default) 0.023-0.028 for r = 2-6 voxels and any jitter seed, the paper's Algorithm 1
0.086 (r = 2), 0.13 (r = 4), 0.19 (r = 6): there the transmittance starts at
``x_o = x' + r ω``, so the first ``r`` of matter along each ray is not attenuated and the
pixel follows the shell's terraced optical depth instead of saturating.

The reference is ``tests/core/references/ambient-banding-shell-path.npz``
(1024 samples, seed 11, about 2.5 minutes on one CPU core); regenerate it with
``python tests/core/test_ambient_banding.py``.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import binary_erosion, gaussian_filter

from vtkillum.core.ambient.cache import AmbientScatteringCache
from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

REFERENCE = Path(__file__).resolve().parent / "references" / "ambient-banding-shell-path.npz"
SIZE = 64
BAND_TOL = 0.04


def shell_scene(n=32, thick=0.12, sigma=30.0):
    """A dense spherical shell (value 1, ``σt = sigma``) around a thin core (value 0.5)."""
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    R = np.sqrt(X**2 + Y**2 + Z**2)
    h = 2 / (n - 1)
    outer = np.clip((0.8 - R) / h + 0.5, 0, 1)
    inner = np.clip((0.8 - thick - R) / h + 0.5, 0, 1)
    vol = Volume((outer - 0.5 * inner).astype(np.float32), spacing=(h,) * 3, origin=(-1, -1, -1))
    u = 0.1
    tf = TransferFunction([0, 0.5, 0.7, 1.0], [0, 1 - np.exp(-0.5 * u), 1 - np.exp(-0.5 * u),
                                               1 - np.exp(-sigma * u)])
    cam = Camera(position=(-0.9, 0.9, 2.6), focal_point=(-0.35, 0.35, 0.45), view_up=(0, 1, 0),
                 view_angle=22)
    return vol, Scene(transfer_function=tf, opacity_unit_distance=u, albedo=0.9, anisotropy=0.0,
                      lights=[DirectionalLight((1, -0.5, -0.6))], camera=cam)


def band_energy(img, ref, mask, fine=1.0, coarse=4.0):
    """RMS of the voxel-scale structure of ``img`` that ``ref`` lacks (see the module docstring)."""
    a = gaussian_filter(img.mean(-1), fine)
    b = gaussian_filter(ref.mean(-1), fine)
    d = a / a[mask].mean() - b / b[mask].mean()
    d = d - gaussian_filter(d, coarse)
    return float(np.sqrt((d[mask] ** 2).mean()))


@pytest.fixture(scope="module")
def reference():
    if not REFERENCE.exists():
        pytest.fail(f"{REFERENCE} is missing: python tests/core/test_ambient_banding.py")
    with np.load(REFERENCE) as data:
        return data["radiance"].astype(np.float64)


@pytest.fixture(scope="module")
def covered():
    vol, scene = shell_scene()
    alpha = render(vol, scene, "emission", SIZE, SIZE, device="cpu").alpha
    return binary_erosion(alpha > 0.95, iterations=4)


@pytest.mark.parametrize("radius", [2.0, 4.0, 6.0])
def test_no_bands_beyond_the_path_tracers(reference, covered, radius):
    vol, scene = shell_scene()
    out = {}
    for gather in ("centred", "paper"):
        img = render(vol, scene, "ambient-scattering", SIZE, SIZE, device="cpu", radius=radius,
                     gather=gather, cache=AmbientScatteringCache("cpu")).radiance
        out[gather] = band_energy(img, reference, covered)
    print(f"r = {radius}: band energy centred {out['centred']:.4f}, paper {out['paper']:.4f}")
    assert covered.sum() > 500
    assert out["centred"] < BAND_TOL
    assert out["paper"] > 2 * BAND_TOL  # the bands of Algorithm 1, which this test catches


def make_reference(path=REFERENCE, spp=1024, seed=11):
    """Path-trace the reference (float16 radiance and alpha) into ``path``."""
    vol, scene = shell_scene()
    res = render(vol, scene, "path", SIZE, SIZE, device="cpu", spp=spp, max_bounces=1000,
                 seed=seed)
    np.savez_compressed(path, radiance=res.radiance.astype(np.float16),
                        alpha=res.alpha.astype(np.float16), spp=np.int64(spp),
                        seed=np.int64(seed))
    return path


if __name__ == "__main__":
    print("wrote", make_reference())
