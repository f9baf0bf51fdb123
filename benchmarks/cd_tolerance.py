"""Which diffusion tolerance the convection–diffusion method needs: image change against error.

The rule (issue 35): stop the diffusion when more iterations would change the image by
less than a tenth of the method's measured error against ``path``. For each scene the
script renders

* a path-traced reference (unbiased, fixed seed; its own relative noise is printed, the
  floor under which no error can be read);
* the ``convection-diffusion`` method (physical model, every other option at its default)
  with the diffusion stopped at each tolerance of ``--tolerances``, and once at
  ``--converged`` (1e-7 by default: the image more iterations would give);

and prints per tolerance the outer iterations of the diffusion, the **image change**
``rel. RMSE(image(tol), image(converged))`` and its ratio to the method's **error**
``sqrt(rel. RMSE(image(converged), path)² - noise²)``, where ``rel. RMSE(a, b) =
sqrt(mean((a - b)²)) / sqrt(mean(b²))`` over all pixels and channels (radiance,
background excluded), as in ``benchmarks/accuracy.py``, and ``noise`` is the reference's
relative standard error: the squared error of a noisy reference is the method's squared
error plus the reference's variance, so the noise is taken out (which makes the error
smaller and the test stricter). A tolerance passes where the change is at most a tenth of the
error; the last line names the loosest tolerance that passes on every scene.

The first columns are cold renders (a fresh Volume: no light volume cached, so the
diffusion starts from zero, the case of a first image). The last ones are the render
after a transfer-function edit (every opacity times :data:`EDIT_OPACITY`) of a scene
solved to the same tolerance: the diffusion starts from the previous light (a warm
start, the interactive case), and its image is compared with a converged solve of the
edited scene. The rule takes the larger of the two changes. Kernels are compiled on a
tiny scene first.

Examples
--------
CPU, small (what ``docs/convection_diffusion_tolerance.md`` shows; minutes on 2 shared
cores)::

    python benchmarks/cd_tolerance.py --size 40 --image 64 --spp 1024

One scene, quicker::

    python benchmarks/cd_tolerance.py --scenes thin-plume --size 32 --image 64 --spp 256
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time
from pathlib import Path

import numpy as np

from vtkillum.core.convection_diffusion.solver import OPTIONS
from vtkillum.core.device import resolve_device
from vtkillum.core.render import render
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.data.accuracy_suite import SUITE, build

#: Scenes of :mod:`vtkillum.data.accuracy_suite`: thin and thick, g = 0 and g != 0, the
#: procedural plume, cloud and CT phantom.
SCENES = ["thin-plume", "thick-cloud", "cloud-point", "ct-layered"]
TOLERANCES = [1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 1e-5]
#: The share of the method's error that stopping early may cost (the issue's rule).
SHARE = 0.1
#: The transfer-function edit of the warm-start column: opacities times this.
EDIT_OPACITY = 0.7


def rel_rmse(image: np.ndarray, reference: np.ndarray) -> float:
    """``sqrt(mean((image - reference)²)) / sqrt(mean(reference²))``."""
    reference = reference.astype(np.float64)
    return float(np.sqrt(np.mean((image.astype(np.float64) - reference) ** 2))
                 / np.sqrt(np.mean(reference ** 2)))


def path_reference(name: str, n: int, image: int, spp: int, device: str,
                   cache: Path | None) -> tuple[np.ndarray, float]:
    """Path-traced radiance (seed 1) and its relative noise, cached as ``.npz`` when asked."""
    file = None
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        file = cache / f"{name}_n{n}_{image}px_{spp}spp.npz"
        if file.is_file():
            with np.load(file) as data:
                return data["radiance"], float(data["noise"])
    volume, scene = build(name, n)
    result = render(volume, scene, "path", image, image, device, spp=spp, seed=1)
    ref = result.radiance
    noise = float(np.sqrt(np.mean(result.info["radiance_variance"]))
                  / np.sqrt(np.mean(ref.astype(np.float64) ** 2)))
    if file is not None:
        np.savez_compressed(file, radiance=ref, noise=noise)
    return ref, noise


def edited(scene):
    """``scene`` after a transfer-function edit: every opacity times :data:`EDIT_OPACITY`."""
    tf = scene.transfer_function
    return dataclasses.replace(scene, transfer_function=TransferFunction(
        tf.scalars, np.asarray(tf.opacity) * EDIT_OPACITY, tf.colors))


def cd_image(name: str, n: int, image: int, device: str, tolerance: float,
             edit: bool = False):
    """``(radiance, outer iterations, converged, seconds)`` of a render at ``tolerance``:
    cold (a fresh volume), or with ``edit`` the render after a transfer-function edit
    (:func:`edited`) of a scene solved to ``tolerance`` before (a warm start)."""
    volume, scene = build(name, n)  # fresh: the light volume starts from zero
    if edit:
        render(volume, scene, "convection-diffusion", image, image, device,
               tolerance=tolerance)
        scene = edited(scene)
    start = time.perf_counter()
    result = render(volume, scene, "convection-diffusion", image, image, device,
                    tolerance=tolerance)
    seconds = time.perf_counter() - start
    stats = result.info.get("convection_diffusion", {})
    return result.radiance, stats.get("iterations"), stats.get("converged"), seconds


def converged_edit(name: str, n: int, image: int, device: str, tolerance: float):
    """The edited scene's image from a cold solve to ``tolerance``."""
    volume, scene = build(name, n)
    return render(volume, edited(scene), "convection-diffusion", image, image, device,
                  tolerance=tolerance).radiance


