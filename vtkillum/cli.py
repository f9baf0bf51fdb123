"""The ``vtkillum`` command line: render volumes with global illumination to PNG or numpy.

::

    vtkillum demo --output demo.png
    vtkillum render builtin:ct:96 --method single --size 512 512 --output ct.png
    vtkillum render head.nii.gz --scene head.json --method path --spp 256 --output head.npy
    vtkillum scene --dataset head.nii.gz --output head.json   # a starter scene to edit

User mistakes (missing files, bad scene fields, unknown methods or datasets, an output
that cannot be written, an image too large for the memory) print one line
``vtkillum: error: ...`` and exit with status 2; ``--debug`` shows the traceback.

The output is checked before rendering (a writable directory, no directory or dangling
link in the way of the picture or of the ``.alpha.npy`` file next to it) and written
to temporary files in the same directory that are renamed into place once all of them
are complete, so an interrupted or failed run never leaves a half-written file or a
radiance file paired with an old alpha file.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import stat
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# Headless VTK for the readers (no window is opened, but VTK may probe for one).
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")

#: Output extensions of ``render``/``demo``.
OUTPUT_FORMATS = (".png", ".npy", ".npz")

#: Largest image side accepted (a sanity limit against typos such as 40960).
MAX_SIDE = 16384

#: Bytes per pixel a render needs at its peak (device buffers, their host copies and the
#: written output; measured on the CPU: ~36 for the ray casters, ~92 for one path-traced
#: sample per pass, with headroom).
BYTES_PER_PIXEL = {"path": 160}
DEFAULT_BYTES_PER_PIXEL = 64
#: Memory kept in reserve beyond the estimate (light volumes, tables, libraries).
MEMORY_RESERVE = 256 << 20

#: Suffix of the alpha file written next to a ``.npy`` output.
ALPHA_SUFFIX = ".alpha"

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
    except (UserError, ValueError, OSError) as err:  # OSError: files (missing, unreadable, ...)
        if args.debug:
            raise
        print(f"vtkillum: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except MemoryError as err:
        if args.debug:
            raise
        print(f"vtkillum: error: out of memory ({_one_line(err)}); try a smaller --size or "
              "volume", file=sys.stderr)
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
    from vtkillum.core.device import resolve_device
    from vtkillum.core.render import method_function, render

    outputs = check_output(args.output, OUTPUT_FORMATS)
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
    device = resolve_device(args.device)

    volume, scene = load_input(args.input, args.scene, args.array, args.component)
    check_memory(args.method, width, height, device, volume)
    start = time.perf_counter()
    try:
        with _progress_bar(args.quiet, f"{args.method} {width}x{height}") as progress:
            result = render(volume, scene, args.method, width, height, device, progress,
                            **options)
    except ValueError as err:
        if args.scene is None or str(err).startswith(str(args.scene)):
            raise
        # Options from the scene file are checked by the method: say where they came from.
        raise ValueError(f"{err} (scene file {args.scene})") from err
    elapsed = time.perf_counter() - start
    written = write_result(outputs[0], result, scene.background, exposure)
    if not args.quiet:
        print(f"wrote {', '.join(str(p) for p in written)} ({width}x{height}, {args.method}, "
              f"{result.info.get('device', device)}, {elapsed:.1f} s)")
    return 0


def run_scene(args) -> int:
    from vtkillum.core.scene import scene_json

    (output,) = check_output(args.output, (".json",))
    volume, scene = load_input(args.dataset, None, args.array, args.component)
    data = explicit_scene(scene, volume)
    text = scene_json(data).encode()
    write_atomically([(output, lambda f: f.write(text))])
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
        optics=scene.optics,
    )


def write_result(output: Path, result, background, exposure) -> list[Path]:
    """Write a :class:`RenderResult` as .png/.npy/.npz (see ``OUTPUT_HELP``); returns the paths.

    The extension is matched case-insensitively and the name is kept as given (``UP.NPY``
    writes ``UP.NPY`` and ``UP.alpha.NPY``). All files are written to temporary files in
    their directories and renamed into place together (:func:`write_atomically`).
    """
    from vtkillum.core.tonemap import auto_exposure, tonemap, write_png

    output = Path(output)
    radiance = np.asarray(result.radiance, dtype=np.float32)
    alpha = np.asarray(result.alpha, dtype=np.float32)
    suffix = output.suffix.lower()
    if suffix == ".png":
        if exposure == "auto":
            exposure = auto_exposure(radiance, alpha=alpha, background=background)
        rgb8 = tonemap(radiance, alpha, background, exposure)
        return write_atomically([(output, lambda f: write_png(f, rgb8))])
    if suffix == ".npy":
        return write_atomically([(output, lambda f: np.save(f, radiance)),
                                 (alpha_path(output), lambda f: np.save(f, alpha))])
    bg = np.asarray(background, dtype=np.float32)
    return write_atomically([(output, lambda f: np.savez(f, radiance=radiance, alpha=alpha,
                                                         background=bg))])


def alpha_path(output) -> Path:
    """The alpha file next to a ``.npy`` output: ``name.npy`` -> ``name.alpha.npy`` (case kept)."""
    output = Path(output)
    return output.with_name(output.stem + ALPHA_SUFFIX + output.suffix)


def output_files(output) -> list[Path]:
    """Every file a render to ``output`` writes: the output, and its alpha file for .npy."""
    output = Path(output)
    return [output, alpha_path(output)] if output.suffix.lower() == ".npy" else [output]


def check_output(path, allowed) -> list[Path]:
    """Validate an output name before any work; returns :func:`output_files`.

    Checks the extension (case-insensitive), that no output name is another's alpha
    file, and for each file that its directory exists and takes new files, that no
    directory, dangling symbolic link or other non-file is in the way, and that an
    existing file may be overwritten. Raises :class:`UserError` naming the file.
    """
    out = Path(path)
    if out.suffix.lower() not in allowed:
        raise UserError(f"output {str(path)!r}: the extension must be one of "
                        f"{', '.join(allowed)}")
    if out.name.lower().endswith(ALPHA_SUFFIX + ".npy") and ".npy" in allowed:
        raise UserError(f"output {str(path)!r}: names ending in {ALPHA_SUFFIX}.npy are the alpha "
                        f"files of .npy outputs ({out.name[:-len(ALPHA_SUFFIX + '.npy')]}.npy "
                        "writes its alpha there); choose another name")
    files = output_files(out)
    for n, target in enumerate(files):
        role = "output" if n == 0 else f"alpha file {str(target)!r} of output"
        _check_target(target, f"{role} {str(path)!r}" if n else f"output {str(path)!r}")
    if len({os.path.realpath(f) for f in files}) < len(files):  # e.g. a link between them
        raise UserError(f"output {str(path)!r}: the radiance and alpha files "
                        f"{', '.join(map(str, files))} are the same file")
    return files


def _check_target(target: Path, what: str) -> None:
    real = target
    if target.is_symlink():
        real = Path(os.path.realpath(target))
        if not real.exists():
            raise UserError(f"{what}: {target} is a dangling symbolic link (to "
                            f"{os.readlink(target)}); remove it or choose another name")
    if real.is_dir():
        raise UserError(f"{what}: {target} is a directory; give a file name (or remove the "
                        "directory)")
    if real.exists() and not real.is_file():
        raise UserError(f"{what}: {target} exists and is not a regular file")
    if real.exists() and not os.access(real, os.W_OK):
        raise UserError(f"{what}: {target} exists and is read-only")
    parent = real.parent
    if not parent.exists():
        raise UserError(f"{what}: the directory {parent} does not exist")
    if not parent.is_dir():
        raise UserError(f"{what}: {parent} is not a directory")
    try:  # the real test: can a file be created there (read-only file systems, ACLs)?
        with tempfile.NamedTemporaryFile(dir=parent, prefix=f".{real.name}.", suffix=".tmp"):
            pass
    except OSError as err:
        raise UserError(f"{what}: cannot write to the directory {parent} "
                        f"({err.strerror or err})") from None


def write_atomically(jobs) -> list[Path]:
    """Write files all-or-nothing: ``jobs`` is a list of ``(path, write(binary_file))``.

    Each file is written to a temporary file in its own directory; only when every one is
    complete are they renamed into place (``os.replace``), so a failure or Ctrl-C while
    writing leaves the old files untouched. A symbolic link is written through (its
    target is replaced), like ``cp``. New files get the usual permissions (0666 less the
    umask); a replaced file keeps its own. Returns the paths as given.
    """
    staged = []
    try:
        for path, write in jobs:
            final = Path(os.path.realpath(path)) if Path(path).is_symlink() else Path(path)
            fd, tmp = tempfile.mkstemp(dir=final.parent, prefix=f".{final.name}.",
                                       suffix=".tmp")
            staged.append((tmp, final))
            with os.fdopen(fd, "wb") as f:
                write(f)
            os.chmod(tmp, _file_mode(final))
        for tmp, final in staged:
            os.replace(tmp, final)
    finally:
        for tmp, _ in staged:
            if os.path.lexists(tmp):
                os.unlink(tmp)
    return [Path(path) for path, _ in jobs]


def _file_mode(path: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def check_memory(method: str, width: int, height: int, device: str, volume=None) -> None:
    """Refuse an image that cannot fit in memory, before rendering it.

    The need is :data:`BYTES_PER_PIXEL` of ``method`` per pixel plus
    :data:`MEMORY_RESERVE` and 16 bytes per voxel (light volumes), compared with
    :func:`vtkillum.core.device.available_memory` (host, and the GPU's free memory for a
    CUDA device). The error names the largest size of the same aspect ratio that fits.
    """
    from vtkillum.core.device import available_memory

    per_pixel = BYTES_PER_PIXEL.get(method, DEFAULT_BYTES_PER_PIXEL)
    fixed = MEMORY_RESERVE + (16 * int(np.prod(volume.dims)) if volume is not None else 0)
    need = per_pixel * width * height + fixed
    host, gpu = available_memory(device)
    for where, have in (("memory", host), (f"{device} memory", gpu)):
        if have is None or need <= have:
            continue
        scale = np.sqrt(max(have - fixed, 0) / (per_pixel * width * height))
        w, h = int(width * scale), int(height * scale)
        fits = (f"the largest image of this shape that fits is about --size {w} {h}"
                if w >= 1 and h >= 1 else "not even a tiny image fits")
        raise UserError(f"--size {width} {height}: the {method!r} render needs about "
                        f"{_gigabytes(need)} of {where}, {_gigabytes(have)} is available; "
                        f"{fits}")


def _gigabytes(n: int) -> str:
    return f"{n / 2**30:.1f} GB" if n >= 2**30 else f"{n / 2**20:.0f} MB"


# --- helpers --------------------------------------------------------------------------------------
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
