"""The tone map from linear radiance to 8-bit PNG colours.

``png = round(255 * clip(exposure * (L + (1 - alpha) * background), 0, 1) ** (1 / gamma))``
with ``gamma = 2.2`` by default (``gamma = 1`` keeps the values linear, which is how
VTK's ray caster writes its frame buffer). NaN maps to 0 and +inf to 255.

The map works in float32 on bands of :data:`CHUNK_PIXELS` pixels, so that a huge image
needs only its 8-bit result and one band of temporaries (not float64 copies of itself).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp

init_warp()

#: Pixels tone-mapped at a time (bounds the temporaries to a few MB).
CHUNK_PIXELS = 1 << 18


def tonemap(radiance, alpha=None, background=(0.0, 0.0, 0.0), exposure: float = 1.0,
            gamma: float = 2.2) -> np.ndarray:
    """Linear radiance (H, W, 3) to uint8 RGB (H, W, 3). See the module docstring."""
    rad = np.asarray(radiance)
    alp = None if alpha is None else np.asarray(alpha)
    bg = np.asarray(background, dtype=np.float32)
    out = np.empty(rad.shape, dtype=np.uint8)
    inv_gamma = np.float32(1.0 / gamma)
    for rows in _bands(rad.shape):
        rgb = np.array(rad[rows], dtype=np.float32)  # a copy: the band's workspace
        if alp is not None and bg.any():
            # Per channel: a broadcast over the last axis of length 3 is ~3x slower.
            seen = np.float32(1.0) - alp[rows].astype(np.float32)
            per_channel = np.broadcast_to(bg, rgb.shape[-1:])
            for c in range(rgb.shape[-1]):
                rgb[..., c] += seen * per_channel[c]
        with np.errstate(over="ignore", invalid="ignore"):
            rgb *= np.float32(exposure)
            # fmax drops NaN (-> 0) and -inf; minimum caps +inf: nan_to_num and clip in two passes.
            np.fmax(rgb, np.float32(0.0), out=rgb)
            np.minimum(rgb, np.float32(1.0), out=rgb)
        if gamma != 1.0:  # a display at gamma 1 (the compute mapper's default) skips the power
            np.power(rgb, inv_gamma, out=rgb)
        rgb *= np.float32(255.0)
        np.rint(rgb, out=rgb)
        out[rows] = rgb
    return out


def tonemap_device(radiance, alpha, background=(0.0, 0.0, 0.0), exposure: float = 1.0,
                   gamma: float = 2.2, flip: bool = False) -> np.ndarray:
    """:func:`tonemap` of an image on a warp device, downloading only its 8-bit result.

    ``radiance`` and ``alpha`` are warp ``array2d(vec3)`` / ``array2d(float32)``
    ``(H, W)`` (e.g. :attr:`vtkillum.core.render.RenderResult.device`); the map is the
    module's formula in float32, the same values as :func:`tonemap` (rounding half to
    even like ``np.rint``). ``flip``: rows bottom-up, as VTK images are. Returns uint8
    ``(H, W, 3)``.
    """
    h, w = int(radiance.shape[0]), int(radiance.shape[1])
    out = wp.empty((h, w, 3), dtype=wp.uint8, device=radiance.device)
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    wp.launch(tonemap_kernel, dim=(h, w),
              inputs=[radiance, alpha, wp.vec3(*bg), float(np.float32(exposure)),
                      float(np.float32(1.0 / gamma)), int(gamma != 1.0), int(bool(flip)), out],
              device=radiance.device)
    return out.numpy()


@wp.func
def _tone(v: float, exposure: float, inv_gamma: float, power: int):
    x = v * exposure
    if not (x > 0.0):  # NaN and negatives (fmax(x, 0) in tonemap)
        x = 0.0
    x = wp.min(x, 1.0)
    if power != 0:
        x = wp.pow(x, inv_gamma)
    return wp.uint8(int(wp.rint(x * 255.0)))


@wp.kernel
def tonemap_kernel(radiance: wp.array2d(dtype=wp.vec3), alpha: wp.array2d(dtype=wp.float32),
                   background: wp.vec3, exposure: float, inv_gamma: float, power: int,
                   flip: int, out: wp.array3d(dtype=wp.uint8)):
    """One pixel of :func:`tonemap_device`; ``wp.tid()`` is ``(row, col)`` of the image."""
    row, col = wp.tid()
    rgb = radiance[row, col] + (1.0 - alpha[row, col]) * background
    dst = row
    if flip != 0:
        dst = radiance.shape[0] - 1 - row
    for c in range(3):
        out[dst, col, c] = _tone(rgb[c], exposure, inv_gamma, power)


def auto_exposure(radiance, percentile: float = 99.5, alpha=None,
                  background=(0.0, 0.0, 0.0)) -> float:
    """Exposure that maps the given percentile of the brightest channel to 1.

    With ``alpha``, of the radiance composited over ``background``
    (``L + (1 - alpha) * background``), computed band by band in float32.
    """
    rad = np.asarray(radiance)
    bg = np.asarray(background, dtype=np.float32)
    peak_channel = np.empty(rad.shape[:-1], dtype=np.float32)
    for rows in _bands(rad.shape):
        rgb = rad[rows].astype(np.float32)
        if alpha is not None:
            rgb = rgb + (np.float32(1.0) - np.asarray(alpha)[rows].astype(np.float32))[
                ..., None] * bg
        peak_channel[rows] = rgb.max(axis=-1)
    finite = np.isfinite(peak_channel)
    values = peak_channel if finite.all() else peak_channel[finite]  # NaN/inf: not a level
    if values.size == 0:
        return 1.0
    peak = float(np.percentile(values, percentile))
    return 1.0 / peak if peak > 0 else 1.0


def _bands(shape):
    """Slices of whole rows (first axis) holding about :data:`CHUNK_PIXELS` pixels each."""
    if len(shape) < 2:
        yield slice(None)
        return
    per_row = max(1, int(np.prod(shape[1:-1])))
    rows = max(1, CHUNK_PIXELS // per_row)
    for r0 in range(0, shape[0], rows):
        yield slice(r0, r0 + rows)


def write_png(path, rgb8: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 image as PNG (Pillow); ``path`` may be a binary file object."""
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(rgb8, dtype=np.uint8), "RGB").save(path, format="PNG")


def read_png(path) -> np.ndarray:
    """Read a PNG as (H, W, 3) uint8 RGB (Pillow)."""
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))