def run(args) -> dict:
    device = resolve_device(args.device)
    volume, scene = build("thin-plume", 12)  # compile the kernels
    render(volume, scene, "convection-diffusion", 8, 8, device)
    render(volume, scene, "path", 8, 8, device, spp=1)
    results = {}
    for name in args.scenes:
        ref, noise = path_reference(name, args.size, args.image, args.spp, device,
                                    Path(args.cache) if args.cache else None)
        converged, its, ok, secs = cd_image(name, args.size, args.image, device, args.converged)
        measured = rel_rmse(converged, ref)
        error = float(np.sqrt(max(measured ** 2 - noise ** 2, 0.0)))
        after_edit = converged_edit(name, args.size, args.image, device, args.converged)
        rows = []
        for tol in args.tolerances:
            img, it, reached, s = cd_image(name, args.size, args.image, device, tol)
            change = rel_rmse(img, converged)
            warm, warm_it, _, _ = cd_image(name, args.size, args.image, device, tol, edit=True)
            edit_change = rel_rmse(warm, after_edit)
            rows.append({"tolerance": tol, "iterations": it, "reached": reached,
                         "seconds": s, "change": change, "error": rel_rmse(img, ref),
                         "ratio": change / error, "edit_iterations": warm_it,
                         "edit_change": edit_change, "edit_ratio": edit_change / error})
        results[name] = {"noise": noise, "error": error, "measured": measured, "converged_iterations": its,
                         "converged_reached": ok, "converged_seconds": secs, "rows": rows}
        print_scene(name, results[name], args)
    print_choice(results, args)
    return results


def print_scene(name: str, r: dict, args) -> None:
    print(f"\n{name}: {SUITE[name].description}; {args.size} points, {args.image}^2 image; "
          f"path {args.spp} spp (noise {100 * r['noise']:.2f} %); converged solve: tolerance "
          f"{args.converged:g}, {r['converged_iterations']} outer iterations"
          f"{'' if r['converged_reached'] else ' (NOT reached: iteration cap)'}, "
          f"{r['converged_seconds']:.2f} s")
    print(f"method error against path (converged): {100 * r['measured']:.2f} % measured, "
          f"{100 * r['error']:.2f} % without the reference's noise")
    print("| tolerance | outer iterations | seconds | image change vs converged | "
          "change / error | measured error vs path | after an edit: iterations | "
          "image change | change / error |")
    print("|---|---|---|---|---|---|---|---|---|")
    for row in r["rows"]:
        mark = "" if row["ratio"] <= SHARE else " (> 1/10)"
        edit_mark = "" if row["edit_ratio"] <= SHARE else " (> 1/10)"
        cap = "" if row["reached"] else " (cap)"
        print(f"| {row['tolerance']:g} | {row['iterations']}{cap} | {row['seconds']:.2f} | "
              f"{100 * row['change']:.3f} % | {row['ratio']:.3f}{mark} | "
              f"{100 * row['error']:.2f} % | {row['edit_iterations']} | "
              f"{100 * row['edit_change']:.3f} % | {row['edit_ratio']:.3f}{edit_mark} |")


def print_choice(results: dict, args) -> None:
    def ratio(res, tol):  # the larger of the cold and the warm-start change, per error
        row = next(r for r in res["rows"] if r["tolerance"] == tol)
        return max(row["ratio"], row["edit_ratio"])

    passing = [tol for tol in args.tolerances
               if all(ratio(res, tol) <= SHARE for res in results.values())]
    # The loosest tolerance from which every tighter one passes too.
    choice = None
    for tol in sorted(args.tolerances):
        if tol in passing:
            choice = tol
        else:
            break
    worst = {tol: max(ratio(res, tol) for res in results.values()) for tol in args.tolerances}
    print("\nworst change / error over the scenes (first image or after an edit): "
          + ", ".join(f"{tol:g}: {worst[tol]:.3f}" for tol in args.tolerances))
    print(f"current default tolerance: {OPTIONS['tolerance']:g}; loosest tolerance whose image "
          f"change is at most {SHARE:g} of the error on every scene (and every tighter one's "
          f"too): {choice if choice is None else f'{choice:g}'}")
    print(f"({platform.processor() or platform.machine()}, device {args.device or 'default'})")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=SCENES, choices=sorted(SUITE))
    parser.add_argument("--size", type=int, default=40, help="volume points along the longest "
                        "axis")
    parser.add_argument("--image", type=int, default=64, help="image side, pixels")
    parser.add_argument("--spp", type=int, default=1024, help="reference samples per pixel")
    parser.add_argument("--tolerances", type=float, nargs="+", default=TOLERANCES)
    parser.add_argument("--converged", type=float, default=1e-7,
                        help="tolerance of the converged solve the changes are measured from")
    parser.add_argument("--device", default=None)
    parser.add_argument("--cache", default=None, help="directory for the path references")
    run(parser.parse_args(argv))


if __name__ == "__main__":
    main()
