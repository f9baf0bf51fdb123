"""The pictures of ``docs/many_lights.md`` (Weber et al.'s Figs. 1, 4 and 6 on our data).

* ``many_lights_fig1.png``: single scattering, multiple scattering alone, both, and the
  path tracer (CT phantom, the paper's Fig. 1);
* ``many_lights_fig6.png``: a transfer-function edit (soft tissue made visible and
  recoloured): before, immediately after (eq. 6 contribution update, VL positions and
  AVSMs kept), after the progressive regeneration (the paper's Fig. 6);
* ``many_lights_fig4.png``: 200 VLs, 2000 VLs and the converged path tracer on a cloud
  where multiple scattering dominates (the paper's Fig. 4 shows two 200-VL sets).

Runs on the CPU in a few minutes at the default sizes (``--size``, ``--image``); images
are tone-mapped with one exposure per figure and written to ``--out``.

Example::

    python benchmarks/many_lights_pictures.py --out docs/images
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from vtkillum.core.many_lights.render import ManyLightsRenderer
from vtkillum.core.render import render
from vtkillum.core.tonemap import tonemap
from vtkillum.data.accuracy_suite import build
from vtkillum.data.procedural import ct_phantom, default_scene

try:
    from bench_many_lights import edited_scene
except ImportError:  # run from elsewhere
    from benchmarks.bench_many_lights import edited_scene


def strip(images: dict, path: Path, exposure: float, scale: int = 2) -> None:
    """Labelled tiles side by side, one exposure, nearest-neighbour upscaled."""
    tiles = []
    for label, img in images.items():
        rgb = tonemap(img, exposure=exposure)
        tile = Image.fromarray(rgb).resize((rgb.shape[1] * scale, rgb.shape[0] * scale),
                                           Image.NEAREST)
        ImageDraw.Draw(tile).text((4, 2), label, fill=(255, 255, 0))
        tiles.append(tile)
    out = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height))
    x = 0
    for tile in tiles:
        out.paste(tile, (x, 0))
        x += tile.width
    path.parent.mkdir(parents=True, exist_ok=True)
    out.save(path)
    print(f"wrote {path}")


def report(name: str, images: dict, reference) -> None:
    """Print rel. RMSE and energy of each image against the reference."""
    for label, img in images.items():
        rmse = np.sqrt(np.mean((img - reference) ** 2)) / np.sqrt(np.mean(reference ** 2))
        print(f"  {name} {label}: rel. RMSE {rmse:.3f}, energy "
              f"{img.sum() / reference.sum():.3f}")


def exposure_of(image) -> float:
    return 0.8 / max(float(np.percentile(image.max(-1), 99.5)), 1e-12)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=64, help="CT phantom points per axis")
    parser.add_argument("--image", type=int, default=128, help="image width = height")
    parser.add_argument("--vls", type=int, default=1000, help="VLs of the CT figures")
    parser.add_argument("--avsm-resolution", type=int, default=32)
    parser.add_argument("--spp", type=int, default=512, help="path-tracer samples per pixel")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--out", default="docs/images")
    parser.add_argument("--only", nargs="*", default=["fig1", "fig6", "fig4"])
    args = parser.parse_args(argv)
    out = Path(args.out)
    W = args.image
    common = {"avsm_resolution": args.avsm_resolution, "seed": 2}

    volume = ct_phantom(args.size)
    scene = default_scene("ct", volume)
    if "fig1" in args.only or "fig6" in args.only:
        t0 = time.perf_counter()
        renderer = ManyLightsRenderer(volume, scene, W, W, args.device, count=args.vls,
                                      **common)
        before = renderer.run(1).result()
        print(f"CT, {renderer.state.vls.n_vls} VLs: {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        reference = render(volume, scene, "path", W, W, args.device, spp=args.spp, seed=1)
        print(f"CT path {args.spp} spp: {time.perf_counter() - t0:.1f} s")
        e = exposure_of(reference.radiance)
        report("CT", {"many lights": before.radiance,
                      "single": before.info["single"]}, reference.radiance)
        if "fig1" in args.only:
            strip({"single scattering": before.info["single"],
                   "multiple (VLs) only": before.info["multiple"],
                   "single + multiple": before.radiance,
                   f"path tracer ({args.spp} spp)": reference.radiance},
                  out / "many_lights_fig1.png", e)
        if "fig6" in args.only:
            edited = edited_scene(scene)
            edit = renderer.update(edited)
            immediate = renderer.run(1).result()
            t0 = time.perf_counter()
            frames = 0
            while renderer.state.stale:
                renderer.frame()
                frames += 1
            after = renderer.result()
            print(f"edit {edit['edits']}: update {edit['update_ms']:.0f} ms, regeneration "
                  f"{frames} frames, {time.perf_counter() - t0:.1f} s")
            fresh = ManyLightsRenderer(volume, edited, W, W, args.device, count=args.vls,
                                       **common).run(1).result()
            print("after regeneration == fresh render:",
                  bool(np.allclose(after.radiance, fresh.radiance, rtol=1e-4, atol=1e-7)))
            strip({"initial": before.radiance, "immediately after the edit": immediate.radiance,
                   f"after regeneration ({frames} frames)": after.radiance},
                  out / "many_lights_fig6.png", e)

    if "fig4" in args.only:
        cloud, cloud_scene = build("thick-cloud", args.size)
        images = {}
        for count in (200, 2000):
            t0 = time.perf_counter()
            result = render(cloud, cloud_scene, "many-lights", W, W, args.device, count=count,
                            **common)
            images[f"{count} VLs"] = result.radiance
            print(f"cloud, {result.info['vls']} VLs: {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        reference = render(cloud, cloud_scene, "path", W, W, args.device, spp=args.spp, seed=1)
        print(f"cloud path {args.spp} spp: {time.perf_counter() - t0:.1f} s")
        report("cloud", images, reference.radiance)
        images[f"converged (path, {args.spp} spp)"] = reference.radiance
        strip(images, out / "many_lights_fig4.png", exposure_of(reference.radiance))


if __name__ == "__main__":
    main()
