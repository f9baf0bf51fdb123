"""Time series of volumes: find their steps, read them, serve them to VTK pipelines.

A time series is a list of steps, each a time and a volume. :func:`open_time_series`
finds one in

a 4-D NIfTI (``.nii``, ``.nii.gz``)
    one volume per time step, at ``toffset + t * pixdim[4]``
    (:func:`vtkillum.io.readers.time_steps`);
``.pvd``
    a VTK collection, ``<DataSet timestep="..." file="..."/>``: one file per time (one
    ``part``), at the times written;
``.series``
    ParaView's file-series JSON, ``{"files": [{"name": ..., "time": ...}, ...]}``;
a glob pattern (``'step_*.vti'``)
    the matching volume files, one step each (one file: a single volume);
a list of files
    what the shell makes of an unquoted pattern;
a directory
    its volume files (all of one extension), or the one ``.pvd``/``.series`` file in it.

Files of a series are ordered naturally (``step_2`` before ``step_10``) and their
times are their positions 0, 1, 2, ... (VTK's file-series convention), except where a
``.pvd`` or ``.series`` file gives times. Every step is read with
:func:`vtkillum.io.readers.read_volume` (so ``array``, ``component`` and ``nan_policy``
mean what they mean there), when it is asked for: a series of 1000 files costs
nothing to open.

:class:`TimeSeriesSource` serves a series to a VTK pipeline as one ``vtkImageData``
per time step (``TIME_STEPS``), so that ParaView's time controls, pyvista animations and
the illumination filters' per-time-step cache (:class:`vtkillum.filters.base.IlluminationFilterBase`)
drive it. A time between two steps gets the step at or before it (:func:`step_at`),
as VTK's readers and the ParaView plugin's reader do.

:class:`StepPrefetcher` reads steps ahead of their use on one background thread, so that
a series plays at the rate of the slower of reading and computing rather than of their
sum: the command line's series renders read step ``t + 1`` (and prepare it for the
render) while step ``t`` renders, and :class:`TimeSeriesSource` (``prefetch=1``) reads
the step after the one a pipeline asked for while the pipeline works on it.
"""

from __future__ import annotations

import collections
import contextlib
import glob
import json
import re
import threading
import xml.etree.ElementTree as ET
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

import numpy as np
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonCore import vtkOutputWindow
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

from vtkillum.core.volume import Volume
from vtkillum.io.readers import EXTENSIONS, read_volume, time_steps, volume_format

#: Characters that make an input a glob pattern (when no file has that name).
GLOB_CHARACTERS = "*?["

#: Series kinds: a file's own time axis, a file listing the steps, files one per step,
#: volumes in memory, and one volume (not a series).
KINDS = ("nifti", "pvd", "series", "files", "memory", "volume")


def step_at(times, time: float) -> int:
    """Index of the step at or before ``time`` (the first step for earlier times).

    ``times`` ascending. A time within a relative 1e-9 of a step counts as that step
    (times travel through VTK as doubles and through ParaView's animation as text).
    """
    times = np.asarray(times, dtype=np.float64)
    time = float(time)
    index = int(np.searchsorted(times, time + 1e-9 * max(abs(time), 1e-300), side="right")) - 1
    return min(max(index, 0), len(times) - 1)


