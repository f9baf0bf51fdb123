"""The ``vtkillum`` command line: render volumes with global illumination to PNG or numpy.

::

    vtkillum demo --output demo.png
    vtkillum render builtin:ct:96 --method single --size 512 512 --output ct.png
    vtkillum render head.nii.gz --scene head.json --method path --spp 256 --output head.npy
    vtkillum scene --dataset head.nii.gz --output head.json   # a starter scene to edit

User mistakes (missing files, bad scene fields, unknown methods or datasets) print one
line ``vtkillum: error: ...`` and exit with status 2; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

# Headless VTK for the readers (no window is opened, but VTK may probe for one).
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")

#: Output extensions of ``render``/``demo``.
OUTPUT_FORMATS = (".png", ".npy", ".npz")

#: Largest image side accepted (a sanity limit against typos such as 40960).
MAX_SIDE = 16384

DEMO_DATASET = "builtin:plume"

OUTPUT_HELP = """\
output formats (by extension):
  .png  8-bit RGB picture: the linear radiance L composited over the scene
        background (L + (1 - alpha) * background), multiplied by the exposure,
        clipped to [0, 1] and raised to 1/2.2 (gamma 2.2), see vtkillum.core.tonemap.
  .npy  linear radiance, float32 array (H, W, 3), row 0 at the top, background NOT
        included; alpha (1 - transmittance, float32 (H, W)) goes to a second file
        next to it, <name>.alpha.npy, so that any background can be composited later.
  .npz  both in one file: arrays 'radiance' (H, W, 3), 'alpha' (H, W) and
        'background' (3,).
