"""The ``vtkillum`` command line: render volumes with global illumination to PNG or numpy.

::

    vtkillum demo --output demo.png
    vtkillum export builtin:ct -o head.nii.gz        # a built-in dataset as a file
    vtkillum render head.nii.gz --output head.png     # data-aware defaults, auto exposure
    vtkillum render builtin:ct:96 --method single --size 512 512 --output ct.png
    vtkillum render head.nii.gz --scene head.json --method path --spp 256 --output head.npy
    vtkillum render functional.nii --output frames.png     # every time step: frames_0000.png ...
    vtkillum render 'step_*.vti' --output movie.gif        # a file series (or .pvd) as animation
    vtkillum scene --dataset head.nii.gz --output head.json   # a starter scene to edit
    vtkillum info                                     # version, devices, tables

Without a scene file (or where it gives none) a file is rendered with the data-aware
defaults of :mod:`vtkillum.core.defaults`: a transfer function from the histogram, a
camera that respects the image's orientation (an anterior view, superior up, for
medical formats) and one key light from the upper front-left. PNG output is exposed
automatically unless ``--exposure`` gives a factor.

User mistakes (missing files, bad scene fields, unknown methods or datasets, an output
that cannot be written, an image too large for the memory, a full disk) print one line
``vtkillum: error: ...`` and exit with status 2; ``--debug`` shows the traceback. A
message quotes at most a few hundred characters of what was typed.

The output is checked before rendering (a writable directory, no directory or dangling
link in the way of the picture or of the ``.alpha.npy`` file next to it) and written
under its final names in a hidden directory next to it, renamed into place once all
files are complete (:mod:`vtkillum.io.writers`): an interrupted or failed run (Ctrl-C,
SIGTERM, SIGHUP, a full disk) never leaves a half-written file, a hidden temporary or a
radiance file paired with an old alpha file, and an exported ``ct.mhd`` names its final
``ct.raw``.

Signals: Ctrl-C (SIGINT) exits with status 130. During a ``path`` render SIGINT, SIGTERM
(what ``timeout`` and batch schedulers send) and SIGHUP stop after the pass under way and
write the image of the samples taken so far (exit status 130, 143, 129); a second one
stops at once. While files are written SIGTERM and SIGHUP remove the partial files and
exit with 143 / 129, the old output kept.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vtkillum.core.defaults import default_image_size
from vtkillum.core.denoise import RequireDenoiser
from vtkillum.core.denoise import for_output as denoised_for_output
from vtkillum.io.writers import (  # noqa: F401  (write_atomically, write_volume: public here too)
    TERMINATING_SIGNALS,
    VOLUME_FORMATS,
    Terminated,
    signals_held,
    volume_files,
    write_atomically,
    write_volume,
)
from vtkillum.progress import PROGRESS_INTERVAL  # noqa: F401  (documented here too)
from vtkillum.progress import ProgressReporter as _progress_bar
from vtkillum.progress import duration as _duration

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

#: Methods the command line offers (``illumination`` needs an illumination volume, which
#: only the Python API can hand over).
HIDDEN_METHODS = ("illumination",)

#: A ``path`` render whose first pass predicts more than this many seconds prints its
#: estimate before going on.
LONG_RENDER_SECONDS = 10.0

#: Steps of a time series read ahead of the one rendering (``--prefetch``).
DEFAULT_PREFETCH = 1

#: Methods whose render hashes the volume's data (:attr:`Volume.content_key`): the
#: prefetch thread computes the hash after the read (:func:`render_preparation`).
CONTENT_KEYED_METHODS = ("convection-diffusion", "refraction")

#: Output formats of ``export``.
EXPORT_FORMATS = VOLUME_FORMATS

#: Longest integer accepted on the command line, in digits (Python refuses to convert
#: more than 4300, with a message about its own limits).
MAX_INTEGER_DIGITS = 30

OUTPUT_HELP = """\
output formats (by extension):
  .png  8-bit RGB picture: the linear radiance L composited over the scene
        background (L + (1 - alpha) * background), multiplied by the exposure,
        clipped to [0, 1] and raised to 1/2.2 (gamma 2.2), see vtkillum.core.tonemap.
        The exposure is automatic by default (--exposure auto: the 99.5th
        percentile of the pixels the volume covers becomes white); give a
        factor (e.g. --exposure 1) for the same scaling in every picture.
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
        print(f"vtkillum: error: {_one_line(err)}", file=sys.stderr)
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
    except Terminated as stop:  # SIGTERM/SIGHUP while writing: partial files removed
        _report(f"vtkillum: terminated ({stop.name}); nothing more was written")
        return stop.code


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (methods are read from the render registry at call time)."""
    from vtkillum import __version__
    from vtkillum.core.render import METHODS

    methods = sorted(m for m in METHODS if m not in HIDDEN_METHODS)
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
    _add_render_options(demo, methods, default_method="single")
    demo.set_defaults(run=run_demo)

    # render
    render = sub.add_parser(
        "render", help="render a volume file or built-in dataset",
        description="Render INPUT (a volume file or builtin:NAME[:SIZE]) with a scene file "
                    "(default: the dataset's recommended scene, or a generic one for files).",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=OUTPUT_HELP + SERIES_HELP,
    )
    render.add_argument("input", nargs="+",
                        help="volume file (.vti .vtk .nrrd .nhdr .mha .mhd .nii .nii.gz), DICOM "
                             "directory, or builtin:NAME[:SIZE]; or a time series: a 4-D NIfTI, "
                             "a .pvd or .series file, several files, a quoted glob pattern "
                             "('step_*.vti') or a directory of volume files")
    render.add_argument("--output", "-o", required=True,
                        help="output .png, .npy or .npz (a time series: one per step, "
                             "NAME_0000.EXT ...), or an animation of a time series: .gif, .mp4")
    render.add_argument("--fps", help="frames per second of a .gif/.mp4 animation (default 10)")
    render.add_argument("--prefetch", type=_integer, default=DEFAULT_PREFETCH, metavar="N",
                        help="time series: steps read (and prepared for the render) ahead "
                             f"of the one rendering, on a background thread (default "
                             f"{DEFAULT_PREFETCH}; 0: read each step when its turn comes)")
    render.add_argument("--scene", "-s", help="scene JSON file (see 'vtkillum scene')")
    render.add_argument("--denoise", action=RequireDenoiser,
                        help="denoise a .png of path, photon or many-lights with Intel Open "
                             "Image Denoise (pip install 'vtkillum[denoise]'); .npy/.npz keep "
                             "the raw radiance")
    _add_input_options(render)
    _add_render_options(render, methods, default_method="single")
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

    # export
    export = sub.add_parser(
        "export", help="write a volume (e.g. a built-in dataset) to a file",
        description="Write INPUT (builtin:NAME[:SIZE] or a volume file) as .vti, .nii/.nii.gz "
                    "or .mha/.mhd, keeping its placement (origin, spacing, direction). "
                    "Built-in datasets are in millimetres in an RAS-like frame: a NIfTI "
                    "export records that, so a render of it shows an anterior view.",
    )
    export.add_argument("input", help="builtin:NAME[:SIZE] or a volume file")
    export.add_argument("--output", "-o", required=True,
                        help="file to write: " + ", ".join(EXPORT_FORMATS))
    _add_input_options(export)
    export.set_defaults(run=run_export)

    # info
    info = sub.add_parser(
        "info", help="show the version, the devices available and the data shipped",
        description="Print the versions of vtkillum and its libraries, the warp devices "
                    "(and which one renders by default), the ambient-scattering tables "
                    "and the built-in datasets.")
    info.set_defaults(run=run_info)
    return parser


def _add_input_options(parser) -> None:
    parser.add_argument("--array", help="data array to render (default: the active scalars)")
    parser.add_argument("--component", help="component of a multi-component array: an index "
                                            "or 'magnitude'")
    parser.add_argument("--time-step", type=_integer, metavar="N",
                        help="step N of a time series (a 4-D NIfTI, a .pvd or .series file, "
                             "several files); negative counts from the end. render: default "
                             "every step")


def _add_render_options(parser, methods, default_method: str) -> None:
    parser.add_argument("--method", "-m", default=default_method, choices=methods,
                        metavar="METHOD",
                        help=f"rendering method, one of: {', '.join(methods)} "
                             f"(default {default_method})")
    cpu, gpu = default_image_size("cpu"), default_image_size("cuda")
    parser.add_argument("--size", nargs=2, type=_integer, metavar=("W", "H"), default=None,
                        help="image width and height in pixels (default "
                             f"{cpu[0]} {cpu[1]} on a CPU, {gpu[0]} {gpu[1]} with CUDA)")
    parser.add_argument("--device", default=None,
                        help="warp device: cpu, cuda, cuda:N (default: CUDA when present; the "
                             "VTKILLUM_DEVICE environment variable overrides; 'vtkillum info' "
                             "lists them)")
    parser.add_argument("--spp", type=_integer, help="samples per pixel (methods that take them, "
                                                "e.g. path); default from the scene file")
    parser.add_argument("--exposure", default="auto",
                        help="PNG exposure: 'auto' (default: the 99.5th percentile of the "
                             "pixels the volume covers maps to white) or a positive factor "
                             "(1: radiance 1 is white)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="extra method option, VALUE in JSON (e.g. step_size=0.5, "
                             "jitter=false); repeatable")
    parser.add_argument("--quiet", "-q", action="store_true",
                        help="no progress, estimate or summary line (progress is a bar on a "
                             "terminal, else a line after a second and then every few "
                             "seconds; a first run on a device says when it compiles "
                             "kernels)")


# --- commands -----------------------------------------------------------------------------------
def run_demo(args) -> int:
    from vtkillum.data.builtin import is_builtin

    if not is_builtin(args.dataset):
        raise UserError(f"demo --dataset must be builtin:NAME[:SIZE]; {_builtin_names()}")
    args.input, args.scene, args.array, args.component = args.dataset, None, None, None
    return run_render(args)


def run_render(args) -> int:
    from vtkillum.core.defaults import camera_inside_warning
    from vtkillum.core.device import resolve_device
    from vtkillum.core.render import render

    # A time series renders step by step (run_render_series); one volume goes on here.
    series = open_input_series(args.input, args.array, args.component,
                               getattr(args, "time_step", None))
    if series is not None:
        return run_render_series(args, series)
    args.input = single_input(args.input)  # a pattern or directory of one file: that file
    if Path(args.output).suffix.lower() in ANIMATION_FORMATS:
        raise UserError(f"output {_short(args.output)}: an animation needs a time series (a 4-D "
                        f"NIfTI, a .pvd or .series file, several files); {args.input} is one "
                        "volume: write a .png")
    outputs = check_output(args.output, OUTPUT_FORMATS)
    exposure = _parse_exposure(args.exposure)
    options = _parse_options(args.option)
    _method_with_spp(args, options)
    device = resolve_device(args.device)
    width, height = _check_size(args.size if args.size is not None
                                else default_image_size(device))

    interrupted = None
    # Started before the data are read: a large file takes seconds, and every render says
    # what it is doing within FIRST_LINE_SECONDS.
    reporter = _progress_bar(args.quiet, f"{args.method} {width}x{height}")
    with reporter as progress:
        name = str(args.input)
        reporter.activity = f"reading {name if len(name) <= 60 else '...' + name[-57:]}"
        volume, scene = load_input(args.input, args.scene, args.array, args.component,
                                   aspect=width / height)
        check_memory(args.method, width, height, device, volume)
        warning = camera_inside_warning(scene.resolved_camera(volume), volume)
        if warning:
            reporter.write(f"vtkillum: warning: {warning}")
        reporter.activity = None
        start = time.perf_counter()
        try:
            if args.method == "path":
                result, interrupted = render_path_with_estimate(
                    volume, scene, width, height, device, progress, quiet=args.quiet,
                    watch=reporter.watch, **options)
            else:
                result = render(volume, scene, args.method, width, height, device, progress,
                                **options)
        except ValueError as err:
            if args.scene is None or str(err).startswith(str(args.scene)):
                raise
            # Options from the scene file are checked by the method: say where they came from.
            raise ValueError(f"{err} (scene file {args.scene})") from err
        elapsed = time.perf_counter() - start
    result = denoised_for_output(result, outputs[0], args.method, getattr(args, "denoise", False))
    written = write_result(outputs[0], result, scene.background, exposure)
    if interrupted is not None:
        done, wanted, signum = interrupted
        _report(f"vtkillum: {_stopped(signum)}: wrote {', '.join(str(p) for p in written)} with "
                f"{done} of {wanted} samples per pixel ({width}x{height}, {elapsed:.1f} s)")
        return 128 + signum
    if not args.quiet:
        compiled = reporter.watch.compile_seconds if reporter.watch is not None else 0.0
        note = f", {compiled:.1f} s of it compiling kernels" if compiled >= 0.1 else ""
        print(f"wrote {', '.join(str(p) for p in written)} ({width}x{height}, {args.method}, "
              f"{result.info.get('device', device)}, {elapsed:.1f} s{note})")
    return 0


def render_path_with_estimate(volume, scene, width, height, device, progress=None,
                              quiet=False, stream=None, spp=None, max_bounces=None, seed=None,
                              watch=None, **options):
    """The ``path`` method, pass by pass, for the command line.

    The first pass (one sample per pixel) that compiled no kernels (``watch``, a
    :class:`vtkillum.progress.KernelWatch`, tells) is timed; when it predicts more than
    :data:`LONG_RENDER_SECONDS` the estimate is printed (unless ``quiet``). Ctrl-C (SIGINT),
    SIGTERM (what ``timeout`` and batch schedulers send) and SIGHUP stop after the pass
    under way: the image of the passes done is returned. A second one stops at once
    (``KeyboardInterrupt``, or :class:`~vtkillum.io.writers.Terminated`). SIGTERM and SIGHUP
    are taken over only where they have their default action (``nohup`` keeps SIGHUP
    ignored).

    Returns ``(result, interrupted)``: ``interrupted`` is ``None``, or ``(done, spp,
    signum)``: the samples per pixel taken and asked for, and the signal that stopped the
    render.
    """
    import threading

    from vtkillum.core.pathtrace import PathTracer

    if options:
        raise ValueError(f"path: unknown option(s) {sorted(options)}; the path tracer takes spp, "
                         "max_bounces and seed")
    defaults = scene.options["path"]
    spp = int(defaults["spp"] if spp is None else spp)
    if spp < 1:
        raise ValueError(f"path: spp must be a positive integer, got {spp}")
    tracer = PathTracer(volume, scene, width, height, device=device,
                        seed=defaults["seed"] if seed is None else seed,
                        max_bounces=defaults["max_bounces"] if max_bounces is None
                        else max_bounces)
    stop = {"signal": None}
    previous = {}
    if threading.current_thread() is threading.main_thread():
        def request_stop(signum, frame):
            if stop["signal"] is not None:  # a second signal: stop at once
                if signum == signal.SIGINT:
                    raise KeyboardInterrupt
                raise Terminated(signum)
            stop["signal"] = signum

        previous[signal.SIGINT] = signal.signal(signal.SIGINT, request_stop)
        for signum in TERMINATING_SIGNALS:
            if signal.getsignal(signum) is signal.SIG_DFL:
                previous[signum] = signal.signal(signum, request_stop)
    try:
        start = time.perf_counter()
        announced = quiet
        while tracer.passes < spp and (tracer.passes == 0 or stop["signal"] is None):
            compiled = watch.compiled if watch is not None else 0
            begin = time.perf_counter()
            tracer.run(1)
            took = time.perf_counter() - begin
            if not announced and (watch is None or watch.compiled == compiled):
                # Timed on the first pass that compiled nothing: a first run on a device
                # compiles the kernels in the first pass, which says nothing of the others.
                announced = True
                estimate = time.perf_counter() - start + took * (spp - tracer.passes)
                if estimate > LONG_RENDER_SECONDS:
                    note = (f", after {watch.compile_seconds:.1f} s compiling kernels"
                            if watch is not None and watch.compile_seconds >= 0.1 else "")
                    print(f"path: {spp} samples per pixel at {width}x{height} on {device}: "
                          f"about {_duration(estimate)} (one sample per pixel took "
                          f"{took:.2f} s{note}); Ctrl-C stops and writes the image so far",
                          file=stream or sys.stderr, flush=True)
            if progress is not None:
                progress(tracer.passes / spp, f"{tracer.passes}/{spp} spp")
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    result = tracer.result()
    if tracer.passes < spp:
        return result, (tracer.passes, spp, stop["signal"] or signal.SIGINT)
    return result, None


# --- time series ----------------------------------------------------------------------------------
def run_render_series(args, series) -> int:
    """``render`` of a time series (``series``, a :class:`~vtkillum.io.time_series.TimeSeries`
    from :func:`open_input_series`).

    Every step (or ``--time-step N`` alone) is rendered with one scene: the scene file's
    fields, and for what it does not give the data-aware defaults of the voxelwise
    maximum over the steps rendered (:func:`series_scene`), so that the transfer function
    and the camera suit every step and stay put. PNG exposure ``auto`` is decided once,
    over the pixels of all frames, so brightness changes between frames are the data's.
    Outputs: an animation (``.gif``, ``.mp4``: :mod:`vtkillum.io.animation`), one file per
    step named ``NAME_0000.EXT`` (the step's index, :func:`numbered_output`), or with
    ``--time-step`` the output name itself. Pictures with a fixed ``--exposure`` and
    ``.npy``/``.npz`` files are written as each step is done; an automatic exposure and
    an animation keep the frames (16 bytes per pixel) until all are rendered.

    Steps are read ahead (``--prefetch N``, default :data:`DEFAULT_PREFETCH`): while step
    ``t`` renders, a background thread (:class:`~vtkillum.io.time_series.StepPrefetcher`)
    reads step ``t + 1`` and prepares it for the render (:func:`render_preparation`: its
    value range, content hash and canonical-unit volume; the upload to the device stays
    in the render), so that a series renders at the rate of the slower of reading and
    rendering. The pictures are
    those of ``--prefetch 0``; a step that cannot be read stops the run at that step with
    that step's error, after the steps before it are written, as without prefetching.
    Each step read ahead holds its volume in host memory until its turn.

    The CLI renders whole images with the core methods (:func:`vtkillum.core.render.render`),
    not through the illumination filters: ``emission``, ``single``, ``path`` and
    ``refraction`` have no filter, and a filter's light volume is only part of a frame.
    Each step is rendered once per run; what it keeps instead is the file (a 4-D NIfTI is
    read once for all steps, :mod:`vtkillum.io.readers`) and the finished frames, in a
    per-process cache keyed by the step's file state, the method, the scene, the size,
    the options and the device (:func:`frame_cache`), so that a second pass from Python
    (``main([...])`` again, e.g. an ``.mp4`` after the ``.png`` pictures) renders nothing.
    """
    from vtkillum.core.defaults import auto_exposure
    from vtkillum.core.device import resolve_device
    from vtkillum.core.render import render
    from vtkillum.core.scene import scene_json
    from vtkillum.core.tonemap import tonemap
    from vtkillum.io.animation import MissingDependencyError, check_animation_support, is_animation
    from vtkillum.io.time_series import StepPrefetcher

    animation = is_animation(args.output)
    device = resolve_device(args.device)
    size = args.size
    if size is None:  # no --size: the device's default picture size
        from vtkillum.core.defaults import default_image_size

        size = default_image_size(device)
    width, height = _check_size(size)
    exposure = _parse_exposure(args.exposure)
    options = _parse_options(args.option)
    fps = _check_fps(getattr(args, "fps", None))
    _method_with_spp(args, options)
    time_step = getattr(args, "time_step", None)
    steps = list(range(len(series))) if time_step is None else [series.index(time_step)]
    if animation:
        try:
            check_animation_support(args.output)
        except MissingDependencyError as err:
            raise UserError(str(err)) from None
        check_output(args.output, ANIMATION_FORMATS)
        targets = [Path(args.output)]
    elif time_step is not None:
        check_output(args.output, OUTPUT_FORMATS)
        targets = [Path(args.output)]
    else:
        targets = [numbered_output(args.output, k, len(series)) for k in steps]
        for target in targets:
            check_output(target, OUTPUT_FORMATS)
    if not args.quiet:
        times = series.times
        span = (f"t = {times[0]:g} .. {times[-1]:g}" if series.kind != "files"
                else f"{series.files[0].name} .. {series.files[-1].name}")
        what = (f"step {steps[0]} only" if len(steps) == 1 and time_step is not None
                else f"all {len(steps)} steps ('--time-step N' renders one)")
        where = (str(targets[0]) if len(targets) == 1
                 else f"{targets[0]} .. {targets[-1].name}")
        print(f"{series.name}: a time series of {len(series)} steps ({span}); rendering {what} "
              f"to {where}", flush=True)

    ahead = getattr(args, "prefetch", DEFAULT_PREFETCH)
    if ahead < 0:
        raise UserError(f"--prefetch {ahead}: the steps read ahead must be 0 or more")
    volume, scene = series_scene(series, steps, args.scene, aspect=width / height,
                                 prefetch=ahead)
    check_memory(args.method, width, height, device, volume)
    cache = frame_cache()
    settings = (args.method, scene_json(scene), width, height, device,
                json.dumps(options, sort_keys=True, default=str))
    # Pictures with a fixed exposure and radiance files are written as each step is done;
    # an automatic exposure (over all frames) and an animation keep the frames until the
    # end (16 bytes per pixel and step).
    keep = animation or (exposure == "auto" and Path(args.output).suffix.lower() == ".png")
    results, written, done, cached, interrupted = [], [], 0, 0, None
    keys = [(series.key(k), settings) for k in steps]
    # The steps to read, in order: those whose frames are not cached (a frame evicted
    # meanwhile is read when its turn comes).
    unread = [k for k, key in zip(steps, keys) if key not in cache]
    turn = {k: m for m, k in enumerate(unread)}
    start = time.perf_counter()
    with StepPrefetcher(series.read, ahead,
                        prepare=render_preparation(args.method)) as prefetcher:
        for n, k in enumerate(steps):
            key = keys[n]
            result = cache.lookup(key)
            if result is not None:
                cached += 1
                done += 1
                if keep:
                    results.append(result)
                else:
                    written += write_result(targets[n], result, scene.background, exposure)
                continue
            m = turn.get(k, len(unread))
            volume = prefetcher.take(k, then=unread[m + 1:m + 1 + ahead])  # read meanwhile
            label = f"{args.method} {width}x{height} {series.label(k)}"
            try:
                with _progress_bar(args.quiet, label) as progress:
                    if args.method == "path":
                        result, interrupted = render_path_with_estimate(
                            volume, scene, width, height, device, progress, quiet=args.quiet,
                            **options)
                    else:
                        result = render(volume, scene, args.method, width, height, device,
                                        progress, **options)
            except ValueError as err:
                if args.scene is None or str(err).startswith(str(args.scene)):
                    raise
                raise ValueError(f"{err} (scene file {args.scene})") from err
            volume = None  # its device copy goes with it
            done += 1
            if keep:
                results.append(result)
            else:
                written += write_result(targets[n], result, scene.background, exposure)
            if interrupted is not None:  # a path render stopped: write the steps so far
                break
            cache.store(key, result, result.radiance.nbytes + result.alpha.nbytes)
    elapsed = time.perf_counter() - start

    if exposure == "auto" and keep:
        # One exposure for every frame: the 99.5th percentile of all frames' covered pixels.
        exposure = auto_exposure(np.concatenate([r.radiance for r in results]),
                                 alpha=np.concatenate([r.alpha for r in results]),
                                 background=scene.background)
    if animation:
        from vtkillum.io.animation import write_animation

        frames = [tonemap(r.radiance, r.alpha, scene.background, exposure) for r in results]
        written = [write_animation(args.output, frames, fps)]
    elif keep:
        for target, result in zip(targets, results):
            written += write_result(target, result, scene.background, exposure)
    if interrupted is not None:
        samples, wanted, signum = interrupted  # (done counts the steps)
        _report(f"vtkillum: {_stopped(signum)}: wrote {done} of {len(steps)} steps, the last "
                f"with {samples} of {wanted} samples per pixel ({width}x{height}, "
                f"{elapsed:.1f} s)")
        return 128 + signum
    if not args.quiet:
        names = (", ".join(str(p) for p in written) if len(written) <= 2
                 else f"{written[0]} .. {written[-1]} ({len(written)} files)")
        reused = f", {cached} from the cache" if cached else ""
        print(f"wrote {names} ({len(steps)} step{'s' if len(steps) > 1 else ''}, "
              f"{width}x{height}, {args.method}, {device}, {elapsed:.1f} s{reused})")
    return 0


def render_preparation(method: str):
    """What the prefetch thread does to each step read ahead for a ``method`` render
    (``prepare`` of :class:`~vtkillum.io.time_series.StepPrefetcher`): the host-side work
    a render would do first on a new volume, so that it is done while the step before
    renders.

    It computes the volume's value range (a pass over the data; and its content hash,
    another, for :data:`CONTENT_KEYED_METHODS`) and makes its canonical-unit twin
    (:func:`vtkillum.core.units.canonical`, kept with the volume and given both): the
    render finds them in the volume's caches.

    The upload to the device stays in the render, on the main thread. Warp's graph
    capture is per device, not per thread: the CUDA stream that a render captures
    launch graphs on (:mod:`vtkillum.core.graphs`) records whatever any thread queues on
    it, an allocation or a copy included, and the CPU's capture recording is global. An
    upload from this thread while a render captures would be recorded into the render's
    graph. An upload that overlaps the kernels needs a stream and a buffer of its own,
    allocated before the render starts; it is not done here.
    """
    def prepare(volume) -> None:
        from vtkillum.core.units import WorldUnits

        volume.value_range  # noqa: B018 - cached with the volume, copied to its twin
        if method in CONTENT_KEYED_METHODS:
            volume.content_key  # noqa: B018
        WorldUnits.for_volume(volume).volume(volume)

    return prepare


def open_input_series(spec, array=None, component=None, time_step=None):
    """The time series ``spec`` names (a 4-D NIfTI, a ``.pvd``/``.series`` file, a glob
    pattern, a directory of volume files, or a list of files), or ``None`` for one volume
    or a built-in dataset. ``time_step`` is checked against it: a single volume has none.
    """
    from vtkillum.data.builtin import is_builtin
    from vtkillum.io.time_series import open_time_series

    specs = list(spec) if isinstance(spec, (list, tuple)) else [spec]
    if any(is_builtin(s) for s in specs):
        if len(specs) > 1:
            raise UserError("a built-in dataset is rendered on its own, not in a list of inputs")
        if time_step is not None:
            raise UserError(f"--time-step applies to time series (a 4-D NIfTI, a .pvd or "
                            f".series file, several files); {specs[0]} has none")
        return None
    series = open_time_series(specs, array=array, component=_parse_component(component))
    if not series.is_series:
        if time_step is not None:
            raise UserError(f"--time-step {time_step}: {series.name} is one volume, not a time "
                            "series (a 4-D NIfTI, a .pvd or .series file, a glob pattern such as "
                            "'step_*.vti', a directory of volume files)")
        return None
    if time_step is not None:
        series.index(time_step)  # a ValueError naming the steps there are
    return series


def single_input(spec):
    """The file (or DICOM directory, or ``builtin:...``) of an input that is not a time
    series: ``spec`` itself, or the one file a pattern or directory names."""
    from vtkillum.data.builtin import is_builtin
    from vtkillum.io.time_series import open_time_series

    spec = spec[0] if isinstance(spec, (list, tuple)) and len(spec) == 1 else spec
    if isinstance(spec, (list, tuple)) or is_builtin(spec) or Path(spec).exists():
        return spec
    return str(open_time_series(spec).files[0])


def series_scene(series, steps, scene_path=None, aspect: float = 1.0, prefetch: int = 0):
    """``(volume, scene)`` for rendering ``steps`` of ``series`` with one scene.

    The scene file (read once) gives what it gives; the rest takes the data-aware defaults
    (:func:`vtkillum.core.defaults.default_scene`) of the voxelwise maximum over ``steps``
    (the first of them alone when their grids differ), so that the camera frames what any
    step shows and the transfer function covers every step's values. ``volume`` is that
    maximum (what ``scene``'s data-dependent fields resolve on). ``prefetch``: steps read
    ahead while the maximum takes in the one before
    (:class:`~vtkillum.io.time_series.StepPrefetcher`).
    """
    from vtkillum.core.defaults import default_scene
    from vtkillum.core.scene import read_scene_data, scene_from_data
    from vtkillum.core.volume import Volume
    from vtkillum.io.time_series import StepPrefetcher

    data = read_scene_data(scene_path) if scene_path else None
    scene = scene_from_data(data, scene_path) if scene_path else None
    fill = {"transfer_function", "camera", "lights"}
    if scene_path:
        fill -= set(data)
    first = series.read(steps[0])
    peak = first.scalars
    rest = steps[1:] if fill else []
    with StepPrefetcher(series.read, prefetch) as prefetcher:
        for n, k in enumerate(rest):
            other = prefetcher.take(k, then=rest[n + 1:n + 1 + prefetch])
            if other.scalars.shape != peak.shape or not (
                    np.allclose(other.spacing, first.spacing) and np.allclose(other.origin,
                                                                               first.origin)):
                peak = first.scalars
                break
            peak = np.maximum(peak, other.scalars)
    volume = first if peak is first.scalars else Volume(
        peak, first.spacing, first.origin, first.direction, nan_policy="fill")
    frame = "LPS" if series.kind == "nifti" else (
        anatomical_frame(series.files[0]) if series.files else None)
    scene = default_scene(volume, frame, base=scene, fill=fill, aspect=aspect)
    return volume, scene


def numbered_output(output, index: int, count: int) -> Path:
    """``out.png`` -> ``out_0007.png``: the picture of step ``index`` of ``count`` (at least
    four digits, more for series of 10000 steps or more)."""
    output = Path(output)
    digits = max(4, len(str(max(count - 1, 0))))
    return output.with_name(f"{output.stem}_{index:0{digits}d}{output.suffix}")


def frame_cache():
    """The per-process cache of rendered frames of time series (a
    :class:`~vtkillum.filters.time_cache.TimeStepCache` with the filters' default budget:
    a share of the memory available)."""
    global _FRAME_CACHE
    if _FRAME_CACHE is None:
        from vtkillum.filters.time_cache import TimeStepCache, default_cache_mb

        _FRAME_CACHE = TimeStepCache(int(default_cache_mb() * 2**20))
    return _FRAME_CACHE


_FRAME_CACHE = None

#: Outputs of ``render`` for a time series besides :data:`OUTPUT_FORMATS`.
ANIMATION_FORMATS = (".gif", ".mp4")

SERIES_HELP = """
time series:
  INPUT may be a time series: a 4-D NIfTI (one volume per time step), a .pvd or
  ParaView .series file, several volume files, a quoted glob pattern such as
  'step_*.vti', or a directory of volume files (ordered naturally: step_2 before
  step_10). Every step is rendered with one scene (defaults from the voxelwise
  maximum over the steps, one automatic exposure for all frames) and written as
  NAME_0000.EXT, NAME_0001.EXT, ... (the step's index), or as an animation:
  --output movie.gif (Pillow) or movie.mp4 (pip install 'vtkillum[animation]'),
  --fps frames per second. --time-step N renders step N alone (negative: from
  the end) under the output name as given. While a step renders the next one is
  read (--prefetch N: N steps ahead, default 1; 0 reads each step in its turn); the
  pictures are the same either way.
"""


def _check_fps(value) -> float:
    if value is None:
        from vtkillum.io.animation import DEFAULT_FPS

        return DEFAULT_FPS
    try:
        fps = float(value)
    except (TypeError, ValueError):
        raise UserError(f"--fps must be a positive number, got {_short(value)}") from None
    if not (np.isfinite(fps) and 0 < fps <= 1000):
        raise UserError(f"--fps must be a positive number of frames per second (at most "
                        f"1000), got {_short(value)}")
    return fps


def run_scene(args) -> int:
    from vtkillum.core.scene import scene_json

    (output,) = check_output(args.output, (".json",))
    time_step = getattr(args, "time_step", None)
    series = open_input_series(args.dataset, args.array, args.component, time_step)
    if series is not None:  # the scene a render of the series (or of its step) would use
        steps = list(range(len(series))) if time_step is None else [series.index(time_step)]
        volume, scene = series_scene(series, steps)
    else:
        volume, scene = load_input(args.dataset, None, args.array, args.component)
    data = explicit_scene(scene, volume)
    text = scene_json(data).encode()
    write_atomically([(output, lambda f: f.write(text))])
    print(f"wrote {output}")
    return 0


def run_export(args) -> int:
    output = Path(args.output)
    if not output.name.lower().endswith(EXPORT_FORMATS):
        raise UserError(f"output {_short(args.output)}: the extension must be one of "
                        f"{', '.join(EXPORT_FORMATS)}")
    for target in volume_files(output):  # .mhd: its data file name.raw too
        role = "" if target == output else f"data file {str(target)!r} of "
        _check_target(target, f"{role}output {args.output!r}")
    time_step = getattr(args, "time_step", None)
    series = open_input_series(args.input, args.array, args.component, time_step)
    if series is not None:
        if time_step is None:
            raise UserError(f"{series.name} is a time series of {len(series)} steps; export one "
                            f"with --time-step N (0..{len(series) - 1})")
        volume = series.read(time_step)
        frame = "LPS" if series.kind == "nifti" else anatomical_frame(series.files[0])
    else:
        volume, frame = load_input_volume(args.input, args.array, args.component)
    write_volume(volume, output, frame)
    print(f"wrote {output} ({'x'.join(map(str, volume.dims))} points, spacing "
          f"{', '.join(f'{v:g}' for v in volume.spacing)})")
    return 0


def run_info(args) -> int:
    import platform

    import warp as wp

    from vtkillum import __version__
    from vtkillum.core.device import ENV_VAR, describe_devices

    versions = [f"python {platform.python_version()}", f"numpy {np.__version__}",
                f"warp {wp.config.version}"]
    try:
        from vtkmodules.vtkCommonCore import vtkVersion

        versions.append(f"vtk {vtkVersion.GetVTKVersion()}")
    except ImportError:
        versions.append("vtk missing")
    print(f"vtkillum {__version__} ({', '.join(versions)})")
    print("devices (pick one with --device NAME or the environment variable "
          f"{ENV_VAR}):")
    for line in describe_devices():
        print(f"  {line}")
    try:
        from vtkillum.core.ambient.table import describe_tables

        print("ambient-scattering tables:")
        for line in describe_tables():
            print(f"  {line}")
    except ImportError:
        pass
    print(_builtin_names())
    return 0


# --- building blocks (usable from Python too) -----------------------------------------------------
def load_input(spec, scene_path=None, array=None, component=None, aspect: float = 1.0):
    """Load ``spec`` (file or ``builtin:...``) and its scene.

    Returns ``(volume, scene)``. A built-in dataset gets its recommended scene unless
    ``scene_path`` is given. A file gets the scene file's settings, and for what the scene
    file does not give (or all of it without one) the data-aware defaults of
    :func:`vtkillum.core.defaults.default_scene`: transfer function from the histogram,
    a camera for the image's orientation (:func:`anatomical_frame`) framing the
    foreground at ``aspect`` (width / height), one key light.
    """
    from vtkillum.core.defaults import default_scene
    from vtkillum.core.scene import read_scene_data, scene_from_data
    from vtkillum.data.builtin import builtin_scene, is_builtin, load_builtin

    # The scene file is read once, before the volume (a pipe such as /dev/stdin can be
    # read only once); its fields say which defaults to fill in.
    data = read_scene_data(scene_path) if scene_path else None
    scene = scene_from_data(data, scene_path) if scene_path else None
    if is_builtin(spec):
        if array is not None or component is not None:
            raise UserError("--array and --component apply to files, not built-in datasets")
        volume = load_builtin(spec)
        return volume, scene if scene is not None else builtin_scene(spec, volume)
    from vtkillum.io.readers import read_volume

    volume = read_volume(spec, array=array, component=_parse_component(component))
    fill = {"transfer_function", "camera", "lights"}
    if scene_path:
        fill -= set(data)
    scene = default_scene(volume, anatomical_frame(spec), base=scene, fill=fill, aspect=aspect)
    return volume, scene


def anatomical_frame(path) -> str | None:
    """``"LPS"`` when ``path``'s world coordinates are anatomical, else ``None``.

    The readers (:mod:`vtkillum.io.readers`) put NIfTI, DICOM and MetaImage data, and NRRD
    files with an anatomical ``space`` (RAS, LAS, LPS), in LPS coordinates (+x left,
    +y posterior, +z superior); other files carry no anatomical meaning.
    """
    from vtkillum.io.readers import NRRD_SPACES, volume_format

    try:
        fmt = volume_format(path)
    except ValueError:
        return None
    if fmt in ("nifti", "dicom", "metaimage"):
        return "LPS"
    if fmt == "nrrd":
        try:
            with open(path, "rb") as f:
                head = f.read(1 << 16).split(b"\n\n")[0].decode("latin-1")
        except OSError:
            return None
        for line in head.splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip().lower() == "space":
                space = value.strip().lower()
                anatomical = {k for k in NRRD_SPACES if k in ("lps", "ras", "las") or "-" in k
                              and k.split("-")[0] in ("left", "right")}
                return "LPS" if space in anatomical else None
    return None


def load_input_volume(spec, array=None, component=None):
    """The volume named by ``spec`` and its anatomical frame (``"RAS"`` for built-in
    datasets, :func:`anatomical_frame` for files)."""
    from vtkillum.data.builtin import is_builtin, load_builtin

    if is_builtin(spec):
        if array is not None or component is not None:
            raise UserError("--array and --component apply to files, not built-in datasets")
        return load_builtin(spec), "RAS"
    from vtkillum.io.readers import read_volume

    volume = read_volume(spec, array=array, component=_parse_component(component))
    return volume, anatomical_frame(spec)


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
    from vtkillum.core.defaults import picture
    from vtkillum.core.tonemap import write_png

    output = Path(output)
    radiance = np.asarray(result.radiance, dtype=np.float32)
    alpha = np.asarray(result.alpha, dtype=np.float32)
    suffix = output.suffix.lower()
    if suffix == ".png":
        rgb8 = picture(radiance, alpha, background, exposure)  # as grid.illum.render writes
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
        with signals_held():  # made and removed at once: a signal cannot leave it behind
            with tempfile.NamedTemporaryFile(dir=parent, prefix=f".{real.name}.", suffix=".tmp"):
                pass
    except OSError as err:
        raise UserError(f"{what}: cannot write to the directory {parent} "
                        f"({err.strerror or err})") from None


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


def _stopped(signum: int) -> str:
    """How a render was stopped, for its last line: by Ctrl-C or by a terminating signal."""
    return ("interrupted" if signum == signal.SIGINT
            else f"terminated ({signal.Signals(signum).name})")


def _method_with_spp(args, options: dict):
    """The render function of ``--method``; ``--spp`` checked and put into ``options``."""
    from vtkillum.core.render import method_function

    if args.method in HIDDEN_METHODS:
        raise UserError(f"--method {args.method} needs an illumination volume, which only the "
                        "Python API can give (vtkillum.core.raycast.render_illuminated)")
    fn = method_function(args.method)
    if args.spp is not None:
        if args.spp < 1:
            raise UserError(f"--spp must be a positive integer, got {args.spp}")
        if "spp" not in inspect.signature(fn).parameters:
            raise UserError(f"--spp does not apply to the {args.method!r} method (it takes no "
                            "samples per pixel; the path method does)")
        options["spp"] = args.spp
    return fn


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


def _integer(text: str) -> int:
    """An integer argument of at most :data:`MAX_INTEGER_DIGITS` digits (argparse type)."""
    digits = str(text).strip().lstrip("+-")
    if len(digits) > MAX_INTEGER_DIGITS and digits.isdigit():
        raise argparse.ArgumentTypeError(
            f"an integer of {len(digits)} digits ({digits[:20]}...{digits[-10:]}); at most "
            f"{MAX_INTEGER_DIGITS} digits")
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {_short(text)}") from None


def _parse_component(text):
    if text is None or text == "magnitude":
        return text
    try:
        return _integer(text)
    except argparse.ArgumentTypeError:
        raise UserError(f"--component must be an index or 'magnitude', got "
                        f"{_short(text)}") from None


def _parse_options(items) -> dict:
    """``--option KEY=VALUE`` items: VALUE as JSON (bounded as scene files are: nesting,
    integer digits, finite numbers), else as a bare string such as a name."""
    from vtkillum.core.scene import JSONLimitError, parse_json

    options = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--option {_short(item)}: expected KEY=VALUE, e.g. step_size=0.5")
        key = key.strip()
        try:
            options[key] = parse_json(value, f"--option {_short(key, 60)}")
        except JSONLimitError as err:
            raise UserError(str(err)) from None
        except json.JSONDecodeError:
            options[key] = value  # a bare string such as a name
    return options


def _short(value, limit: int = 80) -> str:
    """``repr`` of a user-supplied value, cut to ``limit`` characters."""
    from vtkillum.core.scene import _short as short

    return short(str(value) if isinstance(value, Path) else value, limit)


def _builtin_names() -> str:
    from vtkillum.data.builtin import available

    return f"built-in datasets: {available()}"


def _one_line(err: BaseException) -> str:
    """The message of ``err`` on one line, long runs of what was typed cut (a 100 kB key,
    a number of 5000 digits: :func:`vtkillum.core.scene.shorten_message`)."""
    from vtkillum.core.scene import shorten_message

    text = str(err).strip() or type(err).__name__
    return shorten_message(" ".join(text.split()))


def _report(line: str) -> None:
    """A last line on stderr, which may be gone (SIGHUP: the terminal closed)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


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
