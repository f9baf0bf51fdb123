"""Writing output files all-or-nothing, under their final names, through signals and full disks.

Every file vtkillum writes (pictures, radiance arrays, scene files, exported volumes) goes
through :func:`write_staged`:

1. a hidden staging directory is made next to each final file (``.NAME.XXXX.tmp/``) and
   the files are written there **under their final names**, so that a format whose
   header names a companion file (MetaImage ``ct.mhd`` -> ``ElementDataFile = ct.raw``)
   names the final file, and copying the pair elsewhere works;
2. only when every file is complete are they renamed into place, in the order given
   (data files before the header that names them), with SIGINT, SIGTERM and SIGHUP held
   back so that a signal cannot fall between the renames of a pair;
3. the staging directories are removed whatever happens: an exception, Ctrl-C, a full
   disk (reported in one line by :class:`DiskFullError`), SIGTERM or SIGHUP. While files
   are written, those two signals raise :class:`Terminated` (a ``SystemExit`` with the
   conventional status 128 + signal number) instead of killing the process outright, so
   the clean-up runs; a signal that was set to be ignored (``nohup``) or handled by the
   program stays so.

The old files are kept until the renames: a failed or interrupted write leaves them as
they were and nothing hidden behind.
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import stat
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

#: Signals that end a program politely (``timeout``, batch schedulers, a closed terminal):
#: while files are written they raise :class:`Terminated`, so the clean-up runs.
TERMINATING_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP")
                            if hasattr(signal, name))

#: Volume formats :func:`write_volume` writes (by extension, case-insensitive).
VOLUME_FORMATS = (".vti", ".nii", ".nii.gz", ".mha", ".mhd")

#: Errors that mean the disk (or the quota) is full.
_DISK_FULL = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}

#: RAS <-> LPS: negate x and y.
_FLIP_XY = np.diag([-1.0, -1.0, 1.0])


class Terminated(SystemExit):
    """SIGTERM or SIGHUP arrived while files were written; the partial files are removed.

    A ``SystemExit`` whose ``code`` is the conventional exit status ``128 + signum`` (143
    for SIGTERM, 129 for SIGHUP): uncaught, the program ends with that status after its
    ``finally`` blocks have run.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(128 + int(signum))
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


class DiskFullError(OSError):
    """No space left on the device (or the quota is exhausted) while writing ``paths``.

    Its message is one line for the user; nothing was written and existing files are kept.
    """

    def __init__(self, paths, cause: OSError | None = None) -> None:
        code = cause.errno if cause is not None and cause.errno in _DISK_FULL else errno.ENOSPC
        names = ", ".join(str(p) for p in paths)
        super().__init__(code, f"cannot write {names}: no space left on device (nothing was "
                               "written; existing files are kept)")

    def __str__(self) -> str:
        return self.strerror


@contextmanager
def terminating_raises():
    """Within the block SIGTERM and SIGHUP raise :class:`Terminated` (main thread only).

    Only signals at their default action are taken over: an ignored signal (``nohup``)
    or a handler the program installed stays as it is. The previous handlers come back
    on leaving the block.
    """
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in TERMINATING_SIGNALS:
            if signal.getsignal(signum) is signal.SIG_DFL:
                previous[signum] = signal.signal(signum, _raise_terminated)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _raise_terminated(signum, frame):
    raise Terminated(signum)


@contextmanager
def signals_held():
    """Hold back SIGINT, SIGTERM and SIGHUP for a short block (renames, clean-up); they are
    delivered when it ends. Where the platform cannot (no ``pthread_sigmask``) a no-op."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    held = {signal.SIGINT, *TERMINATING_SIGNALS}
    before = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def write_staged(paths, write) -> list[Path]:
    """Write the files ``paths`` all-or-nothing under their final names (module docstring).

    Parameters
    ----------
    paths : sequence of path-like
        The final files, in the order they are renamed into place (companion data
        files before a header that names them).
    write : callable
        ``write(staged)`` with ``staged`` a dict final path -> staging path (same file
        name, in a hidden directory next to the final file); it must write every one.

    Returns
    -------
    list of Path
        ``paths``.

    Raises
    ------
    DiskFullError
        No space left on the device: nothing written, old files kept.
    Terminated
        SIGTERM or SIGHUP during the write: nothing written, old files kept.
    OSError
        Another failure, or ``write`` left a file out; nothing written.
    """
    finals = [Path(p) for p in paths]
    staging: dict[Path, Path] = {}
    with terminating_raises():
        try:
            staged = {}
            for final in finals:
                parent = final.parent
                if parent not in staging:
                    with signals_held():  # made and recorded at once: never left behind
                        staging[parent] = Path(tempfile.mkdtemp(
                            dir=parent, prefix=f".{final.name}.", suffix=".tmp"))
                staged[final] = staging[parent] / final.name
            write(staged)
            for final in finals:
                if not staged[final].is_file():
                    raise OSError(f"{final}: the file was not written")
                os.chmod(staged[final], file_mode(final))
            with signals_held():  # a pair is replaced together
                for final in finals:
                    os.replace(staged[final], final)
        except OSError as err:
            if err.errno in _DISK_FULL and not isinstance(err, DiskFullError):
                raise DiskFullError(finals, err) from err
            raise
        finally:
            with signals_held():
                for directory in staging.values():
                    shutil.rmtree(directory, ignore_errors=True)
    return finals


def write_atomically(jobs) -> list[Path]:
    """Write files all-or-nothing: ``jobs`` is a list of ``(path, write(binary_file))``.

    Through :func:`write_staged`: a failure, Ctrl-C, SIGTERM or SIGHUP while writing
    leaves the old files untouched and nothing hidden behind; a full disk raises
    :class:`DiskFullError`. A symbolic link is written through (its target is replaced),
    like ``cp``. New files get the usual permissions (0666 less the umask); a replaced
    file keeps its own. Returns the paths as given.
    """
    jobs = [(Path(path), job) for path, job in jobs]
    finals = [Path(os.path.realpath(path)) if path.is_symlink() else path for path, _ in jobs]

    def write(staged):
        for (_, job), final in zip(jobs, finals):
            with open(staged[final], "wb") as f:
                job(f)

    write_staged(finals, write)
    return [path for path, _ in jobs]


def file_mode(path: Path) -> int:
    """The permissions of ``path`` when it exists, else 0666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def volume_files(path) -> list[Path]:
    """The files :func:`write_volume` writes for ``path``, in the order they are replaced:
    ``name.raw`` then ``name.mhd`` for MetaImage with a separate data file, else ``path``."""
    path = Path(path)
    if path.name.lower().endswith(".mhd"):
        return [path.with_suffix(".raw"), path]
    return [path]


