"""Regenerate the reference images of ``test_reference_images.py`` (on the CPU).

Run from the repository root::

    python tests/rendering/make_references.py                 # every case
    python tests/rendering/make_references.py single-plume    # only some cases
    python tests/rendering/make_references.py --montage /tmp/refs.png   # also a montage

For every case in :data:`CASES` it renders the procedural dataset with its
``default_scene`` (plus the few edits listed in the case) on ``cpu`` and writes
into ``tests/rendering/references/``:

``<case>.npz``
    ``radiance`` (H, W, 3) and ``alpha`` (H, W) as float16 (linear), for ``path``
    also ``radiance_std`` (H, W, 3) float16, the Monte-Carlo standard error of each
    pixel's mean; ``case`` (the case as JSON) and ``device``.
``<case>.png``
    The tone-mapped picture for humans: :func:`vtkillum.core.tonemap.tonemap` of
    the radiance over the scene's background, gamma 2.2, with the exposure of
    :func:`png_exposure` (a power of two, stored as ``exposure`` in the npz and
    printed in the table; the methods' brightness differs up to 20-fold).

and prints a table of the images with their mean and max. Look at the PNGs (or
the montage) before committing new references. The test module imports the case
table and the render function from here, so a test renders exactly what this
script stored.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from vtkillum.core.render import RenderResult, render
from vtkillum.core.tonemap import tonemap, write_png
from vtkillum.data.procedural import cornell_box, ct_phantom, default_scene, smoke_plume

#: Where the references live (next to this script).
REFERENCE_DIR = Path(__file__).resolve().parent / "references"

#: Brightest exposure of the PNGs (the default scenes are lit for 1 with ``single``).
MAX_EXPOSURE = 1.0

#: The procedural datasets at the small sizes the tests use.
DATASETS = {
    "plume": lambda: smoke_plume((32, 32, 48)),
    "ct": lambda: ct_phantom(40),
    "cornell": lambda: cornell_box(32),
}

@dataclass(frozen=True)
class Case:
    """One reference image.

    Attributes
    ----------
    method : str
        A method of :data:`vtkillum.core.render.METHODS`.
    dataset : str
        A key of :data:`DATASETS`.
    size : int
        Width and height in pixels.
    options : dict
        Keyword options of the render call (``spp``, ``seed``, ...).
    albedo : float or None
        Replaces the scene's albedo when given.
    zoom : float
        The camera moves ``zoom`` times closer to its focal point.
    """

    method: str
    dataset: str
    size: int = 64
    options: dict = field(default_factory=dict)
    albedo: float | None = None
    zoom: float = 1.0

    @property
    def name(self) -> str:
        return f"{self.method}-{self.dataset}"


def _cases() -> dict[str, Case]:
    cases = []
    for method in ("emission", "single", "transmittance", "convection-diffusion"):
        cases += [Case(method, "plume"), Case(method, "ct", zoom=1.4), Case(method, "cornell")]
    # The shipped preintegration table is for albedo 0.9 (the plume's 0.95 would generate
    # one on demand, ~30 s); the plume keeps its g = 0.3, which the other two lack.
    cases += [Case("ambient-scattering", "plume", albedo=0.9),
              Case("ambient-scattering", "ct", zoom=1.4),
              Case("ambient-scattering", "cornell")]
    # Path tracing: few samples (the test's tolerance comes from their own noise, so the
    # PNGs are noisy), fixed seed; 48x48 keeps the three at about 4 s on one CPU core.
    path = {"spp": 64, "seed": 7}  # unbiased: no bounce limit
    cases += [Case("path", "plume", 48, path),
              Case("path", "ct", 48, path, zoom=1.4),
              Case("path", "cornell", 48, path)]
    return {c.name: c for c in cases}


#: Case name -> :class:`Case`.
CASES: dict[str, Case] = _cases()


def build(case: Case):
    """The volume and scene of ``case`` (the dataset's ``default_scene`` plus its edits)."""
    from vtkillum.core.camera import Camera

    volume = DATASETS[case.dataset]()
    scene = default_scene(case.dataset, volume)
    if case.albedo is not None:
        scene.albedo = float(case.albedo)
    if case.zoom != 1.0:
        cam = scene.resolved_camera(volume)
        position = cam.focal_point + (cam.position - cam.focal_point) / case.zoom
        scene.camera = Camera(position, cam.focal_point, cam.view_up, cam.view_angle)
    return volume, scene


def render_case(case: Case, device: str = "cpu", volume=None, scene=None) -> RenderResult:
    """Render ``case`` on ``device`` (``volume``/``scene`` override :func:`build`'s)."""
    if volume is None or scene is None:
        v, s = build(case)
        volume = v if volume is None else volume
        scene = s if scene is None else scene
    return render(volume, scene, case.method, case.size, case.size, device, **case.options)


def radiance_std(result: RenderResult) -> np.ndarray | None:
    """Per-pixel Monte-Carlo standard error of a path-traced image (None for other methods)."""
    var = result.info.get("radiance_variance")
    return None if var is None else np.sqrt(np.asarray(var, dtype=np.float64))


def png_exposure(radiance) -> float:
    """The largest power of two <= :data:`MAX_EXPOSURE` that keeps the 99th percentile <= 1."""
    peak = float(np.percentile(np.asarray(radiance, dtype=np.float64), 99.0))
    if not peak > 0:
        return MAX_EXPOSURE
    return float(min(MAX_EXPOSURE, 2.0 ** np.floor(np.log2(1.0 / peak))))


def to_png(radiance, alpha, background, exposure: float) -> np.ndarray:
    """The 8-bit picture of an image (see the module docstring)."""
    return tonemap(radiance, alpha, background, exposure)


def save_reference(name: str, result: RenderResult, background, directory=REFERENCE_DIR,
                   device: str = "cpu", exposure: float | None = None) -> tuple[Path, Path]:
    """Write ``<name>.npz`` and ``<name>.png`` into ``directory``; return both paths.

    ``exposure`` defaults to :func:`png_exposure` of the radiance.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    if exposure is None:
        exposure = png_exposure(result.radiance)
    arrays = {"radiance": result.radiance.astype(np.float16),
              "alpha": result.alpha.astype(np.float16),
              "exposure": np.array(exposure),
              "case": np.array(json.dumps(asdict(CASES[name])) if name in CASES else name),
              "device": np.array(device)}
    std = radiance_std(result)
    if std is not None:
        arrays["radiance_std"] = std.astype(np.float16)
    npz = directory / f"{name}.npz"
    np.savez_compressed(npz, **arrays)
    png = directory / f"{name}.png"
    write_png(png, to_png(result.radiance, result.alpha, background, exposure))
    return npz, png


def load_reference(name: str, directory=REFERENCE_DIR) -> dict:
    """``<name>.npz``: ``radiance``, ``alpha`` (maybe ``radiance_std``) as float64, ``exposure``."""
    path = Path(directory) / f"{name}.npz"
    if not path.exists():
        raise FileNotFoundError(
            f"reference {path} is missing; regenerate it with "
            f"python tests/rendering/make_references.py {name}"
        )
    with np.load(path) as data:
        out = {k: data[k].astype(np.float64) for k in ("radiance", "alpha", "radiance_std")
               if k in data}
        out["case"] = json.loads(str(data["case"]))
        out["exposure"] = float(data["exposure"])
    return out


def montage(pictures: list[tuple[str, np.ndarray]], path, columns: int = 3, zoom: int = 3):
    """Write the labelled pictures side by side (enlarged ``zoom`` times) as one PNG."""
    from PIL import Image, ImageDraw

    cell = max(p.shape[0] for _, p in pictures) * zoom
    rows = -(-len(pictures) // columns)
    canvas = Image.new("RGB", (columns * cell, rows * (cell + 14)), (60, 0, 60))
    draw = ImageDraw.Draw(canvas)
    for i, (label, picture) in enumerate(pictures):
        x, y = (i % columns) * cell, (i // columns) * (cell + 14)
        big = Image.fromarray(picture).resize((picture.shape[1] * zoom, picture.shape[0] * zoom),
                                              Image.NEAREST)
        canvas.paste(big, (x, y + 14))
        draw.text((x + 2, y + 1), label, fill=(255, 255, 255))
    canvas.save(path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", help=f"case names (default: all of {list(CASES)})")
    parser.add_argument("--out", default=str(REFERENCE_DIR), help="output folder")
    parser.add_argument("--montage", help="also write a montage of the PNGs to this path")
    args = parser.parse_args(argv)
    unknown = [c for c in args.cases if c not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {list(CASES)}")
    pictures = []
    print(f"{'image':28s} {'size':>7s} {'mean':>9s} {'max':>9s} {'alpha':>6s} {'exposure':>8s} "
          f"{'bytes':>7s}")
    for name in args.cases or list(CASES):
        case = CASES[name]
        volume, scene = build(case)
        result = render_case(case, "cpu", volume, scene)
        exposure = png_exposure(result.radiance)
        npz, png = save_reference(name, result, scene.background, args.out, exposure=exposure)
        pictures.append((f"{name} x{exposure:g}",
                         to_png(result.radiance, result.alpha, scene.background, exposure)))
        size = npz.stat().st_size + png.stat().st_size
        print(f"{name:28s} {case.size:>3d}x{case.size:<3d} {result.radiance.mean():9.4f} "
              f"{result.radiance.max():9.3f} {result.alpha.mean():6.3f} {exposure:8.4g} "
              f"{size:7d}", flush=True)
    total = sum(p.stat().st_size for p in Path(args.out).iterdir())
    print(f"references folder: {total / 1024:.0f} KiB")
    if args.montage:
        montage(pictures, args.montage)
        print(f"montage: {args.montage}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
