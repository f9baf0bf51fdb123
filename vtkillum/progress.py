"""Progress of a command-line render: what it is doing, how far it got, how long is left.

Two pieces, used by :mod:`vtkillum.cli`:

:class:`KernelWatch`
    Watches warp while a render runs: which *stage* is running (named after the module
    that defines the kernel just launched: the method packages name their files after
    the paper's stages, :data:`STAGE_NAMES`), and whether warp is **compiling** a kernel
    module (the first launch of a module on a device generates and compiles its code,
    seconds to a minute; later runs load it from warp's kernel cache at once). It wraps
    ``warp.launch``/``warp.launch_tiled`` and ``warp.Module.load`` for its duration; a
    load is a compile when warp generates code for it (``Module._run_codegen``, warp
    1.x) or, where that step cannot be seen, when it takes longer than
    :data:`COMPILE_GUESS_SECONDS`.

:class:`ProgressReporter`
    The ``progress(fraction, detail=None)`` callback handed to the methods, plus a
    heartbeat thread, so that a render says what it is doing even while one long kernel
    runs or a method reports no fractions. On a terminal a bar; elsewhere (a log, a pipe)
    a line :data:`FIRST_LINE_SECONDS` after the start and then every
    :data:`PROGRESS_INTERVAL` seconds::

        single 256x256: compiling kernels (first run on this device), 1 s spent
        single 256x256: ray casting, 35 %, 6 s spent (4 s compiling), about 4 s left
        many-lights 256x256: gathering virtual lights, 11 s spent

    The time left is extrapolated only from work measured after the last compile and
    after the first fraction reported (that first stretch holds set-up: allocations,
    empty rows, a compile that could not be seen), over at least
    :data:`MIN_MEASURED_SECONDS`, at the rate of the fraction done since then over the
    time since then (up to now, so that a stalling render's estimate grows); before
    that, while compiling, or without fractions, no estimate is printed.
"""

from __future__ import annotations

import os
import sys
import threading
import time

#: Seconds into a render at which its first progress line is printed (lines mode; the
#: bar shows at once).
FIRST_LINE_SECONDS = 1.0
#: Seconds between progress lines when the output is not a terminal
#: (``VTKILLUM_PROGRESS_INTERVAL`` overrides).
PROGRESS_INTERVAL = 5.0
#: Seconds between the heartbeat thread's looks at the render.
HEARTBEAT_POLL = 0.2
#: A module load that takes longer than this is taken for a compile when warp's code
#: generation step cannot be watched.
COMPILE_GUESS_SECONDS = 0.5
#: Seconds of measured work (after compiling and after the first fraction) before the
#: time left is estimated.
MIN_MEASURED_SECONDS = 1.0
#: What a compiling render says it is doing.
COMPILING = "compiling kernels (first run on this device)"
#: What a render says before its first kernel or stage is known.
RENDERING = "rendering"
#: The clock of :class:`ProgressReporter` when none is given (seconds, monotonic).
DEFAULT_CLOCK = time.perf_counter

#: Readable stage names by the module defining a kernel (``vtkillum.core.`` left off).
#: Other modules of vtkillum read as the last part of their name; warp's own kernels
#: and shared helpers (``None``) leave the stage as it was.
STAGE_NAMES = {
    "raycast": "ray casting",
    "raymarch": "ray casting",
    "empty_space": "empty-space skipping",
    "warp_common": None,
    "pathtrace": "path tracing",
    "light_transmittance": "light transmittance volume",
    "ambient.table": "scattering table",
    "ambient.device_table": "scattering table",
    "ambient.sat": "summed-area tables",
    "ambient.tube_march": "ambient extinction (tube march)",
    "ambient.gather": "ambient gather",
    "ambient.textures": "ambient textures",
    "convection_diffusion.opacity": "opacity volume",
    "convection_diffusion.convection": "convection",
    "convection_diffusion.composition": "convection",
    "convection_diffusion.radiative": "diffusion",
    "convection_diffusion.multigrid": "diffusion",
    "convection_diffusion.coarsening": "diffusion",
    "convection_diffusion.stencil": "diffusion",
    "convection_diffusion.diffusion": "diffusion",
    "convection_diffusion.solver": "diffusion",
    "convection_diffusion.reconstruction": "light volume",
    "photon.tables": "transfer-function tables",
    "photon.density": "photon density",
    "photon.tracing": "photon tracing",
    "photon.storage": "photon tracing",
    "photon.hashgrid": "photon hash grid",
    "photon.segments": "gathering photons along view rays",
    "photon.mapper": "photon map",
    "many_lights.walk": "light paths (virtual lights)",
    "many_lights.contribution": "virtual-light contributions",
    "many_lights.avsm": "transmittance caching (AVSM)",
    "many_lights.gather": "gathering virtual lights",
    "refraction.sweep": "plane sweep",
    "refraction.ray_equation": "bent rays",
    "refraction.environment": "environment map",
}