def write_volume(volume, path, frame: str | None = "LPS") -> Path:
    """Write ``volume`` as .vti, .nii/.nii.gz or .mha/.mhd (by extension), all-or-nothing.

    ``frame`` is the anatomical frame of ``volume``'s world coordinates (``"RAS"`` for
    the built-in datasets, ``"LPS"`` for what the medical readers return, ``None``:
    none). NIfTI and MetaImage files are written in their conventions (NIfTI: RAS in
    the s- and q-form; MetaImage: LPS), so that :func:`vtkillum.io.readers.read_volume`
    reads back the same voxels at the same anatomical places (in LPS); ``None`` is
    written as if LPS, which keeps the coordinates unchanged on reading back. .vti
    keeps the world coordinates as they are.

    ``.mhd`` writes the header and its data file ``name.raw`` next to it; the header
    names ``name.raw`` (relative), so the pair can be copied elsewhere. The files go
    through :func:`write_staged` (old files kept on any failure, nothing hidden left).
    """
    from vtkillum.io.convert import image_data_from_volume

    path = Path(path)
    name = path.name.lower()
    if not name.endswith(VOLUME_FORMATS):
        raise ValueError(f"output {str(path)!r}: the extension must be one of "
                         f"{', '.join(VOLUME_FORMATS)}")
    image = image_data_from_volume(volume, "scalars")
    direction = np.asarray(volume.direction, dtype=np.float64)
    origin = np.asarray(volume.origin, dtype=np.float64)
    if frame is not None and str(frame).upper() == "RAS" and not name.endswith(".vti"):
        direction, origin = _FLIP_XY @ direction, _FLIP_XY @ origin  # to LPS
    if name.endswith(".vti"):
        from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

        writer = vtkXMLImageDataWriter()
        writer.SetDataModeToAppended()
        writer.SetCompressorTypeToZLib()
    elif name.endswith((".mha", ".mhd")):
        from vtkmodules.vtkIOImage import vtkMetaImageWriter

        image.SetOrigin(*origin)
        image.SetDirectionMatrix(*direction.ravel())
        writer = vtkMetaImageWriter()
        writer.SetCompression(name.endswith(".mha"))
    else:
        from vtkmodules.vtkCommonMath import vtkMatrix4x4
        from vtkmodules.vtkIOImage import vtkNIFTIImageWriter

        # The NIfTI writer takes the grid without placement plus the RAS affine.
        image.SetOrigin(0.0, 0.0, 0.0)
        image.SetDirectionMatrix(1, 0, 0, 0, 1, 0, 0, 0, 1)
        affine = np.eye(4)
        affine[:3, :3] = _FLIP_XY @ direction
        affine[:3, 3] = _FLIP_XY @ origin
        matrix = vtkMatrix4x4()
        for r in range(4):
            for c in range(4):
                matrix.SetElement(r, c, affine[r, c])
        writer = vtkNIFTIImageWriter()
        writer.SetSFormMatrix(matrix)
        if np.linalg.det(affine[:3, :3]) > 0:
            writer.SetQFormMatrix(matrix)
    writer.SetInputData(image)
    files = volume_files(path)

    def write(staged):
        # VTK picks the format by a lower-case extension (CT.MHA came out as CT.mhd +
        # CT.raw, CT.NII.GZ uncompressed): write that name, then take the one asked for.
        written = _lower_extension(staged[path])
        writer.SetFileName(str(written))
        if len(files) == 2:  # after SetFileName, which resets it; named relative to the header
            writer.SetRAWFileName(str(staged[files[0]]))
        run_writer(writer, path)
        if written != staged[path]:
            os.replace(written, staged[path])

    write_staged(files, write)
    return path


def _lower_extension(path: Path) -> Path:
    """``path`` with its volume-format extension in lower case (``CT.NII.GZ`` -> ``CT.nii.gz``)."""
    for suffix in VOLUME_FORMATS:
        if path.name.lower().endswith(suffix):
            return path.with_name(path.name[: -len(suffix)] + suffix)
    return path


def run_writer(writer, path) -> None:
    """``writer.Write()`` for a VTK writer, its error code raised as ``OSError`` (ENOSPC
    for VTK's out-of-disk-space error), and an empty file refused."""
    from vtkmodules.vtkCommonMisc import vtkErrorCode

    writer.Write()
    code = writer.GetErrorCode()
    if code == vtkErrorCode.OutOfDiskSpaceError:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    name = writer.GetFileName()
    if code or not name or not os.path.exists(name) or os.path.getsize(name) == 0:
        reason = f" ({vtkErrorCode.GetStringFromErrorCode(code)})" if code else ""
        raise OSError(f"{path}: {writer.GetClassName()} could not write the file{reason}")
