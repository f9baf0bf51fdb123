"""Pictures of ``docs/photon.md``: photon mapping with Historygrams.

* ``photon_cornell_edit.png`` — the Cornell box with a sphere before and after an edit of
  the sphere's colour; the second image is the Historygram update of the first (only the
  photons and segments the edit invalidated are recomputed; the fractions are printed
  and written into the picture).
* ``photon_cornell_orders.png`` — single scattering (``S_n = 1``) next to unbounded
  multiple scattering, photons for all light as in the paper's Fig. 4(b, c), and the
  default (exact direct light + scattered photons).
* ``photon_ct.png`` — the CT phantom: ``single``, ``photon`` (multiple scattering), and
  ``photon`` with the bone scattering as a specular surface (the optional BRDF of
  :mod:`vtkillum.core.photon.material`).

Usage::

    python benchmarks/photon_pictures.py --size 64 --image 160 --photons 200000
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from PIL import Image, ImageDraw

from vtkillum.core.photon.mapper import PhotonMapper
from vtkillum.core.render import render
from vtkillum.core.tonemap import tonemap
from vtkillum.data.cornell_sphere import cornell_sphere, cornell_sphere_scene
from vtkillum.data.procedural import ct_phantom, default_scene


def tile(result, scene, label, exposure=1.0):
    img = Image.fromarray(tonemap(result.radiance, result.alpha, scene.background,
                                  exposure=exposure))
    draw = ImageDraw.Draw(img)
    for i, line in enumerate(label.split("\n")):
        draw.text((4, 2 + 11 * i), line, fill=(255, 255, 0))
    return img


def strip(tiles, path):
    out = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height))
    x = 0
    for t in tiles:
        out.paste(t, (x, 0))
        x += t.width
    out.save(path)
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--image", type=int, default=160)
    parser.add_argument("--photons", type=int, default=200_000)
    parser.add_argument("--passes", type=int, default=2)
    parser.add_argument("--device", default=None)
    parser.add_argument("--out", default="docs/images")
    parser.add_argument("--only", choices=["cornell", "ct"], default=None)
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    s = args.image
    from vtkillum.core.device import resolve_device

    device = resolve_device(args.device)

    if args.only != "ct":
        cornell_pictures(args, out, s, device)
    if args.only != "cornell":
        ct_pictures(args, out, s, device)


def cornell_pictures(args, out, s, device):
    # 1. Cornell box: sphere colour edit through the Historygrams.
    volume = cornell_sphere(args.size)
    scene = cornell_sphere_scene(volume)
    edited = cornell_sphere_scene(volume, color=(0.2, 0.35, 0.9))
    m = PhotonMapper(device, args.photons, 2.0 * volume.mean_spacing(), 0, 8, 0)
    u = scene.resolved_unit_distance(volume)
    camera = scene.resolved_camera(volume)
    step = scene.resolved_step_size(volume)
    t0 = time.perf_counter()
    m.update(volume, scene.transfer_function, u, scene.albedo, scene.anisotropy, scene.lights)
    before = m.render(volume, camera, s, s, step)
    t_full = time.perf_counter() - t0
    t0 = time.perf_counter()
    upd = m.update(volume, edited.transfer_function, u, scene.albedo, scene.anisotropy,
                   scene.lights)
    after = m.render(volume, camera, s, s, step)
    t_inc = time.perf_counter() - t0
    info = m.last_render
    print(f"cornell edit: full {t_full:.1f} s, incremental {t_inc:.1f} s, photons "
          f"{upd['photon_fraction']:.1%}, segments {info['segment_fraction']:.1%}")
    strip([tile(before, scene, "before"),
           tile(after, scene, f"after: {upd['photon_fraction']:.0%} photons,\n"
                              f"{info['segment_fraction']:.0%} segments recomputed")],
          out / "photon_cornell_edit.png")

    # 2. Single vs multiple scattering.
    tiles = []
    for label, opts in (("S_n = 1, photons only", {"max_order": 1, "direct": "photons"}),
                        ("S_n unbounded, photons only", {"max_order": 0, "direct": "photons"}),
                        ("S_n unbounded, exact direct", {"max_order": 0})):
        r = render(volume, scene, "photon", s, s, device, photons=args.photons,
                   passes=args.passes, **opts)
        tiles.append(tile(r, scene, label))
    strip(tiles, out / "photon_cornell_orders.png")



def ct_pictures(args, out, s, device):
    # 3. CT phantom, the bone optionally a specular surface.
    ct = ct_phantom(args.size)
    ct_scene = default_scene("ct", ct)
    single = render(ct, ct_scene, "single", s, s, device)
    photon = render(ct, ct_scene, "photon", s, s, device, photons=args.photons,
                    passes=args.passes)
    shiny = render(ct, ct_scene, "photon", s, s, device, photons=args.photons,
                   passes=args.passes, surface_range=[0.8, 1.0], surface_diffuse=0.5,
                   surface_specular=0.5, surface_shininess=30.0)
    strip([tile(single, ct_scene, "single"), tile(photon, ct_scene, "photon"),
           tile(shiny, ct_scene, "photon, specular bone")], out / "photon_ct.png")
    ratio = float(photon.radiance.sum() / max(single.radiance.sum(), 1e-12))
    print(f"ct: photon / single energy {ratio:.2f}")


if __name__ == "__main__":
    main()