"""


class UserError(Exception):
    """A mistake in the command line or its inputs: reported in one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors in one line (and raises instead of exiting)."""

    def error(self, message):
        raise UserError(f"{self.prog}: {message} (see '{self.prog} --help')")


# --- entry point --------------------------------------------------------------------------------
def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 user error)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UserError as err:
        print(f"vtkillum: error: {err}", file=sys.stderr)
        return 2
    except SystemExit as exit_:  # --help, --version
        return int(exit_.code or 0)
    if args.command is None:
        parser.print_help()
        return 2
    _quiet_libraries()
    try:
        return args.run(args)
    except (UserError, ValueError, FileNotFoundError, IsADirectoryError, PermissionError) as err:
        if args.debug:
            raise
        print(f"vtkillum: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("vtkillum: interrupted", file=sys.stderr)
        return 130


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (methods are read from the render registry at call time)."""
    from vtkillum import __version__
    from vtkillum.core.render import METHODS

    methods = sorted(METHODS)
    parser = _Parser(
        prog="vtkillum",
        description="Global illumination for direct volume rendering.",
        epilog="Run 'vtkillum COMMAND --help' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"vtkillum {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    parser.set_defaults(command=None, debug=False)
    sub = parser.add_subparsers(title="commands", dest="command", parser_class=_Parser)

    # demo
    demo = sub.add_parser(
        "demo", help="render a built-in dataset with its recommended scene",
        description="Render a procedural dataset with shadows and scattering (the 'single' "
                    "method by default) and write a picture.",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=OUTPUT_HELP,
    )
    demo.add_argument("--output", "-o", default="demo.png", help="output file (default demo.png)")
    demo.add_argument("--dataset", default=DEMO_DATASET,
                      help=f"builtin:NAME[:SIZE] (default {DEMO_DATASET}); " + _builtin_names())
    _add_render_options(demo, methods, default_method="single", default_size=(384, 384))
    demo.set_defaults(run=run_demo)

    # render
    render = sub.add_parser(
        "render", help="render a volume file or built-in dataset",
        description="Render INPUT (a volume file or builtin:NAME[:SIZE]) with a scene file "
                    "(default: the dataset's recommended scene, or a generic one for files).",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=OUTPUT_HELP,
    )
    render.add_argument("input", help="volume file (.vti .vtk .nrrd .nhdr .mha .mhd .nii "
                                      ".nii.gz), DICOM directory, or builtin:NAME[:SIZE]")
    render.add_argument("--output", "-o", required=True, help="output .png, .npy or .npz")
    render.add_argument("--scene", "-s", help="scene JSON file (see 'vtkillum scene')")
    _add_input_options(render)
    _add_render_options(render, methods, default_method="single", default_size=(512, 512))
    render.set_defaults(run=run_render)

    # scene
    scene = sub.add_parser(
        "scene", help="write a starter scene file for a dataset",
        description="Write the scene a render of DATASET would use by default, with every "
                    "data-dependent default (transfer function, unit distance, camera) spelt "
                    "out, ready to edit.",
    )
    scene.add_argument("--dataset", "-d", required=True,
                       help="volume file, DICOM directory or builtin:NAME[:SIZE]")
    scene.add_argument("--output", "-o", required=True, help="scene JSON file to write")
    _add_input_options(scene)
    scene.set_defaults(run=run_scene)
    return parser


def _add_input_options(parser) -> None:
    parser.add_argument("--array", help="data array to render (default: the active scalars)")
    parser.add_argument("--component", help="component of a multi-component array: an index "
                                            "or 'magnitude'")


def _add_render_options(parser, methods, default_method: str, default_size) -> None:
    parser.add_argument("--method", "-m", default=default_method, choices=methods,
                        metavar="METHOD",
                        help=f"rendering method, one of: {', '.join(methods)} "
                             f"(default {default_method})")
    parser.add_argument("--size", nargs=2, type=int, metavar=("W", "H"),
                        default=list(default_size),
                        help="image width and height in pixels (default "
                             f"{default_size[0]} {default_size[1]})")
    parser.add_argument("--device", default=None,
                        help="warp device: cpu, cuda, cuda:N (default: CUDA when present; the "
                             "VTKILLUM_DEVICE environment variable overrides)")
    parser.add_argument("--spp", type=int, help="samples per pixel (methods that take them, "
                                                "e.g. path); default from the scene file")
    parser.add_argument("--exposure", default="1",
                        help="PNG exposure: a positive factor, or 'auto' (the 99.5th "
                             "percentile of the radiance maps to white); default 1")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="extra method option, VALUE in JSON (e.g. step_size=0.5, "
                             "jitter=false); repeatable")
    parser.add_argument("--quiet", "-q", action="store_true",
                        help="no progress bar or summary line")


# --- commands -----------------------------------------------------------------------------------
def run_demo(args) -> int:
    from vtkillum.data.builtin import is_builtin

    if not is_builtin(args.dataset):
        raise UserError(f"demo --dataset must be builtin:NAME[:SIZE]; {_builtin_names()}")
    args.input, args.scene, args.array, args.component = args.dataset, None, None, None
    return run_render(args)


def run_render(args) -> int:
    from vtkillum.core.render import method_function, render

    output = _check_output(args.output, OUTPUT_FORMATS)
    width, height = _check_size(args.size)
    exposure = _parse_exposure(args.exposure)
    options = _parse_options(args.option)
    fn = method_function(args.method)
    if args.spp is not None:
        if args.spp < 1:
            raise UserError(f"--spp must be a positive integer, got {args.spp}")
        if "spp" not in inspect.signature(fn).parameters:
            raise UserError(f"--spp does not apply to the {args.method!r} method (it takes no "
                            "samples per pixel; the path method does)")
        options["spp"] = args.spp

    volume, scene = load_input(args.input, args.scene, args.array, args.component)
    start = time.perf_counter()
    with _progress_bar(args.quiet, f"{args.method} {width}x{height}") as progress:
        result = render(volume, scene, args.method, width, height, args.device, progress,
                        **options)
    elapsed = time.perf_counter() - start
    written = write_result(output, result, scene.background, exposure)
    if not args.quiet:
        print(f"wrote {', '.join(str(p) for p in written)} ({width}x{height}, {args.method}, "
              f"{result.info.get('device', args.device or 'default device')}, {elapsed:.1f} s)")
    return 0


def run_scene(args) -> int:
    from vtkillum.core.scene import save_scene

    output = _check_output(args.output, (".json",))
    volume, scene = load_input(args.dataset, None, args.array, args.component)
    save_scene(explicit_scene(scene, volume), output)
    print(f"wrote {output}")
    return 0


# --- building blocks (usable from Python too) -----------------------------------------------------
def load_input(spec, scene_path=None, array=None, component=None):
    """Load ``spec`` (file or ``builtin:...``) and its scene.

    Returns ``(volume, scene)``: the scene from ``scene_path`` when given, else the
    built-in dataset's recommended scene, else the generic :class:`Scene` defaults.
    """
    from vtkillum.core.scene import Scene, load_scene
    from vtkillum.data.builtin import builtin_scene, is_builtin, load_builtin

    if is_builtin(spec):
        if array is not None or component is not None:
            raise UserError("--array and --component apply to files, not built-in datasets")
        volume = load_builtin(spec)
        scene = load_scene(scene_path) if scene_path else builtin_scene(spec, volume)
        return volume, scene
    from vtkillum.io.readers import read_volume

    volume = read_volume(spec, array=array, component=_parse_component(component))
    scene = load_scene(scene_path) if scene_path else Scene()
    return volume, scene


def explicit_scene(scene, volume):
    """``scene`` with its data-dependent defaults resolved for ``volume`` (for editing)."""
    from vtkillum.core.scene import Scene

    return Scene(
        transfer_function=scene.resolved_transfer_function(volume),
        opacity_unit_distance=scene.resolved_unit_distance(volume),
        albedo=scene.albedo,
        anisotropy=scene.anisotropy,
        lights=scene.lights,
        camera=scene.resolved_camera(volume),
        background=scene.background,
        step_size=scene.step_size,
        shading=scene.shading,
        options=scene.options,
    )


def write_result(output: Path, result, background, exposure) -> list[Path]:
    """Write a :class:`RenderResult` as .png/.npy/.npz (see ``OUTPUT_HELP``); returns the paths."""
    from vtkillum.core.tonemap import auto_exposure, tonemap, write_png

    radiance = np.asarray(result.radiance, dtype=np.float32)
    alpha = np.asarray(result.alpha, dtype=np.float32)
    suffix = output.suffix.lower()
    if suffix == ".png":
        if exposure == "auto":
            exposure = auto_exposure(result.composite(background))
        write_png(output, tonemap(radiance, alpha, background, exposure))
        return [output]
    if suffix == ".npy":
        alpha_path = output.with_name(output.name[: -len(".npy")] + ".alpha.npy")
        np.save(output, radiance)
        np.save(alpha_path, alpha)
        return [output, alpha_path]
    np.savez(output, radiance=radiance, alpha=alpha,
             background=np.asarray(background, dtype=np.float32))
    return [output]


# --- helpers --------------------------------------------------------------------------------------
def _check_output(path, allowed) -> Path:
    out = Path(path)
    if out.suffix.lower() not in allowed:
        raise UserError(f"output {path!r}: the extension must be one of {', '.join(allowed)}")
    if not out.parent.exists():
        raise UserError(f"output {path!r}: the directory {out.parent} does not exist")
    if out.is_dir():
        raise UserError(f"output {path!r} is a directory; give a file name")
    return out


def _check_size(size) -> tuple[int, int]:
    width, height = size
    if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
        raise UserError(f"--size {width} {height}: width and height must be integers in "
                        f"[1, {MAX_SIDE}]")
    return width, height


def _parse_exposure(text: str):
    if str(text).lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise UserError(f"--exposure must be a positive number or 'auto', got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise UserError(f"--exposure must be a positive number or 'auto', got {text!r}")
    return value


def _parse_component(text):
    if text is None or text == "magnitude":
        return text
    try:
        return int(text)
    except ValueError:
        raise UserError(f"--component must be an index or 'magnitude', got {text!r}") from None


def _parse_options(items) -> dict:
    options = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--option {item!r}: expected KEY=VALUE, e.g. step_size=0.5")
        try:
            options[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            options[key.strip()] = value  # a bare string such as a name
    return options


class _progress_bar:
    """Context manager yielding a ``progress(fraction)`` callback drawing a tqdm bar.

    The bar goes to ``stream`` (default stderr, where it is drawn only on a terminal:
    tqdm's ``disable=None``) and is never drawn with ``--quiet``.
    """

    def __init__(self, quiet: bool, description: str, stream=None):
        self.quiet, self.description, self.stream, self.bar = quiet, description, stream, None

    def __enter__(self):
        if self.quiet:
            return None
        from tqdm import tqdm

        self.bar = tqdm(total=100, desc=self.description, unit="%", file=self.stream,
                        disable=None if self.stream is None else False, leave=False,
                        bar_format="{l_bar}{bar}| {elapsed}<{remaining}")

        def progress(fraction: float) -> None:
            target = int(round(100 * min(max(float(fraction), 0.0), 1.0)))
            if target > self.bar.n:
                self.bar.update(target - self.bar.n)

        return progress

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.close()
        return False


def _builtin_names() -> str:
    from vtkillum.data.builtin import available

    return f"built-in datasets: {available()}"


def _one_line(err: BaseException) -> str:
    text = str(err).strip() or type(err).__name__
    return " ".join(text.split())


def _quiet_libraries() -> None:
    """Keep library chatter (warp's banner, VTK's own error log) off the terminal.

    Errors that matter reach the user as exceptions, reported in one line.
    """
    from vtkillum.core.device import init_warp

    init_warp()
    try:
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    except ImportError:
        pass


if __name__ == "__main__":
    sys.exit(main())