@dataclass
class TimeSeries:
    """The steps of a time series: their times and how to read each.

    Attributes
    ----------
    name : str
        What the series is called in messages: the file, pattern or directory given.
    kind : str
        One of :data:`KINDS`: ``"volume"`` is a single volume (no time axis).
    times : list of float
        Ascending.
    files : list of Path
        The file of each step (the same file for every step of a 4-D NIfTI; empty for
        volumes in memory).
    array, component, nan_policy
        How each step is read (:func:`vtkillum.io.readers.read_volume`).
    """

    name: str
    kind: str
    times: list
    files: list = field(default_factory=list)
    array: str | None = None
    component: object = None
    nan_policy: str = "raise"
    volumes: list | None = None  # the steps of a series held in memory

    def __len__(self) -> int:
        return len(self.times)

    @property
    def is_series(self) -> bool:
        """True unless this is a single volume without a time axis."""
        return self.kind != "volume"

    @property
    def array_name(self) -> str:
        """Name of the point array in images of the steps: ``array``, else the name of the
        file (the first file of a file series) without directory, extensions and step
        number (``functional``, ``step``)."""
        if self.array:
            return self.array
        named = self.files[0] if self.kind == "files" else Path(self.name.rstrip("/"))
        stem = named.name.split(".")[0]
        stem = re.sub(r"[^A-Za-z0-9_-]+", "_", stem)
        stem = re.sub(r"[_-]*\d*$", "", stem).strip("_-")
        return stem or "scalars"

    def index(self, step: int) -> int:
        """``step`` as an index (negative counts from the end); ``ValueError`` if absent."""
        count = len(self)
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)):
            raise ValueError(f"{self.name}: a time step is an integer, got {step!r}")
        if not -count <= int(step) < count:
            if not self.is_series:
                raise ValueError(f"{self.name} is one volume, not a time series (a 4-D NIfTI, "
                                 "a .pvd or .series file, or several files); it has no time "
                                 f"step {step}")
            raise ValueError(f"{self.name}: time step {step} does not exist: the series has "
                             f"{count} steps, 0..{count - 1}")
        return int(step) % count

    def read(self, step: int) -> Volume:
        """The volume of ``step`` (an index, negative from the end)."""
        k = self.index(step)
        if self.volumes is not None:
            return self.volumes[k]
        path = self.files[k]
        time_step = k if self.kind == "nifti" else 0 if self.kind == "volume" else None
        if time_step is None and volume_format(path) == "nifti":
            inner = len(time_steps(path))
            if inner > 1:
                raise ValueError(f"{path} (step {k} of {self.name}) is itself a time series "
                                 f"of {inner} volumes; a series of files takes one volume per "
                                 "file")
        return read_volume(path, array=self.array, component=self.component,
                           nan_policy=self.nan_policy, time_step=time_step)

    def key(self, step: int) -> tuple:
        """What identifies the contents of ``step``: file, its state, step and reading
        options (for caches; a rewritten file gets a new key)."""
        k = self.index(step)
        if self.volumes is not None:
            return ("memory", id(self.volumes[k]), k)
        path = self.files[k]
        try:
            stat = path.stat()
            state = (stat.st_mtime_ns, stat.st_size)
        except OSError:
            state = None
        return (str(path.resolve()), state, k if self.kind == "nifti" else None, self.array,
                self.component, self.nan_policy)

    def label(self, step: int) -> str:
        """``step 3/20 (t = 6)`` or ``step 3/20 (step_003.vti)`` for messages."""
        k = self.index(step)
        where = (f"t = {self.times[k]:g}" if self.kind in ("nifti", "pvd", "series", "memory")
                 else self.files[k].name)
        return f"step {k}/{len(self)} ({where})"

    @classmethod
    def from_volumes(cls, steps, name: str = "series") -> TimeSeries:
        """A series of volumes in memory: ``steps`` a sequence of ``(time, Volume)``."""
        steps = sorted(((float(t), v) for t, v in steps), key=lambda s: s[0])
        if not steps:
            raise ValueError(f"{name}: a time series needs at least one step")
        for _, volume in steps:
            if not isinstance(volume, Volume):
                raise TypeError(f"{name}: steps must be (time, vtkillum Volume) pairs, got "
                                f"{type(volume).__name__}")
        _check_times(name, [t for t, _ in steps])
        return cls(name, "memory", [t for t, _ in steps], volumes=[v for _, v in steps])


