"""The pictures of ``docs/refraction.md`` (refraction and caustics, Magnus & Bruckner 2017).

* ``refraction_glass_series.png`` — the paper's Fig. 8 on ``builtin:glass``: no
  refraction, medium colour only, "beer", "juice", "red wine in green glass";
* ``refraction_luneburg.png`` — a Luneburg lens focusing parallel light on a screen
  behind it, and the light buffer along the lens axis (a slice through the planes);
* ``refraction_soft_hard.png`` — a glass ball on a checkered floor: no refraction,
  hard light, soft light (softness 0.5 and 1.5); ``refraction_soft_hard_glass.png`` — the
  "beer" glass under hard and soft light;
* ``refraction_environment.png`` — a gradient-index lens in front of an environment map
  (section 4.4), without and with refraction.

Run on the CPU at the default sizes in a few minutes::

    python benchmarks/refraction_pictures.py --out docs/images
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.refraction.environment import checker_environment
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.render import render_refraction
from vtkillum.core.scene import Scene
from vtkillum.core.tonemap import tonemap
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume
from vtkillum.data.procedural import GLASS_PRESETS, glass_preset, stemmed_glass


def labelled(rgb: np.ndarray, label: str) -> Image.Image:
    tile = Image.fromarray(rgb)
    ImageDraw.Draw(tile).text((4, 2), label, fill=(255, 255, 0))
    return tile


def strip(tiles, path: Path) -> None:
    out = Image.new("RGB", (sum(t.width for t in tiles), max(t.height for t in tiles)))
    x = 0
    for t in tiles:
        out.paste(t, (x, 0))
        x += t.width
    out.save(path)
    print(f"wrote {path}")


def glass_series(out: Path, n: int, size: int, device: str) -> None:
    volume = stemmed_glass(n)
    tiles = []
    for preset in GLASS_PRESETS:
        scene, optics = glass_preset(volume, preset)
        t0 = time.perf_counter()
        r = render_refraction(volume, scene, size, size, device, optics=optics)
        print(f"  glass {preset}: {time.perf_counter() - t0:.1f} s, {r.info['planes']} planes")
        tiles.append(labelled(tonemap(r.radiance, r.alpha, (0.02, 0.02, 0.03), gamma=2.2),
                              preset))
    strip(tiles, out / "refraction_glass_series.png")


def luneburg(out: Path, size: int, device: str) -> None:
    """Lens of radius 12 voxels, η = sqrt(2 - (r/R)²); a white screen 2 voxels behind its pole."""
    n = (49, 49, 52)
    R, c = 12.0, np.array([24.0, 24.0, 18.0])
    x, y, z = (np.arange(k, dtype=np.float64) for k in n)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    lens = ((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) / R ** 2  # (r/R)^2
    screen = np.clip(Z - (c[2] + R + 2.0), 0.0, 1.0)  # from z = 32 on
    data = np.where(screen > 0, 2.0 + screen, np.minimum(lens, 1.5)).astype(np.float32)
    volume = Volume(data)
    knots = np.linspace(0.0, 1.0, 65)
    optics = RefractiveOptics(np.r_[knots, 1.5, 3.0], np.r_[np.sqrt(2.0 - knots), 1.0, 1.0])
    tf = TransferFunction([0.0, 1.0, 1.5, 2.0, 3.0], [0.0, 0.0, 0.0, 0.0, 0.9],
                          [[1, 1, 1]] * 4 + [[0.95, 0.95, 0.9]])
    light = DirectionalLight((0.0, 0.0, 1.0), (8.0, 8.0, 8.0))
    camera = Camera((c[0] + 70.0, c[1] - 20.0, c[2] - 35.0), (c[0], c[1], c[2] + 8.0),
                    (0.0, 1.0, 0.0), view_angle=34.0)
    scene = Scene(transfer_function=tf, opacity_unit_distance=1.0, lights=[light], camera=camera)
    tiles = []
    for label, opts in (("straight light (eta = 1)", {}),
                        ("Luneburg lens", {"optics": optics})):
        r = render_refraction(volume, scene, size, size, device, **opts)
        tiles.append(labelled(tonemap(r.radiance, r.alpha, (0.02, 0.02, 0.03), exposure=0.8,
                                      gamma=2.2), label))
    # The light field along the axis: one row of every light plane (camera along the light).
    axial = Camera((c[0], c[1], -60.0), (c[0], c[1], 0.0), (0.0, 1.0, 0.0),
                   parallel_projection=True, parallel_scale=24.0)
    scene.camera = axial
    r = render_refraction(volume, scene, 49, 49, device, optics=optics, record_light=True,
                          max_concentration=1000.0)
    g = r.info["geometry"]
    planes = r.info["light_planes"]
    row = int(round((0.0 - g.grid_origin[1]) / g.texel))
    section = np.array([planes[j]["light"][row, :, 0] for j in sorted(planes)])
    img = np.log1p(section) / np.log1p(section.max())
    img = (255 * np.clip(img, 0, 1)).astype(np.uint8)
    scale = size / max(img.shape)
    tile = Image.fromarray(np.stack([img] * 3, -1)).resize(
        (int(img.shape[1] * scale), int(img.shape[0] * scale)), Image.NEAREST)
    ImageDraw.Draw(tile).text((4, 2), "light buffer along the axis (log)", fill=(255, 255, 0))
    tiles.append(tile)
    strip(tiles, out / "refraction_luneburg.png")


def glass_ball(n: int = 80):
    x = np.linspace(-1, 1, n)
    h = x[1] - x[0]
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    r = np.sqrt(X ** 2 + (Y - 0.15) ** 2 + Z ** 2)
    ball = np.clip((0.45 - r) / (1.5 * h) + 0.5, 0, 1)
    floor = np.clip((-0.55 - Y) / (1.5 * h) + 0.5, 0, 1)
    check = (np.floor(X * 5) + np.floor(Z * 5)) % 2
    data = (ball - floor * (1.0 - 0.3 * check)).astype(np.float32)
    volume = Volume(data, spacing=(h, h, h), origin=(-1, -1, -1))
    tf = TransferFunction([-1.0, -0.6, -0.05, 0.0, 1.0], [0.9, 0.9, 0.0, 0.0, 0.002],
                          [[0.9, 0.9, 0.9], [0.6, 0.6, 0.6], [1, 1, 1], [1, 1, 1], [1, 1, 1]])
    camera = Camera((0.0, 0.9, -3.6), (0.0, -0.15, 0.0), (0.0, 1.0, 0.0), view_angle=35.0)
    scene = Scene(transfer_function=tf, lights=[DirectionalLight((0.25, -1.0, 0.6), (3, 3, 3))],
                  camera=camera, opacity_unit_distance=h)
    return volume, scene, RefractiveOptics([0.0, 1.0], [1.0, 1.5])


def soft_hard(out: Path, size: int, device: str, n: int = 96) -> None:
    volume, scene, optics = glass_ball()
    tiles = []
    for label, opts in (("no refraction", {}), ("hard light", {"optics": optics}),
                        ("softness 0.5", {"optics": optics, "softness": 0.5}),
                        ("softness 1.5", {"optics": optics, "softness": 1.5})):
        r = render_refraction(volume, scene, size, size, device, **opts)
        tiles.append(labelled(tonemap(r.radiance, r.alpha, (0.05, 0.05, 0.06), exposure=1.5,
                                      gamma=2.2), label))
    strip(tiles, out / "refraction_soft_hard.png")
    # The glass ("beer"): its shadow and the caustics on the wall soften with the light.
    glass = stemmed_glass(n)
    scene, optics = glass_preset(glass, "beer")
    tiles = []
    for softness in (0.0, 0.5, 1.5):
        r = render_refraction(glass, scene, size, size, device, optics=optics, softness=softness)
        tiles.append(labelled(tonemap(r.radiance, r.alpha, gamma=2.2), f"softness {softness}"))
    strip(tiles, out / "refraction_soft_hard_glass.png")


def environment(out: Path, size: int, device: str) -> None:
    n = 48
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    s = np.exp(-(X ** 2 + Y ** 2 + Z ** 2) / 0.18).astype(np.float32)
    volume = Volume(s, spacing=(x[1] - x[0],) * 3, origin=(-1, -1, -1))
    camera = Camera((0.0, 0.35, -4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), view_angle=40.0)
    tf = TransferFunction([0.0, 1.0], [0.0, 0.0])
    scene = Scene(transfer_function=tf, camera=camera,
                  lights=[DirectionalLight((0.3, -0.4, 1.0), (1, 1, 1))])
    env = checker_environment(256, squares=24)
    tiles = []
    for label, opts in (("eta = 1", {}),
                        ("gradient-index ball", {"optics": RefractiveOptics([0.0, 1.0],
                                                                            [1.0, 1.35])}),
                        ("+ medium colour", {"optics": RefractiveOptics(
                            [0.0, 1.0], [1.0, 1.35], [0.0, 1.0], [[1, 1, 1], [0.8, 0.9, 1.0]])})):
        r = render_refraction(volume, scene, size, size, device, environment=env, **opts)
        tiles.append(labelled(tonemap(r.radiance, r.alpha, gamma=2.2), label))
    strip(tiles, out / "refraction_environment.png")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/images")
    ap.add_argument("--device", default=None)
    ap.add_argument("--glass-size", type=int, default=128, help="builtin:glass resolution")
    ap.add_argument("--image", type=int, default=200)
    ap.add_argument("--only", nargs="+", default=["glass", "luneburg", "soft", "environment"])
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if "glass" in args.only:
        glass_series(out, args.glass_size, args.image, args.device)
    if "luneburg" in args.only:
        luneburg(out, args.image, args.device)
    if "soft" in args.only:
        soft_hard(out, args.image, args.device)
    if "environment" in args.only:
        environment(out, args.image, args.device)


if __name__ == "__main__":
    main()
