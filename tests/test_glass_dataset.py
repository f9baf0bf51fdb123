"""The built-in stemmed glass (``builtin:glass``) and its Fig. 8 material presets."""

import numpy as np
import pytest

from vtkillum.data.builtin import builtin_scene, load_builtin, parse_builtin
from vtkillum.data.procedural import (
    GLASS_GLASS,
    GLASS_LIQUID,
    GLASS_PRESETS,
    glass_preset,
    stemmed_glass,
)


def test_glass_volume_holds_its_materials():
    vol = stemmed_glass(48)
    assert vol.dims[:2] == (48, 48) and vol.dims[2] == pytest.approx(1.05 * 48, abs=2)
    s = vol.scalars
    assert s.min() == -1.0 and s.max() == pytest.approx(GLASS_LIQUID)
    # Liquid, air and both wall tiles are present in bulk, the thin glass wall around them.
    for value in (-1.0, -0.7, 0.0, GLASS_LIQUID):
        assert np.sum(np.abs(s - value) < 0.05) > 100
    assert np.sum(np.abs(s - GLASS_GLASS) < 0.3) > 100
    # The liquid sits above the stem, inside the bowl, below the fill line (z = 1).
    z = vol.origin[2] + vol.spacing[2] * np.arange(vol.dims[2])
    liquid_z = z[np.nonzero(np.abs(s - GLASS_LIQUID) < 0.05)[2]]
    assert 0.55 < liquid_z.min() and liquid_z.max() < 1.0
    # Resolution-independent placement: the same world box at any size (z to a voxel).
    coarse = stemmed_glass(24)
    np.testing.assert_allclose(coarse.bounds, vol.bounds, atol=coarse.spacing[2])  # z: whole voxels


def test_builtin_spec_and_default_scene():
    assert parse_builtin("builtin:glass") == ("glass", 96)
    assert parse_builtin("builtin:stemmed-glass:32") == ("glass", 32)
    vol = load_builtin("builtin:glass:24")
    scene = builtin_scene("builtin:glass:24", vol)
    assert len(scene.lights) == 1 and scene.lights[0].kind == 0


@pytest.mark.parametrize("preset", GLASS_PRESETS)
def test_presets_render(preset):
    from vtkillum.core.refraction.render import render_refraction

    vol = stemmed_glass(24)
    scene, optics = glass_preset(vol, preset)
    assert optics.eta_constant == (preset in ("no-refraction", "medium"))
    assert optics.medium_white == (preset == "no-refraction")
    result = render_refraction(vol, scene, 16, 16, "cpu", optics=optics)
    assert np.isfinite(result.radiance).all() and result.radiance.max() > 0


def test_unknown_preset():
    with pytest.raises(ValueError, match="beer"):
        glass_preset(stemmed_glass(16), "lemonade")