def open_time_series(spec, array: str | None = None, component=None,
                     nan_policy: str = "raise") -> TimeSeries:
    """The time series ``spec`` names (module docstring), or a single volume as a series of
    one step of kind ``"volume"``.

    Parameters
    ----------
    spec : str, Path or sequence of them
        A file, a glob pattern, a directory, or several files (one step each).
    array, component, nan_policy
        How each step is read (:func:`vtkillum.io.readers.read_volume`).

    Raises
    ------
    FileNotFoundError
        A file (or every match of a pattern) is missing.
    ValueError
        A ``.pvd``/``.series`` file that cannot be parsed, a step file of an unknown
        format, files of several formats, a ``.pvd`` with several parts per time.
    """
    options = dict(array=array, component=component, nan_policy=nan_policy)
    if isinstance(spec, (list, tuple)):
        if len(spec) == 1:
            return open_time_series(spec[0], **options)
        if not spec:
            raise ValueError("no input files given")
        files = [Path(p) for p in spec]
        for path in files:
            if not path.exists():
                raise FileNotFoundError(f"{path}: no such file or directory")
        return _file_series(" ".join(str(p) for p in spec), files, **options)
    path = Path(spec)
    if not path.exists():
        if any(c in str(spec) for c in GLOB_CHARACTERS):
            matches = [Path(p) for p in glob.glob(str(spec))]
            if not matches:
                raise FileNotFoundError(f"{spec}: no file matches this pattern")
            return _file_series(str(spec), matches, **options)
        raise FileNotFoundError(f"{path}: no such file or directory")
    if path.is_dir() and volume_format(path) == "directory":
        return _directory_series(path, **options)
    fmt = volume_format(path)
    if fmt == "series":
        return _listed_series(path, **options)
    if fmt == "nifti":
        times = time_steps(path)
        if times:
            return TimeSeries(str(path), "nifti", times, [path] * len(times), **options)
    return TimeSeries(str(path), "volume", [0.0], [path], **options)


def _file_series(name: str, files, **options) -> TimeSeries:
    """One step per file, naturally ordered, times 0, 1, 2, ... (one file: that volume)."""
    files = sorted({Path(p) for p in files}, key=_natural_key)
    if len(files) == 1 and not files[0].is_dir():
        return open_time_series(files[0], **options)
    formats = {}
    for path in files:
        if path.is_dir():
            raise ValueError(f"{name}: {path} is a directory; a series of files takes one "
                             "volume file per step")
        formats.setdefault(volume_format(path), []).append(path)
    if "series" in formats:
        raise ValueError(f"{name}: {formats['series'][0]} lists a time series itself; give it "
                         "alone")
    if len(formats) > 1:
        raise ValueError(f"{name}: the files are of several formats ({', '.join(sorted(formats))}); "
                         "a series takes one file per step of one format (give a pattern such "
                         "as 'step_*.vti')")
    return TimeSeries(name, "files", [float(k) for k in range(len(files))], files, **options)


def _directory_series(directory: Path, **options) -> TimeSeries:
    """The one ``.pvd``/``.series`` file of ``directory``, else its volume files."""
    entries = sorted(p for p in directory.iterdir() if p.is_file() and not p.name.startswith("."))
    listed = [p for p in entries if _format_or_none(p) == "series"]
    if len(listed) == 1:
        return _listed_series(listed[0], **options)
    volumes = [p for p in entries if _format_or_none(p) not in (None, "series", "dicom")]
    if not volumes:
        raise ValueError(f"{directory} holds no volume files (and no DICOM series); supported: "
                         f"{', '.join(sorted(EXTENSIONS))}")
    extensions = {_extension(p) for p in volumes}
    if len(extensions) > 1:
        raise ValueError(f"{directory} holds volume files of several kinds "
                         f"({', '.join(sorted(extensions))}); give a pattern such as "
                         f"'{directory}/*{sorted(extensions)[0]}'")
    return _file_series(str(directory), volumes, **options)


def _listed_series(path: Path, **options) -> TimeSeries:
    """A ``.pvd`` collection or ParaView ``.series`` file: its ``(time, file)`` steps."""
    steps = _pvd_steps(path) if path.name.lower().endswith(".pvd") else _json_steps(path)
    if not steps:
        raise ValueError(f"{path} lists no data files")
    steps.sort(key=lambda s: s[0])
    times = [t for t, _ in steps]
    _check_times(str(path), times)
    files = []
    for _, name in steps:
        target = Path(name) if Path(name).is_absolute() else path.parent / name
        if not target.exists():
            raise FileNotFoundError(f"{path}: its data file {target} does not exist")
        if _format_or_none(target) in (None, "series"):
            raise ValueError(f"{path}: its data file {target} is not a volume file; "
                             "supported: .vti, .vtk, .nrrd, .mha/.mhd, .nii/.nii.gz")
        files.append(target)
    kind = "pvd" if path.name.lower().endswith(".pvd") else "series"
    return TimeSeries(str(path), kind, times, files, **options)