def stage_name(module: str | None) -> str | None:
    """The stage a kernel defined in Python module ``module`` belongs to (``None``: keep)."""
    if not module or not module.startswith("vtkillum."):
        return None
    key = module.removeprefix("vtkillum.").removeprefix("core.")
    if key in STAGE_NAMES:
        return STAGE_NAMES[key]
    return key.rsplit(".", 1)[-1].replace("_", " ")


def duration(seconds: float) -> str:
    """``42 s``, ``3 min 20 s``, ``1 h 05 min``; ``?`` for what is not finite."""
    if not (seconds == seconds and abs(seconds) != float("inf")):
        return "?"
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {(seconds % 3600) // 60:02d} min"


class KernelWatch:
    """Context manager watching warp's launches and module loads (module docstring).

    Attributes
    ----------
    stage : str or None
        Stage of the kernel launched last (:func:`stage_name`).
    compiled : int
        Module loads that compiled.
    compile_seconds : float
        Time spent in them.
    compile_end : float or None
        ``clock()`` when the last one ended.
    on_launch : callable or None
        Called (no arguments) before every kernel launch: a progress line can be
        printed between kernels, from the rendering thread itself.
    """

    def __init__(self, clock=time.perf_counter, on_launch=None):
        self.clock, self.on_launch = clock, on_launch
        self.stage = None
        self.compiled = 0
        self.compile_seconds = 0.0
        self.compile_end = None
        self._loads = {}  # thread id -> [start, codegen seen]
        self._saved = []

    # -- what the reporter asks ----------------------------------------------------------
    def compiling(self) -> bool:
        """Whether a module is being compiled now."""
        now = self.clock()
        return any(seen or now - start > COMPILE_GUESS_SECONDS
                   for start, seen in list(self._loads.values()))

    def compile_started(self) -> float | None:
        """``clock()`` when the compile under way began (``None`` when none is)."""
        now = self.clock()
        starts = [start for start, seen in list(self._loads.values())
                  if seen or now - start > COMPILE_GUESS_SECONDS]
        return min(starts) if starts else None

    # -- hooks ----------------------------------------------------------------------------
    def __enter__(self):
        import warp as wp

        watch = self
        module_class = wp.Module
        original_load = module_class.load

        def load(module, *args, **kwargs):
            key = threading.get_ident()
            if key in watch._loads:  # a load within a load: timed by the outer one
                return original_load(module, *args, **kwargs)
            watch._loads[key] = [watch.clock(), False]
            try:
                return original_load(module, *args, **kwargs)
            finally:
                start, seen = watch._loads.pop(key)
                spent = watch.clock() - start
                if seen or spent > COMPILE_GUESS_SECONDS:
                    watch.compiled += 1
                    watch.compile_seconds += spent
                    watch.compile_end = watch.clock()

        self._patch(module_class, "load", load)
        original_codegen = getattr(module_class, "_run_codegen", None)
        if original_codegen is not None:  # warp 1.x: runs only when the cache misses
            def run_codegen(module, *args, **kwargs):
                entry = watch._loads.get(threading.get_ident())
                if entry is not None:
                    entry[1] = True
                return original_codegen(module, *args, **kwargs)

            self._patch(module_class, "_run_codegen", run_codegen)
        for name in ("launch", "launch_tiled"):
            original = getattr(wp, name, None)
            if original is not None:
                self._patch(wp, name, self._launch_wrapper(original))
        return self

    def _launch_wrapper(self, original):
        watch = self

        def launch(kernel, *args, **kwargs):
            func = getattr(kernel, "func", None)
            stage = stage_name(getattr(func, "__module__", None)
                               or getattr(getattr(kernel, "module", None), "name", None))
            if stage is not None:
                watch.stage = stage
            if watch.on_launch is not None:
                watch.on_launch()
            return original(kernel, *args, **kwargs)

        launch.__wrapped__ = original
        launch.__doc__ = original.__doc__
        return launch

    def _patch(self, owner, name, value):
        self._saved.append((owner, name, owner.__dict__.get(name, getattr(owner, name))))
        setattr(owner, name, value)

    def __exit__(self, *exc):
        while self._saved:
            owner, name, value = self._saved.pop()
            setattr(owner, name, value)
        return False


class ProgressReporter:
    """Context manager yielding a ``progress(fraction, detail=None)`` callback.

    Parameters
    ----------
    quiet : bool
        Show nothing (the callback is then ``None`` and warp is not watched).
    description : str
        Start of every line, e.g. ``"single 256x256"``.
    stream : file, optional
        Where to write (default ``sys.stderr``).
    mode : {"auto", "bar", "lines"}
        ``"auto"``: a tqdm bar on a terminal, else lines.
    interval : float, optional
        Seconds between lines (default :data:`PROGRESS_INTERVAL`, or the environment
        variable ``VTKILLUM_PROGRESS_INTERVAL``).
    first_line : float, optional
        Seconds before the first line (default :data:`FIRST_LINE_SECONDS`; never later
        than ``interval``).
    clock : callable, optional
        Seconds, monotonic (default :data:`DEFAULT_CLOCK`; tests give a fake one).
    heartbeat : bool
        Run the heartbeat thread (lines while the render reports nothing).

    Attributes
    ----------
    watch : KernelWatch or None
        Stage and compile state (``None`` when quiet).
    activity : str or None
        What the caller says is happening before the render starts (``"reading the
        data"``); the watch's stage takes over once kernels run.
    printed : list of (time, line, estimate)
        Every line written in lines mode: ``clock()`` time, text, the seconds left it
        stated (``None``: no estimate).
    """

    def __init__(self, quiet: bool, description: str, stream=None, mode: str = "auto",
                 interval: float | None = None, first_line: float | None = None,
                 clock=None, heartbeat: bool = True):
        self.quiet, self.description, self.stream, self.mode = quiet, description, stream, mode
        if interval is None:
            try:
                interval = float(os.environ.get("VTKILLUM_PROGRESS_INTERVAL", PROGRESS_INTERVAL))
            except ValueError:
                interval = PROGRESS_INTERVAL
        self.interval = interval
        self.first_line = min(FIRST_LINE_SECONDS if first_line is None else first_line,
                              interval)
        self.clock = clock if clock is not None else DEFAULT_CLOCK
        self.heartbeat = heartbeat
        self.watch = None
        self.activity = None
        self.bar = None
        self.printed = []
        self.lines = 0
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread = None
        self._start = None
        self._last_line = None
        self._fraction = None
        self._detail = None
        self._base = None  # (time, fraction) the rate is measured from
        self._last = None  # (time, fraction) of the last report

    # -- state ----------------------------------------------------------------------------
    def estimate(self, now: float | None = None) -> float | None:
        """Seconds left, from the work measured since the baseline (module docstring)."""
        now = self.clock() if now is None else now
        if self._base is None or self._last is None or self.watch_compiling():
            return None
        (t0, f0), (t1, f1) = self._base, self._last
        if f1 <= f0 or t1 - t0 < MIN_MEASURED_SECONDS or f1 >= 1.0:
            return None
        # The rate counts the time since the last report too: while a pass runs longer
        # than the ones before (a slower stage) the estimate grows instead of running out.
        return (1.0 - f1) * (max(now, t1) - t0) / (f1 - f0)

    def watch_compiling(self) -> bool:
        return self.watch is not None and self.watch.compiling()

    def doing(self) -> str:
        """What the render is doing now, in words."""
        if self.watch_compiling():
            return COMPILING
        stage = self.watch.stage if self.watch is not None else None
        return stage or self.activity or RENDERING

    def line(self, now: float | None = None, fraction: bool = True) -> tuple[str, float | None]:
        """The progress line for ``now`` and the estimate it states (``fraction``: with
        the percentage done, which a bar shows itself)."""
        now = self.clock() if now is None else now
        parts = [self.doing()]
        if fraction and self._fraction is not None and not self.watch_compiling():
            parts.append(f"{100 * self._fraction:.0f} %")
        if self._detail:
            parts.append(self._detail)
        spent = f"{duration(now - self._start)} spent"
        compiled = self._compile_seconds(now)
        if compiled >= 1.0 and not self.watch_compiling():
            spent += f" ({duration(compiled)} compiling)"
        parts.append(spent)
        left = self.estimate(now)
        if left is not None:
            parts.append(f"about {duration(left)} left")
        return f"{self.description}: {', '.join(parts)}", left

    def _compile_seconds(self, now: float) -> float:
        if self.watch is None:
            return 0.0
        started = self.watch.compile_started()
        return self.watch.compile_seconds + (now - started if started is not None else 0.0)

    # -- the callback and the heartbeat -------------------------------------------------------
    def report(self, fraction: float, detail: str | None = None) -> None:
        """The ``progress`` callback: ``fraction`` of the render done, optional detail."""
        now = self.clock()
        fraction = min(max(float(fraction), 0.0), 1.0)
        with self._lock:
            compile_end = self.watch.compile_end if self.watch is not None else None
            # The rate is measured from the first report, and again from the first one
            # after a compile: what came before holds set-up, not work.
            if self._base is None or (compile_end is not None and self._base[0] < compile_end):
                self._base = (now, fraction)
            self._last = (now, fraction)
            self._fraction, self._detail = fraction, detail
            if self.bar is not None:
                target = round(100 * fraction)
                if target > self.bar.n:
                    self.bar.update(target - self.bar.n)
                if self._last_line is None or now - self._last_line >= HEARTBEAT_POLL:
                    self._refresh_bar(now)
            elif fraction < 1.0:
                self._maybe_print(now)

    def _maybe_print(self, now: float) -> None:
        with self._lock:
            due = (self.first_line if self._last_line is None else self.interval)
            since = now - (self._start if self._last_line is None else self._last_line)
            if since < due or self._stop.is_set():
                return
            text, left = self.line(now)
            try:
                print(text, file=self.stream, flush=True)
            except (OSError, ValueError):  # the stream went away (SIGHUP, a closed pipe)
                self._stop.set()  # the render goes on; progress stops
                return
            self._last_line = now
            self.printed.append((now, text, left))
            self.lines += 1

    def _refresh_bar(self, now: float) -> None:
        text, _ = self.line(now, fraction=False)
        self.bar.status = text.split(": ", 1)[1]
        self.bar.refresh()
        self._last_line = now

    def write(self, text: str) -> None:
        """A line of its own (a warning), kept clear of the bar."""
        stream = self.stream if self.stream is not None else sys.stderr
        with self._lock:
            if self.bar is not None:
                self.bar.write(text, file=stream)
            else:
                print(text, file=stream, flush=True)

    def _on_launch(self) -> None:
        if self.bar is None:  # lines between kernels; the bar is the heartbeat's
            self._maybe_print(self.clock())

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_POLL):
            now = self.clock()
            try:
                if self.bar is not None:
                    with self._lock:
                        self._refresh_bar(now)
                else:
                    self._maybe_print(now)
            except (OSError, ValueError):  # the stream went away (SIGHUP, a closed pipe)
                return

    # -- context manager ------------------------------------------------------------------
    def __enter__(self):
        if self.quiet:
            return None
        if self.stream is None:
            self.stream = sys.stderr
        mode = self.mode
        if mode == "auto":
            try:
                mode = "bar" if self.stream.isatty() else "lines"
            except (AttributeError, ValueError):
                mode = "lines"
        self.watch = KernelWatch(self.clock, on_launch=self._on_launch).__enter__()
        self._start = self.clock()
        if mode == "bar":
            # Our own "spent / left" after the bar: tqdm's would count compile time as work.
            self.bar = _bar_class()(total=100, desc=self.description, file=self.stream,
                                    leave=False,
                                    bar_format="{desc}: {percentage:3.0f}%|{bar}| {status}")
        if self.heartbeat:
            self._thread = threading.Thread(target=self._beat, name="vtkillum-progress",
                                            daemon=True)
            self._thread.start()
        return self.report

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self.watch is not None:
            self.watch.__exit__(*exc)
        if self.bar is not None:
            self.bar.close()
        return False


def _bar_class():
    """tqdm with a ``status`` text after the bar (its postfix field would start with ', ')."""
    from tqdm import tqdm

    class StatusBar(tqdm):
        status = ""

        @property
        def format_dict(self):
            return dict(super().format_dict, status=self.status)

    return StatusBar
