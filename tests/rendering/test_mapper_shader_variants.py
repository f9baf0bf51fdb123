"""Issues 13 and 35: the IlluminatedVolume shader compiles only the terms the picture needs.

Without diffuse and specular terms (``kd = ks = 0``, the default) the shader is built
with ``IL_PHONG 0``; a scene that needs them rebuilds it with ``IL_PHONG 1``. An
illumination without transmittance (a scattered fluence only: photon density, many-lights
fluence) is built with ``IL_DIRECT 0``, one without a scattered fluence with
``IL_SCATTERED 0`` (``inputs.variant`` is ``(phong, direct, scattered)``). Every variant
must match the warp ray caster within the tolerance of ``test_mappers.py``, and switching
between them on a shown volume must give what a fresh volume gives.
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

from vtkillum.core.illumination import IlluminationVolume
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
    assert actor.inputs.variant == (False, True, True)
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
    assert actor.inputs.variant == (True, True, True)
    assert within(rel_errors(shown, reference.radiance))
    actor.set_scene(flat)
    assert actor.inputs.variant == (False, True, True)
    assert (read_window_rgb(window) == fresh_flat).all()
    actor.set_scene(make_scene(volume))
    assert actor.inputs.variant[0] is True
    assert within(rel_errors(read_window_rgb(window), reference.radiance))
    window.Finalize()


def test_scattered_only_variant_matches_warp_and_switches(setup):  # noqa: F811
    """A scattered fluence alone (no transmittance: no direct light) compiles without the
    direct light, matches warp, and a shown volume switched to it and back gives what
    fresh volumes give."""
    volume, scene, illumination, reference, exposure = setup
    scattered = IlluminationVolume.for_volume(volume, illumination.scattered)
    assert scattered.transmittance is None
    ref_scattered = warp_reference(volume, scene, scattered)
    scale = 0.8 / float(ref_scattered.radiance.max())
    image = image_data_from_volume(volume)
    fresh, actor, window = render_opengl(image, scene, scattered, scale)
    assert actor.inputs.variant == (True, False, True)
    errors = rel_errors(fresh, scale * ref_scattered.radiance)
    print(f"scattered only, OpenGL vs warp: mean {errors[0]:.2e}, p99 {errors[1]:.2e}")
    assert within(errors), errors
    # the full illumination on the same volume: the direct light is compiled again
    actor.set_illumination(illumination)
    actor.exposure = exposure
    assert actor.inputs.variant == (True, True, True)
    assert within(rel_errors(read_window_rgb(window), reference.radiance))
    actor.set_illumination(scattered)
    actor.exposure = scale
    assert (read_window_rgb(window) == fresh).all()
    window.Finalize()