def _pvd_steps(path: Path) -> list:
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as err:
        raise ValueError(f"{path}: not a readable .pvd file ({err})") from None
    if root.tag != "VTKFile" or root.get("type") != "Collection":
        raise ValueError(f"{path}: not a VTK collection (.pvd) file: it must start with "
                         "<VTKFile type=\"Collection\">")
    steps, parts = [], set()
    for n, item in enumerate(root.iter("DataSet")):
        name = item.get("file")
        if not name:
            raise ValueError(f"{path}: DataSet {n} has no 'file' attribute")
        try:
            time = float(item.get("timestep", n))
        except ValueError:
            raise ValueError(f"{path}: DataSet {n} has timestep {item.get('timestep')!r}, "
                             "not a number") from None
        parts.add(item.get("part", "0"))
        steps.append((time, name))
    if len(parts) > 1:
        raise ValueError(f"{path} has {len(parts)} parts per time step; vtkillum renders one "
                         "image per step (a collection of one part)")
    return steps


def _json_steps(path: Path) -> list:
    try:
        data = json.loads(path.read_text())
        files = data["files"]
        return [(float(entry["time"]), str(entry["name"])) for entry in files]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError,
            ValueError) as err:
        raise ValueError(f"{path}: not a readable ParaView file series (.series): expected "
                         '{"files": [{"name": ..., "time": ...}, ...]} '
                         f"({type(err).__name__}: {err})") from None


def _check_times(name: str, times) -> None:
    values = np.asarray(times, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name}: the time steps must be finite numbers")
    if np.any(np.diff(values) <= 0):
        duplicate = values[1:][np.diff(values) <= 0][0]
        raise ValueError(f"{name}: two steps at time {duplicate:g}; each time holds one volume")


def _format_or_none(path: Path) -> str | None:
    try:
        return volume_format(path)
    except ValueError:
        return None


def _extension(path: Path) -> str:
    name = path.name.lower()
    for ext in sorted(EXTENSIONS, key=len, reverse=True):
        if name.endswith(ext):
            return ext
    return path.suffix.lower()


def _natural_key(path: Path):
    """``step_2`` before ``step_10``: digit runs compare as numbers."""
    parts = re.split(r"(\d+)", str(path))
    return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in parts]


#: Name of the threads of :class:`StepPrefetcher`.
PREFETCH_THREAD_NAME = "vtkillum-prefetch"


