"""Accuracy of every method against the converged path tracer, on the accuracy suite.

For each scene of :mod:`vtkillum.data.accuracy_suite` the script path-traces a
reference (unbiased: Russian roulette only), renders every method with its
defaults, and prints per method

* **rel. RMSE** — ``sqrt(mean((L - L_ref)^2)) / sqrt(mean(L_ref^2))`` over all
  pixels and channels (radiance, background excluded);
* **energy** — ``sum(L) / sum(L_ref)``;
* **time** — wall-clock seconds of the render, light volumes included (kernels
  compiled beforehand, camera-independent caches cold);

and the reference's own noise, ``sqrt(mean(var(L_ref))) / sqrt(mean(L_ref^2))``,
the floor under which no rel. RMSE can be read. With ``--markdown`` it writes the
tables and side-by-side pictures (reference first) to ``docs/accuracy.md`` and
``docs/images/accuracy_<scene>.png``.

Examples
--------
CPU, small (a few minutes on 2 cores)::

    python benchmarks/accuracy.py --size 40 --image 64 --spp 256

GPU, the published table::

    python benchmarks/accuracy.py --size 128 --image 256 --spp 4096 --markdown docs/accuracy.md
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from vtkillum.core.device import resolve_device
from vtkillum.core.render import render
from vtkillum.core.tonemap import tonemap
from vtkillum.data.accuracy_suite import SUITE, build

METHODS = ["single", "transmittance", "convection-diffusion", "ambient-scattering"]


def errors(image: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """``(rel. RMSE, energy ratio)`` of ``image`` against ``reference`` (both (H, W, 3))."""
    rms = float(np.sqrt(np.mean(reference.astype(np.float64) ** 2)))
    rmse = float(np.sqrt(np.mean((image.astype(np.float64) - reference) ** 2)))
    return rmse / rms, float(image.sum(dtype=np.float64) / reference.sum(dtype=np.float64))


def reference(name: str, n: int, size: int, spp: int, device: str, cache: Path | None):
    """Converged path-traced radiance and its relative noise (cached as .npz when asked)."""
    path = None
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        path = cache / f"{name}_n{n}_{size}px_{spp}spp.npz"
        if path.is_file():
            data = np.load(path)
            return data["radiance"], float(data["noise"]), float(data["seconds"])
    volume, scene = build(name, n)
    t0 = time.perf_counter()
    result = render(volume, scene, "path", size, size, device, spp=spp, seed=1)
    seconds = time.perf_counter() - t0
    ref = result.radiance
    noise = float(np.sqrt(np.mean(result.info["radiance_variance"]))
                  / np.sqrt(np.mean(ref.astype(np.float64) ** 2)))
    if result.info.get("capped_paths"):
        print(f"  warning: {result.info['capped_paths']} reference paths hit the bounce cap")
    if path is not None:
        np.savez_compressed(path, radiance=ref, noise=noise, seconds=seconds)
    return ref, noise, seconds


def run(args) -> dict:
    device = resolve_device(args.device)
    # Compile every kernel on a tiny scene first so that timings are the methods' own.
    volume, scene = build("thin-plume", 12)
    for method in args.methods + ["path"]:
        render(volume, scene, method, 8, 8, device, **({"spp": 1} if method == "path" else {}))
    results = {"device": device_name(device), "size": args.size, "image": args.image,
               "spp": args.spp, "scenes": {}}
    for name in args.scenes:
        ref, noise, ref_s = reference(name, args.size, args.image, args.spp, device,
                                      Path(args.cache) if args.cache else None)
        row = {"description": SUITE[name].description, "noise": noise, "path_s": ref_s,
               "methods": {}}
        images = {"path": ref}
        for method in args.methods:
            volume, scene = build(name, args.size)  # fresh: light volumes not cached
            t0 = time.perf_counter()
            out = render(volume, scene, method, args.image, args.image, device)
            seconds = time.perf_counter() - t0
            rmse, energy = errors(out.radiance, ref)
            row["methods"][method] = {"rel_rmse": rmse, "energy": energy, "seconds": seconds}
            images[method] = out.radiance
        results["scenes"][name] = row
        print_scene(name, row)
        if args.markdown:
            save_strip(images, Path(args.markdown).parent / "images" / f"accuracy_{name}.png")
    return results


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        import warp as wp

        return wp.get_device(device).name
    return f"CPU ({platform.processor() or platform.machine()}, warp single-threaded)"


def print_scene(name: str, row: dict) -> None:
    print(f"\n{name}: {row['description']} (reference noise {row['noise']:.3f}, "
          f"path {row['path_s']:.1f} s)")
    print(f"  {'method':22s} {'rel. RMSE':>10s} {'energy':>8s} {'time s':>8s}")
    for method, m in row["methods"].items():
        print(f"  {method:22s} {m['rel_rmse']:10.3f} {m['energy']:8.3f} {m['seconds']:8.3f}")


def save_strip(images: dict, path: Path) -> None:
    """Tone-mapped images side by side (reference first), one exposure for the row."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        from PIL import Image, ImageDraw
    except ImportError:  # e.g. a GPU machine without Pillow: keep the radiance instead
        np.savez_compressed(path.with_suffix(".npz"), **images)
        return
    ref = images["path"]
    exposure = 0.8 / max(float(np.percentile(ref.max(-1), 99.5)), 1e-12)
    tiles = []
    for label, img in images.items():
        rgb = tonemap(img, exposure=exposure)
        tile = Image.fromarray(rgb)
        ImageDraw.Draw(tile).text((4, 2), label, fill=(255, 255, 0))
        tiles.append(tile)
    strip = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height))
    x = 0
    for tile in tiles:
        strip.paste(tile, (x, 0))
        x += tile.width
    strip.save(path)


