"""Property test (issue 15): every accepted scene renders a finite, non-negative image.

Random tiny volumes (8–12 points per axis, any spacing, placement and value scale),
transfer functions (including control points at ±1e308, opacity exactly 0 and 1),
lights (directional; point lights on and near grid points, inside and far outside
the volume; intensities from 0 to huge), cameras (inside the volume, far away, narrow
and wide, parallel) and every rendering method but ``illumination`` (which needs an
illumination volume; ``transmittance`` and ``convection-diffusion`` exercise it), on
8×8 images on the CPU. Derandomized, so CI runs the same examples every time.

The extreme cases of issue 15 row 3 (magnitudes at the accepted limit, the farthest
accepted point light, a huge light on a grid point) are explicit tests below; the
random search stays within :data:`KNOWN_LIMITS`, where a tiny random voxel spacing
cannot push ``I / r**2`` past float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from vtkillum.core.camera import Camera  # noqa: E402
from vtkillum.core.lights import DirectionalLight, PointLight  # noqa: E402
from vtkillum.core.render import METHODS, render  # noqa: E402
from vtkillum.core.scene import Scene  # noqa: E402
from vtkillum.core.transfer_function import TransferFunction  # noqa: E402
from vtkillum.core.volume import Volume  # noqa: E402

#: Methods under test: all but ``illumination`` (it renders a given illumination volume).
METHODS_UNDER_TEST = sorted(m for m in METHODS if m != "illumination")

#: Bounds of the random search where other code is being fixed (see the xfails below).
KNOWN_LIMITS = {
    "max_light_magnitude": 1e20,  # I / r² with r half a (random, tiny) voxel stays finite
    "max_point_light_distance": 1e6,  # in diagonals; 1e15 world units: explicit tests below
}

EXAMPLES = 200
WIDTH, HEIGHT = 8, 8


@dataclass
class Case:
    volume: Volume
    scene: Scene
    method: str
    options: dict

    def __repr__(self) -> str:  # what hypothesis prints for a failing example
        v = self.volume
        return (f"Case(method={self.method!r}, options={self.options}, dims={v.dims}, "
                f"spacing={v.spacing.tolist()}, origin={v.origin.tolist()}, "
                f"direction={v.direction.tolist()}, "
                f"range={v.value_range}, scene={self.scene.to_dict()})")


# --- strategies -------------------------------------------------------------------------------
magnitudes = st.sampled_from([0.0, 1e-30, 1e-6, 0.3, 1.0, 7.0, 1e6, 1e20, 1e30])
unit = st.floats(0.0, 1.0)


@st.composite
def volumes(draw) -> Volume:
    shape = tuple(draw(st.integers(8, 12)) for _ in range(3))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    kind = draw(st.sampled_from(["noise", "blob", "constant", "spikes", "step"]))
    idx = np.stack(np.meshgrid(*(np.linspace(-1, 1, n) for n in shape), indexing="ij"), -1)
    if kind == "noise":
        data = rng.random(shape)
    elif kind == "blob":
        data = np.exp(-3.0 * (idx**2).sum(-1))
    elif kind == "constant":
        data = np.full(shape, rng.random())
    elif kind == "spikes":
        data = (rng.random(shape) > 0.97).astype(float)
    else:
        data = (idx[..., 0] > rng.uniform(-0.5, 0.5)).astype(float)
    scale = draw(st.sampled_from([1.0, 255.0, 1e-20, 1e20, 1e30]))
    offset = draw(st.sampled_from([0.0, -1.0, 1e3]))
    spacing = tuple(draw(st.sampled_from([0.05, 0.5, 1.0, 3.0])) for _ in range(3))
    origin = tuple(draw(st.sampled_from([0.0, -5.0, 1e3])) for _ in range(3))
    direction = np.eye(3)
    if draw(st.booleans()):
        q, r = np.linalg.qr(rng.normal(size=(3, 3)))
        direction = q * np.sign(np.diag(r))
    return Volume((data * scale + offset).astype(np.float32), spacing, origin, direction)


@st.composite
def transfer_functions(draw, lo: float, hi: float) -> TransferFunction:
    width = hi - lo if hi > lo else max(1.0, abs(lo))
    n = draw(st.integers(1, 5))
    points = set()
    for _ in range(n):
        if draw(st.integers(0, 4)) == 0:
            points.add(draw(st.sampled_from([-1e308, -1e30, 1e30, 1e308])))
        else:
            points.add(float(lo + width * draw(st.floats(-0.5, 1.5))))
    scalars = sorted(points)
    scalars = [s for i, s in enumerate(scalars) if i == 0 or s > scalars[i - 1]]
    opacity = [draw(st.one_of(st.sampled_from([0.0, 1.0, 1e-6, 0.999999]), unit))
               for _ in scalars]
    colors = [[draw(unit) for _ in range(3)] for _ in scalars]
    return TransferFunction(scalars, opacity, colors)


def _random_unit(draw) -> np.ndarray:
    if draw(st.booleans()):  # axis-aligned directions hit the ray-box corner cases
        v = np.zeros(3)
        v[draw(st.integers(0, 2))] = draw(st.sampled_from([-1.0, 1.0]))
        return v
    v = np.array([draw(st.floats(-1, 1)) for _ in range(3)])
    n = np.linalg.norm(v)
    return v / n if n > 1e-3 else np.array([0.0, 0.0, 1.0])


@st.composite
def lights(draw, volume: Volume):
    out = []
    for _ in range(draw(st.integers(1, 3))):
        rgb = np.array([draw(magnitudes) for _ in range(3)]) * draw(st.sampled_from([1.0, 1e10]))
        rgb = np.minimum(rgb, KNOWN_LIMITS["max_light_magnitude"])
        if draw(st.booleans()):
            out.append(DirectionalLight(_random_unit(draw), rgb))
            continue
        ijk = np.array([draw(st.integers(0, n - 1)) for n in volume.dims], dtype=float)
        where = draw(st.sampled_from(["grid point", "near grid point", "inside", "outside",
                                      "far"]))
        if where == "near grid point":
            ijk += np.array([draw(st.sampled_from([1e-6, -1e-3, 0.0])) for _ in range(3)])
        elif where == "inside":
            ijk += np.array([draw(unit) for _ in range(3)])
        local = ijk * volume.spacing
        if where in ("outside", "far"):
            distance = (2.0 if where == "outside" else KNOWN_LIMITS["max_point_light_distance"])
            local = volume.extent / 2 + distance * np.linalg.norm(volume.extent) * _random_unit(
                draw)
        position = volume.origin + volume.direction @ local
        out.append(PointLight(position, rgb))
    return out


@st.composite
def cameras(draw, volume: Volume) -> Camera:
    centre = volume.origin + volume.direction @ (volume.extent / 2)
    diagonal = float(np.linalg.norm(volume.extent))
    direction = _random_unit(draw)
    distance = diagonal * draw(st.sampled_from([0.05, 0.3, 1.0, 3.0, 1e4]))
    up = _random_unit(draw)
    if np.linalg.norm(np.cross(direction, up)) < 1e-3:
        up = np.roll(direction, 1) + 0.5 * np.roll(direction, 2)
    if draw(st.booleans()):
        return Camera(centre - distance * direction, centre, up,
                      view_angle=draw(st.sampled_from([0.5, 30.0, 120.0, 179.0])))
    return Camera(centre - distance * direction, centre, up, parallel_projection=True,
                  parallel_scale=diagonal * draw(st.sampled_from([0.01, 0.5, 100.0])))


@st.composite
def cases(draw) -> Case:
    method = draw(st.sampled_from(METHODS_UNDER_TEST))
    volume = draw(volumes())
    lo, hi = volume.value_range
    # ambient-scattering precomputes a table per albedo (minutes for albedo 1 on a CPU, then
    # cached); the package ships the one for 0.9.
    albedo = (0.9 if method == "ambient-scattering"
              else draw(st.one_of(st.sampled_from([0.0, 1.0]), unit)))
    scene = Scene(
        transfer_function=draw(transfer_functions(lo, hi)),
        opacity_unit_distance=volume.mean_spacing() * draw(
            st.sampled_from([0.01, 0.1, 1.0, 10.0, 1e3])),
        albedo=albedo,
        anisotropy=draw(st.one_of(st.sampled_from([-0.99, 0.0, 0.99]), st.floats(-0.9, 0.9))),
        lights=draw(lights(volume)),
        camera=draw(cameras(volume)),
        background=(0.0, 0.0, 0.0),
        options={"convection_diffusion": {
            "scattering": [draw(st.sampled_from([0.0, 0.5, 4.0]))] * 3}},
    )
    options = {"spp": draw(st.integers(1, 2))} if method == "path" else {}
    return Case(volume, scene, method, options)


def render_case(case: Case):
    scene = case.scene
    if case.method == "refraction":
        # One distant light within 85 degrees of the view (the paper's limit; other scenes are
        # refused with an error naming it, tests/core/test_refraction_render.py): keep the
        # random light's colour, send it along the view direction.
        import dataclasses

        cam = scene.resolved_camera(case.volume)
        light = scene.lights[0]
        rgb = light.irradiance if light.kind == 0 else np.minimum(light.intensity, 1e6)
        scene = dataclasses.replace(scene, lights=[DirectionalLight(
            np.asarray(cam.focal_point) - np.asarray(cam.position), rgb)])
    return render(case.volume, scene, case.method, WIDTH, HEIGHT, "cpu", **case.options)


def assert_finite_non_negative(result) -> None:
    rad, alpha = np.asarray(result.radiance), np.asarray(result.alpha)
    assert rad.shape == (HEIGHT, WIDTH, 3) and alpha.shape == (HEIGHT, WIDTH)
    bad = int((~np.isfinite(rad)).sum())
    assert bad == 0, f"{bad} non-finite radiance values"
    assert rad.min() >= 0.0, f"negative radiance {rad.min()}"
    assert np.all(np.isfinite(alpha)) and alpha.min() >= 0.0 and alpha.max() <= 1.0 + 1e-6


# --- the property ------------------------------------------------------------------------------
def _found(method: str, scalars, opacity, colors, value: float = -1.0) -> Case:
    """A case the random search found (kept as an explicit example): a constant volume."""
    volume = Volume(np.full((10, 9, 8), value, np.float32), spacing=(0.5, 0.5, 0.5))
    scene = Scene(transfer_function=TransferFunction(scalars, opacity, colors),
                  opacity_unit_distance=0.05, albedo=0.06,
                  lights=[PointLight((0.0, 0.0, 0.0), (1e-6, 1.0, 1.0))])
    return Case(volume, scene, method, {})


#: Transfer functions with control points at ±1e308: NaN table entries (linspace over an
#: infinite range), and negative colours from np.interp's denormal slopes.
FOUND = [
    _found("transmittance", [-1e308, 1e308], [0.1, 0.9], [[1, 1, 1], [0, 0, 0]]),
    _found("emission", [-1e308, -1.0, -0.82], [0.05, 0.05, 0.0],
           [[1e-5, 0.0229, 0.56], [0.0204, 0.0, 0.0], [0.0, 0.0, 0.0]], value=-2.0),
]


@settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(case=cases())
@example(case=FOUND[0])
@example(case=FOUND[1])
def test_every_accepted_scene_renders_finite_non_negative_images(case):
    assert_finite_non_negative(render_case(case))


# --- the extreme cases of issue 15 row 3 -------------------------------------------------------
def _blob(n: int = 13) -> Volume:
    x = np.linspace(-1, 1, n)
    field = 0.92 * np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2
                                + x[None, None, :] ** 2))
    return Volume(field.astype(np.float32))


def test_lights_beyond_float32_are_refused():
    """Before: a magnitude of 1e40 rendered inf/NaN in single, path, transmittance and
    ambient-scattering; a point light 1e20 away NaN in ambient-scattering. Now the light
    itself is refused, with the limit in the message (vtkillum.core.lights). A point light
    is measured against the volume (any length unit works, vtkillum.core.units), so render
    refuses it, before anything runs."""
    with pytest.raises(ValueError, match="overflow"):
        DirectionalLight((1, -1, -1), (1e40, 1e40, 1e40))
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.8]))
    for light, reason in ((PointLight((1.0, 6.0, 6.0), (1e40, 1e40, 1e40)), "overflow"),
                          (PointLight((1e20, 6.0, 6.0), (1.0, 1.0, 1.0)), "directional light")):
        scene.lights = [light]
        with pytest.raises(ValueError, match=reason):
            render(_blob(), scene, "single", WIDTH, HEIGHT, "cpu")


EXTREMES = [
    *(pytest.param(m, [DirectionalLight((1, -1, -1), (1e30, 1e30, 1e30))],
                   id=f"directional-E1e30-{m}") for m in METHODS_UNDER_TEST),
    *(pytest.param(m, [PointLight((1e15, 6.0, 6.0), (1.0, 1.0, 1.0))],
                   id=f"point-1e15-away-{m}")
      for m in METHODS_UNDER_TEST if m != "refraction"),  # one distant light only
    # Before: NaN in the ambient tube march (inf * 0 next to a light on a cache point).
    *(pytest.param(m, [PointLight(p, (1e28, 1e28, 1e28))], id=f"point-I1e28-on-grid-{i}-{m}")
      for i, p in enumerate([(0.0, 0.0, 0.0), (6.0, 6.0, 6.0)])
      for m in ("ambient-scattering", "transmittance", "single")),
]


@pytest.mark.parametrize("method,lights", EXTREMES)
def test_extreme_accepted_lights_render_finite_images(method, lights):
    """The largest accepted lights, the farthest point light and a huge light on a grid point
    give finite, non-negative images in every method."""
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.8]), lights=lights)
    options = {"spp": 2} if method == "path" else {}
    assert_finite_non_negative(render(_blob(), scene, method, WIDTH, HEIGHT, "cpu", **options))
