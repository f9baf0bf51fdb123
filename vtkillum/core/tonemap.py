"""The tone map from linear radiance to 8-bit PNG colours.

``png = round(255 * clip(exposure * (L + (1 - alpha) * background), 0, 1) ** (1 / gamma))``
with ``gamma = 2.2`` by default (``gamma = 1`` keeps the values linear, which is how
VTK's ray caster writes its frame buffer).
"""

from __future__ import annotations

import numpy as np


def tonemap(radiance, alpha=None, background=(0.0, 0.0, 0.0), exposure: float = 1.0,
            gamma: float = 2.2) -> np.ndarray:
    """Linear radiance (H, W, 3) to uint8 RGB (H, W, 3). See the module docstring."""
    rgb = np.asarray(radiance, dtype=np.float64)
    if alpha is not None:
        rgb = rgb + (1.0 - np.asarray(alpha, dtype=np.float64))[..., None] * np.asarray(background)
    rgb = np.clip(np.nan_to_num(rgb * exposure), 0.0, 1.0) ** (1.0 / gamma)
    return np.round(rgb * 255.0).astype(np.uint8)


def auto_exposure(radiance, percentile: float = 99.5) -> float:
    """Exposure that maps the given percentile of the brightest channel to 1."""
    peak = float(np.percentile(np.asarray(radiance).max(axis=-1), percentile))
    return 1.0 / peak if peak > 0 else 1.0


def write_png(path, rgb8: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 image as PNG (Pillow)."""
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(rgb8, dtype=np.uint8), "RGB").save(path)


def read_png(path) -> np.ndarray:
    """Read a PNG as (H, W, 3) uint8 RGB (Pillow)."""
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))