def markdown(results: dict) -> str:
    methods = list(next(iter(results["scenes"].values()))["methods"])
    lines = [
        "# Accuracy against the path tracer",
        "",
        "Generated by `benchmarks/accuracy.py` "
        f"(`--size {results['size']} --image {results['image']} --spp {results['spp']}`) on "
        f"**{results['device']}**. Reference: `path` (unbiased, Russian roulette only) with "
        f"{results['spp']} samples per pixel; *noise* is its own relative standard error, "
        "the floor of every rel. RMSE. Each method runs with its defaults; times include "
        "its light volumes (kernels compiled, caches cold).",
        "",
        "rel. RMSE = sqrt(mean((L - L_ref)²)) / sqrt(mean(L_ref²)) over pixels and channels; "
        "energy = sum(L) / sum(L_ref).",
        "",
    ]
    header = "| scene | noise | " + " | ".join(methods) + " |"
    lines += ["## Relative RMSE (energy ratio)", "", header,
              "|" + "---|" * (len(methods) + 2)]
    for name, row in results["scenes"].items():
        cells = [f"{m['rel_rmse']:.3f} ({m['energy']:.2f})" for m in row["methods"].values()]
        lines.append(f"| {name} | {row['noise']:.3f} | " + " | ".join(cells) + " |")
    lines += ["", "## Time per render (s)", "", header, "|" + "---|" * (len(methods) + 2)]
    for name, row in results["scenes"].items():
        cells = [f"{m['seconds']:.3f}" for m in row["methods"].values()]
        lines.append(f"| {name} | path {row['path_s']:.1f} | " + " | ".join(cells) + " |")
    lines += ["", "## Scenes", ""]
    for name, row in results["scenes"].items():
        lines += [f"**{name}**: {row['description']}.", "",
                  f"![{name}](images/accuracy_{name}.png)", ""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=40, help="volume points per axis")
    parser.add_argument("--image", type=int, default=64, help="image width = height")
    parser.add_argument("--spp", type=int, default=256, help="reference samples per pixel")
    parser.add_argument("--scenes", nargs="+", default=list(SUITE), choices=list(SUITE))
    parser.add_argument("--methods", nargs="+", default=METHODS)
    parser.add_argument("--device", default=None)
    parser.add_argument("--cache", default=None, help="folder caching the path references")
    parser.add_argument("--markdown", default=None, help="write tables + pictures here")
    parser.add_argument("--json", default=None, help="write the raw numbers here")
    args = parser.parse_args(argv)
    results = run(args)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    if args.markdown:
        Path(args.markdown).write_text(markdown(results))
        print(f"\nwrote {args.markdown}")


if __name__ == "__main__":
    main()
