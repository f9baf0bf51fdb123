"""Environment mapping (paper section 4.4): the background seen along the bent view rays.

After the sweep every view ray has a final direction; the background radiance
comes from an equirectangular (equiangular) environment map looked up along it, so
that refracting structures visibly distort what lies behind them. Neighbouring
rays that refracted differently can point in very different directions, so the map
is mip-mapped and the level is picked from the spread of the neighbouring final
directions (the angle to the right and lower neighbours, in map texels), then
sampled trilinearly. Without a map the background is the scene's uniform colour.

Map convention: an ``(H, W, 3)`` array of linear RGB; row 0 looks straight up
(world ``+y``), row ``H - 1`` straight down; column ``W/2`` looks along world
``-z``, longitude increasing towards ``+x`` (the usual equirectangular layout of
HDR panoramas with ``+y`` up). :func:`load_environment` reads ``.npy`` files and
8-bit images (through Pillow, imported only then, decoded with the sRGB curve).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device


@wp.struct
class Environment:
    """A mip-mapped equirectangular map: level ``l`` is ``heights[l] x widths[l]`` texels
    stored row-major from ``offsets[l]`` in ``texels``. ``levels == 0``: no map."""

    texels: wp.array(dtype=wp.vec3)
    offsets: wp.array(dtype=wp.int32)
    widths: wp.array(dtype=wp.int32)
    heights: wp.array(dtype=wp.int32)
    levels: int


def make_environment(image, device: str | None = None) -> Environment:
    """Upload an environment map (``None``: an empty placeholder) with its mip pyramid.

    Parameters
    ----------
    image : ndarray (H, W, 3), str, Path or None
        Linear RGB (non-negative, finite), or a file for :func:`load_environment`.
    """
    device = resolve_device(device)
    env = Environment()
    if image is None:
        env.texels = wp.zeros(1, dtype=wp.vec3, device=device)
        for name in ("offsets", "widths", "heights"):
            setattr(env, name, wp.zeros(1, dtype=wp.int32, device=device))
        env.levels = 0
        return env
    if isinstance(image, (str, Path)):
        image = load_environment(image)
    levels = mip_pyramid(check_environment(image))
    sizes = [lvl.shape[0] * lvl.shape[1] for lvl in levels]
    env.texels = wp.array(np.concatenate([lvl.reshape(-1, 3) for lvl in levels]), dtype=wp.vec3,
                          device=device)
    env.offsets = wp.array(np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32),
                           dtype=wp.int32, device=device)
    env.widths = wp.array(np.array([lvl.shape[1] for lvl in levels], np.int32), dtype=wp.int32,
                          device=device)
    env.heights = wp.array(np.array([lvl.shape[0] for lvl in levels], np.int32), dtype=wp.int32,
                           device=device)
    env.levels = len(levels)
    return env


def sample_environment(image, directions, spread=0.0, device: str | None = None) -> np.ndarray:
    """Look a map up along world ``directions`` (n, 3) with a filter ``spread`` (radians, scalar
    or per direction), as the renderer does; for tests and tools. Returns (n, 3) RGB."""
    device = resolve_device(device)
    env = make_environment(image, device)
    d = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    spread = np.broadcast_to(np.asarray(spread, dtype=np.float32), (len(d),))
    out = wp.zeros(len(d), dtype=wp.vec3, device=device)
    wp.launch(sample_kernel, dim=len(d), inputs=[env, wp.array(d.astype(np.float32), dtype=wp.vec3,
                                                                device=device),
                                                  wp.array(np.ascontiguousarray(spread),
                                                           dtype=wp.float32, device=device), out],
              device=device)
    return out.numpy()


def check_environment(image) -> np.ndarray:
    """Validate an environment image: ``(H, W, 3)`` (or RGBA, alpha dropped), finite, >= 0."""
    a = np.asarray(image, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or min(a.shape[:2]) < 1:
        raise ValueError(f"environment: expected an (H, W, 3) RGB image, got shape {a.shape}")
    a = a[..., :3]
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError("environment: values must be finite and non-negative (linear RGB)")
    return np.ascontiguousarray(a)


def mip_pyramid(image: np.ndarray) -> list[np.ndarray]:
    """Levels from full size down to one row: 2x2 box averages (odd sizes drop a last
    row/column into the previous texel's average)."""
    levels = [np.asarray(image, dtype=np.float32)]
    while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
        a = levels[-1]
        h, w = a.shape[:2]
        if h > 1:
            a = _halve(a, 0)
        if w > 1:
            a = _halve(a, 1)
        levels.append(a.astype(np.float32))
    return levels


def _halve(a: np.ndarray, axis: int) -> np.ndarray:
    n = a.shape[axis]
    even = np.take(a, range(n - n % 2), axis=axis)
    shape = list(even.shape)
    shape[axis] //= 2
    shape.insert(axis + 1, 2)
    out = even.reshape(shape).mean(axis=axis + 1)
    if n % 2:  # the last odd row/column joins the last pair
        last = np.take(a, [n - 1], axis=axis)
        tail = np.take(out, [out.shape[axis] - 1], axis=axis)
        merged = (2 * tail + last) / 3
        out = np.concatenate([np.take(out, range(out.shape[axis] - 1), axis=axis), merged],
                             axis=axis)
    return out


def load_environment(path) -> np.ndarray:
    """Read an environment map: ``.npy`` (linear RGB) or an 8-bit image (sRGB decoded)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"environment map {path} does not exist")
    if path.suffix.lower() == ".npy":
        return check_environment(np.load(path))
    try:
        from PIL import Image
    except ImportError as err:  # pragma: no cover - Pillow is a dependency of the project
        raise ValueError(f"reading {path.name} needs Pillow; save the map as .npy instead") from err
    with Image.open(path) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    return check_environment(linear)


def checker_environment(height: int = 256, squares: int = 16, sky=(0.55, 0.7, 0.95),
                        ground=(0.35, 0.3, 0.25), contrast: float = 0.5) -> np.ndarray:
    """A procedural environment: a sky gradient above, a checkered ground below (linear RGB).

    The checkers make refraction visible (straight lines bend behind lenses).
    """
    h = int(height)
    w = 2 * h
    theta = (np.arange(h) + 0.5) / h * np.pi  # polar angle from +y
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    up = np.cos(theta)[:, None, None]
    sky_rgb = np.asarray(sky, np.float32) * (0.6 + 0.4 * np.clip(up, 0, 1))
    check = ((np.floor(theta / np.pi * squares)[:, None] + np.floor(phi / (2 * np.pi) * 2 * squares)
              [None, :]) % 2)[..., None]
    ground_rgb = np.asarray(ground, np.float32) * (1 - contrast + 2 * contrast * check)
    img = np.where(up > 0, sky_rgb, ground_rgb)
    return np.broadcast_to(img, (h, w, 3)).astype(np.float32).copy()


# --- device functions ---------------------------------------------------------------------------
@wp.func
def _texel(env: Environment, level: int, x: int, y: int):
    w = env.widths[level]
    h = env.heights[level]
    xi = x % w
    if xi < 0:
        xi += w
    yi = wp.clamp(y, 0, h - 1)
    return env.texels[env.offsets[level] + yi * w + xi]


@wp.func
def _bilinear(env: Environment, level: int, u: float, v: float):
    """Bilinear sample at map coordinates ``u, v`` in [0, 1] (longitude wraps)."""
    x = u * float(env.widths[level]) - 0.5
    y = v * float(env.heights[level]) - 0.5
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    i = int(x0)
    j = int(y0)
    top = wp.lerp(_texel(env, level, i, j), _texel(env, level, i + 1, j), fx)
    bottom = wp.lerp(_texel(env, level, i, j + 1), _texel(env, level, i + 1, j + 1), fx)
    return wp.lerp(top, bottom, fy)


@wp.func
def environment_lookup(env: Environment, d: wp.vec3, spread: float):
    """Radiance of the map in world direction ``d`` (unit), filtered over ``spread`` radians
    (the angle between neighbouring rays): level ``log2(spread W / 2π)``, trilinear."""
    u = wp.atan2(d[0], -d[2]) / (2.0 * wp.pi) + 0.5
    v = wp.acos(wp.clamp(d[1], -1.0, 1.0)) / wp.pi
    texels = spread * float(env.widths[0]) / (2.0 * wp.pi)
    level = wp.clamp(wp.log2(wp.max(texels, 1.0e-6)), 0.0, float(env.levels - 1))
    l0 = int(level)
    l1 = wp.min(l0 + 1, env.levels - 1)
    return wp.lerp(_bilinear(env, l0, u, v), _bilinear(env, l1, u, v), level - float(l0))


@wp.kernel
def sample_kernel(env: Environment, dirs: wp.array(dtype=wp.vec3), spread: wp.array(dtype=float),
                  out: wp.array(dtype=wp.vec3)):
    """``out[i]``: the map along unit world direction ``dirs[i]`` filtered over ``spread[i]``
    radians; ``wp.tid()`` indexes the directions."""
    i = wp.tid()
    out[i] = environment_lookup(env, dirs[i], spread[i])