class StepPrefetcher:
    """Reads the steps of a series ahead of their use, on one background thread.

    While the consumer works on step ``t`` (renders it, computes its light volume), the
    thread reads the steps the consumer names as next, so that a series plays at the
    rate of the slower of reading and computing instead of their sum::

        with StepPrefetcher(series.read, ahead=1) as steps:
            for n, k in enumerate(order):
                volume = steps.take(k, then=order[n + 1:n + 2])  # k + 1 read meanwhile
                compute(volume)

    Parameters
    ----------
    read : callable
        ``read(step) -> value``, e.g. :meth:`TimeSeries.read`. It runs on the thread, one
        step at a time, in the order the steps were asked for: two steps are never read
        at once (a reader need not be thread-safe, only callable from another thread).
    ahead : int
        How many steps may be read ahead of the one taken (default 1). ``0``: no thread;
        :meth:`take` reads the step itself, as if there were no prefetcher.
    prepare : callable, optional
        ``prepare(value)``, called on the thread after each read, before the value is
        handed over: work the consumer would otherwise do first on each step (the command
        line computes the volume's value range and content hash and converts it to the
        render's units, :func:`vtkillum.cli.render_preparation`). Its return value is not
        used. It must not use warp: warp's graph capture is per device, not per thread,
        so device work queued here could be recorded into a graph the consumer captures. An exception in it is dropped: it may only move work earlier, never change
        what the consumer gets, so the consumer repeats the work and meets the error
        itself.

    Notes
    -----
    Results and errors are exactly those of reading without a prefetcher: :meth:`take`
    returns the value ``read`` returned, or raises the exception ``read`` raised for that
    step (the same object), when that step is taken, not earlier: the steps before an
    unreadable one are all handed over first.

    Memory: at most ``ahead`` values besides the one taken are held (each :meth:`take`
    drops values read for steps it does not name, and cancels their reads not begun).

    Cancellation: :meth:`close` (also on leaving a ``with`` block, whatever the exception,
    Ctrl-C and :class:`~vtkillum.io.writers.Terminated` included) cancels the reads not
    begun and waits for the one under way, so that no thread is left behind. A read
    cannot be interrupted: a second Ctrl-C interrupts that wait, and the thread (a daemon)
    ends with the process. Signals are handled on the main thread only (Python's rule),
    so the thread never receives them.

    The thread runs only while there are steps to read: it ends when it has read what
    was asked for, and the next :meth:`take` starts another, so a prefetcher nobody
    closes (a source dropped by a pipeline) holds no thread either.

    :attr:`reads` counts the reads done (on the thread or in :meth:`take`).
    """

    def __init__(self, read, ahead: int = 1, prepare=None) -> None:
        if isinstance(ahead, bool) or not isinstance(ahead, (int, np.integer)) or ahead < 0:
            raise ValueError(f"prefetch: the steps read ahead must be a whole number >= 0, "
                             f"got {ahead!r}")
        self._read = read
        self._prepare = prepare
        self.ahead = int(ahead)
        self._futures: dict = {}  # step -> Future, in the order asked for
        self._queue: collections.deque = collections.deque()  # (step, Future) not begun
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None  # the thread while it reads
        self._started: threading.Thread | None = None  # the last thread started
        self._closed = False
        #: Steps read so far.
        self.reads = 0

    # --- use -----------------------------------------------------------------------------
    def take(self, step, then=()):
        """The value of ``step``; ``then``, at most :attr:`ahead` of them, are read next.

        Waits for ``step``'s read (started now if it was not asked for before); raises
        what ``read`` raised for it. Reads of steps other than ``step`` and ``then`` are
        dropped.
        """
        then = [k for k in then if k != step][:self.ahead]
        if self.ahead == 0:
            return self._load(step, prepare=False)
        if self._closed:
            raise RuntimeError("StepPrefetcher: take() after close()")
        with self._lock:
            keep = {step, *then}
            for k in [k for k in self._futures if k not in keep]:
                self._futures.pop(k).cancel()  # a read not begun is dropped; a done one freed
            self._queue = collections.deque(
                (k, f) for k, f in self._queue if not f.cancelled())
            for k in (step, *then):
                self._schedule(k)
            future = self._futures.pop(step)
        return future.result()

    def close(self) -> None:
        """Cancel the reads not begun, wait for the one under way, end the thread."""
        with self._lock:
            self._closed = True
            for future in self._futures.values():
                future.cancel()
            self._futures.clear()
            self._queue.clear()
            thread = self._started  # the last thread started, ending or ended
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def pending(self) -> list:
        """The steps asked for and not taken (read, being read or waiting)."""
        with self._lock:
            return list(self._futures)

    # --- the thread ----------------------------------------------------------------------
    def _schedule(self, step) -> None:
        """Ask for ``step`` (with ``_lock`` held)."""
        if step in self._futures:
            return
        future = Future()
        self._futures[step] = future
        self._queue.append((step, future))
        if self._thread is None:
            self._thread = self._started = threading.Thread(
                target=self._work, name=PREFETCH_THREAD_NAME, daemon=True)
            self._thread.start()

    def _work(self) -> None:
        """Read the steps asked for, in order; end when there are none (a later request
        starts a new thread), so that an idle prefetcher holds no thread."""
        while True:
            with self._lock:
                if self._closed or not self._queue:
                    if self._thread is threading.current_thread():
                        self._thread = None
                    return
                step, future = self._queue.popleft()
                if not future.set_running_or_notify_cancel():
                    continue  # dropped before its read began
            try:
                value = self._load(step, prepare=True)
            except BaseException as err:  # noqa: BLE001 - handed to the consumer as is
                future.set_exception(err)
            else:
                future.set_result(value)
            value = future = None  # held by the consumer's future only

    def _load(self, step, prepare: bool):
        value = self._read(step)
        self.reads += 1
        if prepare and self._prepare is not None:
            # Its errors are dropped: it only moves work earlier (class docstring).
            with contextlib.suppress(Exception):
                self._prepare(value)
        return value


