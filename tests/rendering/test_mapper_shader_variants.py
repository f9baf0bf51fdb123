"""Issue 13: the IlluminatedVolume shader compiles the gradient only where shading needs it.

Without diffuse and specular terms (``kd = ks = 0``, the default) the shader is built
with ``IL_PHONG 0``; a scene that needs them rebuilds it with ``IL_PHONG 1``. Both
variants must match the warp ray caster within the tolerance of ``test_mappers.py``,
and switching between them on a shown volume must give what a fresh volume gives.
"""

import copy

import pytest
from helpers import read_window_rgb, rel_errors
from test_mappers import (
    make_scene,
    render_opengl,
    setup,  # noqa: F401  (the fixture)
    warp_reference,
    within,
)

from vtkillum.io.convert import image_data_from_volume

pytest.importorskip("vtkmodules.vtkRenderingVolumeOpenGL2")


def ambient_only(scene):
    scene = copy.deepcopy(scene)
    scene.shading = {"ambient": 1.0, "diffuse": 0.0, "specular": 0.0, "shininess": 32.0}
    return scene


def test_ambient_only_variant_matches_warp(setup):  # noqa: F811
    volume, scene, illumination, _, _ = setup
    flat = ambient_only(scene)
    reference = warp_reference(volume, flat, illumination)
    exposure = 0.8 / float(reference.radiance.max())
    reference.radiance[:] *= exposure
    image, actor, window = render_opengl(image_data_from_volume(volume), flat, illumination,
                                         exposure)
    assert actor._phong is False
    errors = rel_errors(image, reference.radiance)
    print(f"ambient only, OpenGL vs warp: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors
    window.Finalize()


def test_switching_shading_rebuilds_the_shader(setup):  # noqa: F811
    volume, scene, illumination, reference, exposure = setup
    image = image_data_from_volume(volume)
    flat = ambient_only(scene)
    fresh_flat, *_ = render_opengl(image, flat, illumination, exposure)
    shown, actor, window = render_opengl(image, scene, illumination, exposure)
    assert actor._phong is True
    assert within(rel_errors(shown, reference.radiance))
    actor.set_scene(flat)
    assert actor._phong is False
    assert (read_window_rgb(window) == fresh_flat).all()
    actor.set_scene(make_scene(volume))
    assert actor._phong is True
    assert within(rel_errors(read_window_rgb(window), reference.radiance))
    window.Finalize()
