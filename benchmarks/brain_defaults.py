"""Issue 34: the MNI152 brain with every method's default settings against the path tracer.

Renders the MNI152 T1 template (nilearn's, 197 x 233 x 189; any NIfTI file works) as
``vtkillum render FILE --size N N`` does (data-aware transfer function, camera and key
light), once per method, and prints rel. RMSE and energy ratio against a path-traced
reference, the mean of ``--runs`` independent renders of ``--spp`` samples per pixel
(seeds 1, 2, ...; cached in ``--cache``). Writes the pictures side by side, all at the
reference's automatic exposure, to ``--out``.

    python benchmarks/brain_defaults.py mni152.nii.gz --size 128 --spp 256 --runs 16 \\
        --cache /tmp/brain --out docs/images/accuracy_mni_brain_defaults.png

The settings compared are the defaults before and after issue 34 (``OLD`` below) and
two methods without Monte Carlo noise for context. ``many-lights`` with its defaults
adds VL sets until a time budget, so its row depends on the machine; ``many-lights,
1 set`` does not.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

#: (label, method, options): each row of the table.
OLD_ML = dict(count=256, sets=1, virtual_lights="spherical", vsl_radius=2.0,
              vsl_radius_mfp=0.5, avsm_resolution=48, view_samples=8)
OLD_PHOTON = dict(photons=200_000, radius=2.0)
ROWS = [
    ("photon, old defaults", "photon", OLD_PHOTON),
    ("photon", "photon", {}),
    ("many-lights, old defaults", "many-lights", OLD_ML),
    ("many-lights, 1 set", "many-lights", {"sets": 1}),
    ("many-lights", "many-lights", {}),
    ("convection-diffusion", "convection-diffusion", {}),
    ("transmittance", "transmittance", {}),
]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("input", help="NIfTI file (e.g. nilearn's MNI152 template)")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--spp", type=int, default=256, help="samples per reference run")
    parser.add_argument("--runs", type=int, default=16, help="reference runs (seeds 1..)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--cache", default="brain_cache", help="folder for the renders")
    parser.add_argument("--out", default="accuracy_mni_brain_defaults.png")
    args = parser.parse_args(argv)

    from vtkillum.cli import load_input
    from vtkillum.core.render import render

    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    n = args.size
    volume, scene = load_input(args.input, aspect=1.0)
    runs = []
    for seed in range(1, args.runs + 1):
        path = cache / f"path_{n}_{args.spp}_{seed}.npy"
        if not path.exists():
            image = render(volume, scene, "path", n, n, args.device, spp=args.spp,
                           seed=seed).radiance
            np.save(path, image)
        runs.append(np.load(path).astype(np.float64))
    ref = np.mean(runs, axis=0)
    noise = np.std(runs, axis=0, ddof=1) / np.sqrt(len(runs))
    norm = np.sqrt(np.mean(ref**2))
    print(f"reference: path, {args.runs} x {args.spp} spp, {n}x{n}, relative noise "
          f"{np.sqrt(np.mean(noise**2)) / norm:.4f}")
    print("| settings | rel. RMSE | energy | s | notes |")
    print("|---|---|---|---|---|")
    images = [("path (reference)", ref)]
    for label, method, options in ROWS:
        t0 = time.perf_counter()
        result = render(volume, scene, method, n, n, args.device, **options)
        seconds = time.perf_counter() - t0
        image = result.radiance.astype(np.float64)
        np.save(cache / f"{label.replace(' ', '_').replace(',', '')}_{n}.npy", image)
        rmse = np.sqrt(np.mean((image - ref) ** 2)) / norm
        energy = image.sum() / ref.sum()
        info = result.info
        notes = []
        if method == "many-lights":
            notes.append(f"{info['sets']} set(s) of {info['vls']} VLs")
            if info.get("stopped"):
                notes.append(f"stopped: {info['stopped']}")
        if method == "photon":
            notes.append(f"{info['photons']} photons, r = "
                         f"{info['radius_world'] / volume.mean_spacing():.2f} voxels")
        print(f"| {label} | {rmse:.3f} | {energy:.2f} | {seconds:.0f} | {', '.join(notes)} |",
              flush=True)
        images.append((label, image))
    write_strip(images, Path(args.out))


def write_strip(images, out: Path, columns: int = 4) -> None:
    """The images in rows of ``columns`` at the first one's automatic exposure, labelled."""
    from PIL import Image, ImageDraw

    from vtkillum.core.defaults import auto_exposure
    from vtkillum.core.tonemap import tonemap

    exposure = auto_exposure(images[0][1])
    tiles = []
    for label, image in images:
        tile = Image.fromarray(tonemap(image.astype(np.float32), None, (0, 0, 0), exposure))
        ImageDraw.Draw(tile).text((3, 2), label, fill=(255, 255, 255))
        tiles.append(tile)
    w, h = tiles[0].size
    rows = -(-len(tiles) // columns)
    strip = Image.new("RGB", (w * min(columns, len(tiles)), h * rows))
    for i, tile in enumerate(tiles):
        strip.paste(tile, ((i % columns) * w, (i // columns) * h))
    strip.save(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