class TimeSeriesSource(VTKPythonAlgorithmBase):
    """A time series as a VTK source: one ``vtkImageData`` per time step (``TIME_STEPS``).

    Parameters
    ----------
    series : TimeSeries, str, Path or sequence, optional
        A :class:`TimeSeries`, or what :func:`open_time_series` opens; also settable with
        :meth:`SetFileName` / :meth:`SetSeries`.
    array, component, nan_policy
        How steps are read when ``series`` is opened here.
    prefetch : int
        Steps read ahead on a background thread (:class:`StepPrefetcher`): after serving
        step ``k`` the source reads ``k + 1 .. k + prefetch`` while the pipeline works on
        ``k``, so that a series played forward (ParaView's Play, a loop over
        :meth:`GetTimeSteps`) waits for reading only when reading is the slower. Default
        0 (read each step when asked for): a pipeline that jumps between times would read
        steps it never uses, and each step read ahead holds its volume in memory.
        :meth:`SetPrefetch` changes it.

    Notes
    -----
    Output: point scalars (float32) named :attr:`TimeSeries.array_name`, on the grid of
    the step's file (origin, spacing, direction matrix as
    :func:`~vtkillum.io.readers.read_volume` gives them), stamped with the step's time
    (``DATA_TIME_STEP``). Every step must have the first step's dimensions (a VTK
    pipeline announces one extent); a step that differs is an error naming it. The image
    of the last step read is kept, so repeated requests for one time read nothing;
    downstream illumination filters keep their outputs per time step, and on their
    cache hits this source does not execute at all. :attr:`reads` counts the steps read.
    Errors (a missing or unreadable step) are reported the VTK way (``ErrorEvent``
    observers, else the output window), the output left empty, and kept in
    :attr:`last_error`.

    Examples
    --------
    >>> source = TimeSeriesSource("functional.nii")          # doctest: +SKIP
    >>> light = LightTransmittanceFilter()                    # doctest: +SKIP
    >>> light.SetInputConnection(source.GetOutputPort())      # doctest: +SKIP
    >>> for t in source.GetTimeSteps():                       # doctest: +SKIP
    ...     illumination = light.execute(time=t)
    """

    def __init__(self, series=None, array: str | None = None, component=None,
                 nan_policy: str = "raise", prefetch: int = 0) -> None:
        super().__init__(nInputPorts=0, nOutputPorts=1, outputType="vtkImageData")
        self._options = dict(array=array, component=component, nan_policy=nan_policy)
        self._series: TimeSeries | None = None
        self._prefetch = 0
        self._prefetcher: StepPrefetcher | None = None
        self._last = None  # (key, image) of the last step read
        self._dims = None  # the first step's dimensions, announced to the pipeline
        #: Steps read from files (or taken from memory) so far.
        self.reads = 0
        #: The error of the last request, or None.
        self.last_error: Exception | None = None
        self.SetPrefetch(prefetch)
        if series is not None:
            self.SetSeries(series)

    # --- properties --------------------------------------------------------------------------
    def SetSeries(self, series) -> None:
        """The series to serve: a :class:`TimeSeries` or what :func:`open_time_series` opens."""
        if not isinstance(series, TimeSeries):
            series = open_time_series(series, **self._options)
        self._series = series
        self._last = None
        self._stop_prefetch()
        self.Modified()

    def SetPrefetch(self, steps: int) -> None:
        """Steps to read ahead of the one served (0: none); see the class docstring."""
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
            raise ValueError(f"TimeSeriesSource: prefetch must be a whole number >= 0, got "
                             f"{steps!r}")
        if int(steps) != self._prefetch:
            self._prefetch = int(steps)
            self._stop_prefetch()  # not Modified(): the output does not change

    def GetPrefetch(self) -> int:
        return self._prefetch

    def _stop_prefetch(self) -> None:
        if self._prefetcher is not None:
            self._prefetcher.close()
            self._prefetcher = None

    def SetFileName(self, name) -> None:
        """Open ``name`` (a file, pattern or directory) as the series to serve."""
        self.SetSeries(str(name))

    def GetSeries(self) -> TimeSeries | None:
        return self._series

    def GetTimeSteps(self) -> list:
        """The times of the steps (``[]`` before a series is set)."""
        return list(self._series.times) if self._series is not None else []

    # --- steps -------------------------------------------------------------------------------
    def image(self, step: int) -> vtkImageData:
        """The image of ``step`` (an index): what the output holds at that step's time."""
        from vtkillum.io.convert import image_data_from_volume

        series = self._require_series()
        key = series.key(step)
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        volume = self._read(series, series.index(step), key)
        image = image_data_from_volume(volume, series.array_name)
        self._last = (key, image)
        return image

    def _read(self, series: TimeSeries, k: int, key) -> Volume:
        """The volume of step ``k``: read now, or by the prefetcher (then ``k + 1 ..`` are
        read next), and read again if its file changed since (another ``key``)."""
        if self._prefetch == 0:
            self.reads += 1
            return series.read(k)
        if self._prefetcher is None:
            def read(step):
                self.reads += 1
                return series.key(step), series.read(step)

            self._prefetcher = StepPrefetcher(read, self._prefetch)
        then = range(k + 1, min(k + 1 + self._prefetch, len(series)))
        read_key, volume = self._prefetcher.take(k, then)
        if read_key != key:  # rewritten after its read: what the file holds now
            self.reads += 1
            volume = series.read(k)
        return volume

    def volume(self, step: int) -> Volume:
        """The :class:`Volume` of ``step`` (an index)."""
        return self._require_series().read(step)

    def _require_series(self) -> TimeSeries:
        if self._series is None:
            raise ValueError("TimeSeriesSource has no series: call SetSeries or SetFileName")
        return self._series

    # --- pipeline ----------------------------------------------------------------------------
    def RequestInformation(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        try:
            first = self.image(0)
        except Exception as err:  # noqa: BLE001 - VTK swallows exceptions: report it
            # Reported once, here; an empty extent and success keep VTK's executive from
            # adding its request dumps (as the ParaView plugin's reader does).
            info.Set(SDDP.WHOLE_EXTENT(), (0, -1, 0, -1, 0, -1), 6)
            info.Remove(SDDP.TIME_STEPS())
            info.Remove(SDDP.TIME_RANGE())
            return self._fail(err)
        self._dims = first.GetDimensions()  # what every step must have (RequestData)
        info.Set(SDDP.WHOLE_EXTENT(), first.GetExtent(), 6)
        info.Set(vtkDataObject.ORIGIN(), first.GetOrigin(), 3)
        info.Set(vtkDataObject.SPACING(), first.GetSpacing(), 3)
        matrix = first.GetDirectionMatrix()
        info.Set(vtkDataObject.DIRECTION(),
                 tuple(matrix.GetElement(r, c) for r in range(3) for c in range(3)), 9)
        times = self._series.times
        if self._series.is_series:
            info.Set(SDDP.TIME_STEPS(), times, len(times))
            info.Set(SDDP.TIME_RANGE(), [times[0], times[-1]], 2)
        else:  # one volume: not time dependent
            info.Remove(SDDP.TIME_STEPS())
            info.Remove(SDDP.TIME_RANGE())
        return 1

    def RequestData(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        output = vtkImageData.GetData(info)
        series = self._series
        try:
            series = self._require_series()
            k = 0
            if info.Has(SDDP.UPDATE_TIME_STEP()):
                k = step_at(series.times, info.Get(SDDP.UPDATE_TIME_STEP()))
            image = self.image(k)
            if self._dims is not None and image.GetDimensions() != self._dims:
                raise ValueError(f"{series.name}: {series.label(k)} has dimensions "
                                 f"{image.GetDimensions()}, the first step {self._dims}; the "
                                 "steps of a series served to a VTK pipeline must share one "
                                 "grid")
        except Exception as err:  # noqa: BLE001 - VTK swallows exceptions: report it
            output.Initialize()
            return self._fail(err)  # an empty output and the message only
        output.ShallowCopy(image)
        output.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(), series.times[k])
        self.last_error = None
        return 1

    def _fail(self, err: Exception) -> int:
        """Report ``err`` in one line; 1 (VTK would add request dumps to a failure)."""
        self.last_error = err
        message = f"TimeSeriesSource: {' '.join(str(err).split()) or type(err).__name__}"
        if self.HasObserver("ErrorEvent"):
            self.InvokeEvent("ErrorEvent", message)
        else:
            vtkOutputWindow.GetInstance().DisplayErrorText(message + "\n")
        return 1


__all__ = ["StepPrefetcher", "TimeSeries", "TimeSeriesSource", "open_time_series", "step_at"]
