"""Read volume files into a :class:`~vtkillum.core.volume.Volume`.

Supported inputs (by extension, case-insensitive):

=====================  ================================================================
``.vti``               VTK XML image data (``vtkXMLImageDataReader``)
``.vtk``               VTK legacy data set (``vtkDataSetReader``)
``.nrrd``, ``.nhdr``   NRRD, attached or detached header (parsed here, see below)
``.mha``, ``.mhd``     MetaImage (``vtkMetaImageReader``)
``.nii``, ``.nii.gz``  NIfTI-1/2 (``vtkNIFTIImageReader``)
directory, ``.dcm``    a DICOM series: every DICOM file of the directory, or of the
                       directory that holds the given DICOM file (``.dcm`` or any file with
                       the DICOM Part-10 preamble) (``vtkDICOMImageReader``)
=====================  ================================================================

World coordinates
-----------------
Each volume keeps the physical placement its file records (origin, spacing and
the direction matrix), so that a scene file's camera and lights mean the same
thing for every copy of a dataset. For the medical formats one convention is
used, **LPS** (+x towards the patient's left, +y posterior, +z superior), the
convention of DICOM, ITK and MetaImage:

- NIfTI stores RAS coordinates: the qform/sform is applied and then x and y are
  negated (as ITK does), so a NIfTI and a DICOM copy of a scan coincide. The
  sform is used when present (the NIfTI "aligned" transform), else the qform,
  else the voxel sizes alone; ``scl_slope``/``scl_inter`` are applied. Lengths
  are taken in the file's units (``xyzt_units``, almost always millimetres).
- NRRD files are parsed here rather than with ``vtkNrrdReader``, which ignores
  ``space directions`` other than their lengths, guesses that a fastest axis of
  nine or fewer samples holds vector components, and flips rows for LAS spaces.
  Here ``space directions`` give the full direction matrix, ``kinds`` (or a
  ``none`` direction) mark a component axis, and RAS/LAS spaces are converted
  to LPS; other spaces (``3D-right-handed``, ``scanner-xyz``, none) are kept.
- DICOM: the position and orientation of every slice (Image Position/Orientation
  (Patient)) give the geometry; grid index i runs along the rows, j down the
  columns and k along the slice normal (row × column), the layout ITK uses.
  Rescale slope/intercept are applied (by the VTK reader). Slices must be
  evenly spaced and not tilted.
- ``.vti``, ``.vtk`` and MetaImage geometry is used as stored.

Time
----
A 4-D NIfTI (``dim[4]`` > 1) holds one volume per time step, at times
``toffset + t * pixdim[4]`` (``t`` when ``pixdim[4]`` is not positive) in the file's time
unit: :func:`time_steps` lists them and ``read_volume(path, time_step=t)`` reads volume
``t`` on the geometry and with the scaling of the first. Without ``time_step`` the first
volume is read and a :class:`TimeStepWarning` says so. The whole file is read once per
file state and kept (one file at a time), so stepping through it reads no more. A
``.pvd`` collection or a ParaView ``.series`` file lists one volume file per time step:
:func:`time_steps` and ``read_volume(..., time_step=)`` read them too, through
:mod:`vtkillum.io.time_series`, which also reads series of files (a glob pattern, a
directory) and serves any series to a VTK pipeline with ``TIME_STEPS``. The CLI, the
Python API and the ParaView plugin's reader all go through these functions, so they
agree on the times and the values of every step.
"""

from __future__ import annotations

import bz2
import functools
import gzip
import re
import warnings
import zlib
from pathlib import Path

import numpy as np

from vtkillum.core.volume import Volume

#: Extension -> format name (``.nii.gz`` is matched before ``.gz`` alone).
EXTENSIONS = {
    ".vti": "vti",
    ".vtk": "vtk",
    ".nrrd": "nrrd",
    ".nhdr": "nrrd",
    ".mha": "metaimage",
    ".mhd": "metaimage",
    ".nii": "nifti",
    ".nii.gz": "nifti",
    ".dcm": "dicom",
    ".pvd": "series",
    ".series": "series",
}

SUPPORTED = (".vti, .vtk, .nrrd/.nhdr, .mha/.mhd, .nii/.nii.gz, or a DICOM directory "
             "(or a .dcm file in one); time series: a 4-D .nii/.nii.gz, a .pvd or .series "
             "file")


class TimeStepWarning(UserWarning):
    """A file holding several time steps was read without ``time_step``: its first step."""

#: RAS -> LPS (and LPS -> RAS): negate x and y.
RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0])


def read_volume(path, array: str | None = None, component: int | None = None,
                nan_policy: str = "raise", time_step: int | None = None) -> Volume:
    """Read a volume file (or a DICOM directory) as a :class:`Volume`.

    Parameters
    ----------
    path : str or Path
        File or DICOM directory; see the module docstring for the formats and
        how their coordinates are interpreted.
    array : str, optional
        Name of the point- or cell-data array to use (default: the active
        scalars, else the first array).
    component : int or "magnitude", optional
        Component of a multi-component array (required for those), or
        ``"magnitude"`` for the norm of each tuple; see
        :func:`vtkillum.io.convert.volume_from_image_data`.
    nan_policy : {"raise", "fill"}
        What to do with NaN/Inf samples (see :class:`Volume`).
    time_step : int, optional
        Step of a time series (a 4-D NIfTI, a ``.pvd`` or ``.series`` file), counted
        from 0; negative counts from the end. Default: the first step, with a
        :class:`TimeStepWarning` when the file holds several. A file of one volume
        takes only 0 (or -1).

    Returns
    -------
    Volume

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        Unknown extension, unreadable file, data that cannot form a volume, or a
        ``time_step`` the file does not have; the message names the file and what to do.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    fmt = volume_format(path)
    if fmt == "series":
        from vtkillum.io.time_series import open_time_series

        series = open_time_series(path, array=array, component=component,
                                  nan_policy=nan_policy)
        return series.read(_step_or_first(path, time_step, len(series)))
    if fmt == "nifti":
        return _read_nifti(path, array, component, nan_policy, time_step)
    _step_or_first(path, time_step, 1)
    if fmt == "dicom":
        return _read_dicom(path if path.is_dir() else path.parent, array, component, nan_policy)
    if path.is_dir():
        raise ValueError(f"{path} is a directory but holds no DICOM files; supported: {SUPPORTED}")
    reader = _READERS[fmt]
    return reader(path, array, component, nan_policy)


def time_steps(path) -> list[float]:
    """Times of the steps of a time-series file, ``[]`` for a file of one volume.

    A 4-D NIfTI: ``toffset + t * pixdim[4]`` (``t`` when ``pixdim[4]`` is not positive),
    in the file's time unit (``xyzt_units``, usually seconds). A ``.pvd`` or ``.series``
    file: the times it lists (:func:`vtkillum.io.time_series.open_time_series`). Anything
    else (or a file whose header cannot be read: :func:`read_volume` reports that) has
    none.
    """
    path = Path(path)
    try:
        fmt = volume_format(path)
    except ValueError:
        return []
    if fmt == "series":
        from vtkillum.io.time_series import open_time_series

        return list(open_time_series(path).times)
    if fmt != "nifti" or not path.is_file():
        return []
    header = _nifti_header(path)
    if header is None or header[0] <= 1:
        return []
    count, step, offset = header
    return [offset + t * (step if step > 0 else 1.0) for t in range(count)]


def _step_or_first(path, time_step, count: int, stacklevel: int = 3) -> int:
    """``time_step`` as an index into ``count`` steps (negative from the end); ``None`` is
    0, with a :class:`TimeStepWarning` when there are several."""
    if time_step is None:
        if count > 1:
            warnings.warn(f"{path} holds {count} time steps; reading the first (give "
                          f"time_step=0..{count - 1} to choose one, or read all with "
                          "vtkillum.io.time_series.open_time_series)", TimeStepWarning,
                          stacklevel=stacklevel)
        return 0
    if isinstance(time_step, bool) or not isinstance(time_step, (int, np.integer)):
        raise ValueError(f"{path}: time_step must be an integer, got {time_step!r}")
    index = int(time_step)
    if not -count <= index < count:
        if count == 1:
            raise ValueError(f"{path}: time step {index} does not exist: the file holds one "
                             "volume, not a time series (time step 0 is the only one)")
        raise ValueError(f"{path}: time step {index} does not exist: the file holds {count} "
                         f"time steps, 0..{count - 1}")
    return index % count


def volume_format(path) -> str:
    """Format name of ``path`` (see :data:`EXTENSIONS`); a directory is ``"dicom"``.

    Raises ``ValueError`` listing the supported formats for an unknown extension.
    """
    path = Path(path)
    name = path.name.lower()
    if path.is_dir():
        return "dicom" if _dicom_files(path) else "directory"
    for ext in sorted(EXTENSIONS, key=len, reverse=True):
        if name.endswith(ext):
            return EXTENSIONS[ext]
    if path.is_file() and _is_dicom_file(path):  # DICOM files often have no extension
        return "dicom"
    suffix = "".join(path.suffixes[-2:]) or "(none)"
    raise ValueError(f"{path}: unknown volume format {suffix!r}; supported: {SUPPORTED}")


# --- VTK readers --------------------------------------------------------------------------------
def _read_vti(path, array, component, nan_policy):
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    return _convert(_run_reader(reader, path), path, array, component, nan_policy)


def _read_vtk(path, array, component, nan_policy):
    from vtkmodules.vtkIOLegacy import vtkDataSetReader

    reader = vtkDataSetReader()
    reader.ReadAllScalarsOn()
    reader.ReadAllVectorsOn()
    reader.ReadAllFieldsOn()
    return _convert(_run_reader(reader, path), path, array, component, nan_policy)


def _read_metaimage(path, array, component, nan_policy):
    from vtkmodules.vtkIOImage import vtkMetaImageReader

    reader = vtkMetaImageReader()
    return _convert(_run_reader(reader, path), path, array, component, nan_policy)


def _read_nifti(path, array, component, nan_policy, time_step=None):
    from vtkmodules.vtkIOImage import vtkNIFTIImageReader

    header = _nifti_header(path)
    count = header[0] if header is not None else 1
    index = _step_or_first(path, time_step, count, stacklevel=4)
    if count > 1:
        stat = Path(path).stat()
        reader, image = _nifti_all_steps(str(path), stat.st_mtime_ns, stat.st_size)
        image = _nifti_step_image(image, index, count)
    else:
        reader = vtkNIFTIImageReader()
        image = _run_reader(reader, path)
    try:
        volume = _convert(image, path, array, component, nan_policy)
    except ValueError as err:
        if count > 1 and component is not None and "component" in str(err):
            # A 4-D file's volumes are time steps, not components: say which option picks one.
            raise ValueError(f"{err} (its {count} volumes are time steps, not components: "
                             f"choose one with time_step / --time-step 0..{count - 1})") from err
        raise
    header = reader.GetNIFTIHeader()
    slope, inter = header.GetSclSlope(), header.GetSclInter()
    if slope not in (0.0, 1.0) or inter != 0.0:
        # NIfTI: slope 0 means "no scaling".
        scalars = volume.scalars * np.float32(slope if slope != 0.0 else 1.0) + np.float32(inter)
        volume = _rebuild(volume, scalars=scalars, nan_policy=nan_policy)
    # vtkNIFTIImageReader outputs the raw grid; its s/q-form maps VTK data coordinates
    # (origin + spacing * ijk, after it reversed the slices when qfac = -1) to RAS.
    # The reader's output has an identity direction, so world = M (origin + spacing * ijk) + t.
    for m in (reader.GetSFormMatrix(), reader.GetQFormMatrix()):
        if m is None:
            continue
        affine = np.array([[m.GetElement(r, c) for c in range(4)] for r in range(4)])
        rotation, scale = _orthonormal_columns(affine[:3, :3])
        if rotation is None:
            continue  # a sheared sform: fall back to the (always rigid) qform
        origin_ras = affine[:3, :3] @ volume.origin + affine[:3, 3]
        return _rebuild(volume, spacing=volume.spacing * scale, origin=RAS_TO_LPS @ origin_ras,
                        direction=RAS_TO_LPS @ rotation, nan_policy=nan_policy)
    return volume  # Analyze-style file: voxel sizes only, no placement


def _nifti_header(path):
    """``(time steps, time spacing, time offset)`` of a NIfTI file's header, or ``None``
    when VTK cannot read it (:func:`read_volume` then reports why)."""
    from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringOutputWindow
    from vtkmodules.vtkIOImage import vtkNIFTIImageReader

    reader = vtkNIFTIImageReader()
    if not reader.CanReadFile(str(path)):
        return None
    reader.SetFileName(str(path))
    previous = vtkOutputWindow.GetInstance()
    vtkOutputWindow.SetInstance(vtkStringOutputWindow())  # read_volume reports header errors
    try:
        reader.UpdateInformation()
    finally:
        vtkOutputWindow.SetInstance(previous)
    return (max(1, int(reader.GetTimeDimension())), float(reader.GetTimeSpacing()),
            float(reader.GetNIFTIHeader().GetTOffset()))


@functools.lru_cache(maxsize=1)
def _nifti_all_steps(path: str, mtime_ns: int, size: int):
    """``(reader, image)``: every volume of a 4-D NIfTI read at once, once per file state
    (``mtime_ns``, ``size``), so that stepping through time reads the file once. Volume
    ``t`` is components ``[t v, (t + 1) v)`` of each point (``v`` components per volume)."""
    from vtkmodules.vtkIOImage import vtkNIFTIImageReader

    reader = vtkNIFTIImageReader()
    reader.TimeAsVectorOn()
    return reader, _run_reader(reader, path)


def _nifti_step_image(image, index: int, count: int):
    """Volume ``index`` of a 4-D NIfTI image read with ``TimeAsVector`` (same grid)."""
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkImageData

    scalars = image.GetPointData().GetScalars()
    values = vtk_to_numpy(scalars).reshape(image.GetNumberOfPoints(), -1)
    per_step = max(1, values.shape[1] // count)
    block = np.ascontiguousarray(values[:, index * per_step:(index + 1) * per_step])
    step = vtkImageData()
    step.CopyStructure(image)  # dimensions, origin, spacing, direction
    array = numpy_to_vtk(block, deep=True)
    array.SetName(scalars.GetName() or "scalars")
    step.GetPointData().SetScalars(array)
    return step


def _read_dicom(directory, array, component, nan_policy):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOImage import vtkDICOMImageReader

    files = _dicom_files(directory)
    if not files:
        raise ValueError(f"{directory}: no DICOM files found; give a directory holding one "
                         "DICOM series (uncompressed transfer syntax)")
    if len(files) < 2:
        raise ValueError(f"{directory}: a single DICOM slice is not a volume; volume rendering "
                         "needs a series of at least 2 slices")
    # Each slice is read on its own so that its position, orientation and rescaling are
    # known exactly (vtkDICOMImageReader's directory mode sorts slices but does not say
    # where they are, and sets neither origin nor direction).
    slices, positions, orientations, spacings = [], [], [], []
    for name in files:
        reader = vtkDICOMImageReader()
        image = _run_reader(reader, name)
        nx, ny, _ = image.GetDimensions()
        ncomp = image.GetNumberOfScalarComponents()
        values = vtk_to_numpy(image.GetPointData().GetScalars())
        # The reader flips rows (VTK's j = 0 is the last DICOM row): flip them back.
        slices.append(values.reshape(ny, nx, ncomp)[::-1].transpose(1, 0, 2))
        positions.append(reader.GetImagePositionPatient())
        orientations.append(reader.GetImageOrientationPatient())
        spacings.append(image.GetSpacing()[:2])
    if (len({sl.shape for sl in slices}) > 1
            or np.ptp(np.array(orientations), axis=0).max() > 1e-4
            or np.ptp(np.array(spacings), axis=0).max() > 1e-4):
        raise ValueError(f"{directory}: the DICOM files differ in size, orientation or pixel "
                         "spacing; the directory must hold a single series")
    orientation = np.array(orientations[0], dtype=np.float64)
    row_dir, col_dir = orientation[:3], orientation[3:]
    if not (np.isclose(np.linalg.norm(row_dir), 1, atol=1e-3)
            and np.isclose(np.linalg.norm(col_dir), 1, atol=1e-3)
            and abs(row_dir @ col_dir) < 1e-3):
        raise ValueError(f"{directory}: DICOM Image Orientation (Patient) {orientation.tolist()} "
                         "is missing or not two orthonormal vectors")
    row_dir, col_dir = row_dir / np.linalg.norm(row_dir), col_dir / np.linalg.norm(col_dir)
    normal = np.cross(row_dir, col_dir)
    positions = np.array(positions, dtype=np.float64)
    order = np.argsort(positions @ normal, kind="stable")
    positions = positions[order]
    steps = np.diff(positions, axis=0)
    step_len = np.linalg.norm(steps, axis=1)
    if np.any(step_len <= 1e-6):
        raise ValueError(f"{directory}: two DICOM slices share a position; the directory may "
                         "hold several series")
    if np.any(np.abs(steps @ normal - step_len) > 1e-3 * step_len.max()):
        raise ValueError(f"{directory}: the slices are not stacked along the slice normal "
                         "(tilted gantry); resample the series first")
    if np.ptp(step_len) > 0.01 * step_len.mean():
        raise ValueError(f"{directory}: the slice spacing is not uniform "
                         f"({step_len.min():g} to {step_len.max():g}); resample the series first")
    dtype = np.result_type(*(sl.dtype for sl in slices))
    stack = np.stack([slices[i].astype(dtype, copy=False) for i in order], 2)  # (nx, ny, nz, c)
    image = _image_data(stack if stack.shape[3] > 1 else stack[..., 0], "DICOMImage",
                        (*spacings[0], float(step_len.mean())), positions[0],
                        np.stack([row_dir, col_dir, normal], 1))
    return _convert(image, directory, array, component, nan_policy)


def _dicom_files(directory: Path) -> list[Path]:
    """Files of ``directory`` that start like a DICOM Part-10 file ("DICM" at byte 128)."""
    return [entry for entry in sorted(Path(directory).iterdir())
            if entry.is_file() and _is_dicom_file(entry)]


def _is_dicom_file(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            f.seek(128)
            return f.read(4) == b"DICM"
    except OSError:
        return False


# --- NRRD ---------------------------------------------------------------------------------------
_NRRD_TYPES = {
    np.dtype(np.int8): ("signed char", "int8", "int8_t"),
    np.dtype(np.uint8): ("uchar", "unsigned char", "uint8", "uint8_t"),
    np.dtype(np.int16): ("short", "short int", "signed short", "signed short int", "int16",
                         "int16_t"),
    np.dtype(np.uint16): ("ushort", "unsigned short", "unsigned short int", "uint16", "uint16_t"),
    np.dtype(np.int32): ("int", "signed int", "int32", "int32_t"),
    np.dtype(np.uint32): ("uint", "unsigned int", "uint32", "uint32_t"),
    np.dtype(np.int64): ("longlong", "long long", "long long int", "signed long long",
                         "signed long long int", "int64", "int64_t"),
    np.dtype(np.uint64): ("ulonglong", "unsigned long long", "unsigned long long int", "uint64",
                          "uint64_t"),
    np.dtype(np.float32): ("float",),
    np.dtype(np.float64): ("double",),
}
NRRD_DTYPES = {name: dtype for dtype, names in _NRRD_TYPES.items() for name in names}

#: NRRD space -> matrix taking its coordinates to the ones used here (LPS or unchanged).
NRRD_SPACES = {
    "left-posterior-superior": np.eye(3), "lps": np.eye(3),
    "right-anterior-superior": RAS_TO_LPS, "ras": RAS_TO_LPS,
    "left-anterior-superior": np.diag([1.0, -1.0, 1.0]), "las": np.diag([1.0, -1.0, 1.0]),
    "scanner-xyz": np.eye(3), "3d-right-handed": np.eye(3), "3d-left-handed": np.eye(3),
}

#: NRRD axis kinds that are sample positions (anything else holds components).
NRRD_SPATIAL_KINDS = {"domain", "space", "time", "???", "none"}


def read_nrrd(path):
    """Parse a NRRD file (attached or detached header) into arrays and geometry.

    Supports the raw, gzip, bzip2, ascii and hex encodings, either endianness,
    ``byte skip`` (including -1) and ``line skip``, a single detached ``data
    file``, ``space directions`` (full orientation), ``space origin``,
    ``spacings`` and ``axis mins`` (without space directions) and ``kinds``.
    Multi-file data (``data file: LIST`` or a pattern) is not supported.

    Returns
    -------
    data : ndarray (nx, ny, nz) or (nx, ny, nz, ncomp)
        Samples indexed ``[i, j, k(, c)]``, native dtype.
    spacing, origin : ndarray (3,)
    direction : ndarray (3, 3)
        Orthonormal columns; coordinates converted to LPS for RAS/LAS spaces.
    """
    path = Path(path)
    try:
        return _parse_nrrd(path)
    except ValueError as err:
        if str(err).startswith(f"{path}:"):
            raise
        # A value the parser did not expect (e.g. a header field that holds too few
        # entries): say which file, never a bare Python message.
        raise ValueError(f"{path}: malformed NRRD file ({err})") from err
    except (IndexError, TypeError) as err:
        raise ValueError(f"{path}: malformed NRRD file ({type(err).__name__}: {err})") from err


def _parse_nrrd(path: Path):
    """:func:`read_nrrd` proper; errors it raises name the file."""
    raw = path.read_bytes()
    magic_end = raw.find(b"\n")
    if not raw.startswith(b"NRRD") or magic_end < 0:
        raise ValueError(f"{path}: not a NRRD file (it must start with 'NRRD000x')")
    end = raw.find(b"\n\n")
    crlf_end = raw.find(b"\r\n\r\n")
    if crlf_end >= 0 and (end < 0 or crlf_end < end):
        header_bytes, body = raw[:crlf_end], raw[crlf_end + 4:]
    elif end >= 0:
        header_bytes, body = raw[:end], raw[end + 2:]
    else:  # a detached header may end without a blank line
        header_bytes, body = raw, b""
    fields: dict[str, str] = {}
    for line in header_bytes.decode("latin-1").splitlines()[1:]:
        line = line.strip()
        if not line or line.startswith("#") or ":=" in line.split(": ", 1)[0]:
            continue
        if ": " not in line:
            raise ValueError(f"{path}: malformed NRRD header line {line!r}")
        key, value = line.split(": ", 1)
        fields[key.strip().lower().replace("datafile", "data file")] = value.strip()

    def need(key):
        if key not in fields:
            raise ValueError(f"{path}: NRRD header lacks the required field {key!r}")
        return fields[key]

    ndim = _nrrd_numbers(path, "dimension", need("dimension"), int)[0]
    sizes = _nrrd_numbers(path, "sizes", need("sizes"), int)
    if ndim < 1 or min(sizes, default=0) < 1:
        raise ValueError(f"{path}: NRRD 'dimension' and 'sizes' must be positive, got "
                         f"dimension {ndim}, sizes {sizes}")
    if len(sizes) != ndim:
        raise ValueError(f"{path}: NRRD 'sizes' has {len(sizes)} entries for dimension {ndim}")
    type_name = need("type").lower()
    if type_name not in NRRD_DTYPES:
        raise ValueError(f"{path}: unsupported NRRD type {type_name!r}")
    dtype = NRRD_DTYPES[type_name]
    if dtype.itemsize > 1:
        endian = fields.get("endian", "little").lower()
        if endian not in ("little", "big"):
            raise ValueError(f"{path}: NRRD endian must be 'little' or 'big', got {endian!r}")
        dtype = dtype.newbyteorder("<" if endian == "little" else ">")
    encoding = need("encoding").lower()

    # Which axes are spatial: "space directions" gives "none" for a component axis,
    # "kinds" names it (vector, RGB-color, list, ...).
    spatial = [True] * ndim
    directions = None
    if "space directions" in fields:
        tokens = re.findall(r"none|\([^)]*\)", fields["space directions"])
        if len(tokens) != ndim:
            raise ValueError(f"{path}: NRRD 'space directions' has {len(tokens)} entries for "
                             f"dimension {ndim}")
        directions = [None if t == "none" else
                      np.array(_nrrd_numbers(path, "space directions", t[1:-1], float, ","))
                      for t in tokens]
        spatial = [d is not None for d in directions]
    if "kinds" in fields:
        kinds = fields["kinds"].split()
        if len(kinds) != ndim:
            raise ValueError(f"{path}: NRRD 'kinds' has {len(kinds)} entries for dimension {ndim}")
        spatial = [s and k.lower() in NRRD_SPATIAL_KINDS for s, k in zip(spatial, kinds)]
    space_axes = [a for a in range(ndim) if spatial[a]]
    comp_axes = [a for a in range(ndim) if not spatial[a]]
    if len(space_axes) != 3 or len(comp_axes) > 1:
        raise ValueError(
            f"{path}: NRRD data with sizes {sizes} has {len(space_axes)} spatial axes and "
            f"{len(comp_axes)} component axes; a volume needs 3 spatial axes (and at most one "
            "axis of components)"
        )

    count = int(np.prod(sizes))
    payload = _nrrd_payload(path, fields, body, encoding, dtype, count)
    if encoding in ("ascii", "text", "txt"):
        try:
            values = np.array(payload.split(), dtype=dtype.newbyteorder("="))
        except (ValueError, OverflowError) as err:
            raise ValueError(f"{path}: the NRRD ascii data holds a value that is not a "
                             f"{type_name} ({_one_line(err)})") from err
    else:
        values = np.frombuffer(payload[: count * dtype.itemsize], dtype=dtype)
    if values.size < count:
        raise ValueError(f"{path}: NRRD data holds {values.size} samples, the header needs {count}")
    data = values[:count].reshape(sizes, order="F")
    data = np.moveaxis(data, space_axes + comp_axes, list(range(ndim)))
    data = data.astype(data.dtype.newbyteorder("="), copy=False)

    space = fields.get("space", "").lower()
    if space and space not in NRRD_SPACES:
        raise ValueError(f"{path}: unsupported NRRD space {fields['space']!r}; known: "
                         f"{sorted(NRRD_SPACES)}")
    to_world = NRRD_SPACES.get(space, np.eye(3))
    if directions is not None:
        dirs = np.stack([directions[a] for a in space_axes], 1)
        if dirs.shape[0] != 3:
            raise ValueError(f"{path}: NRRD space directions must be 3-vectors")
        rotation, spacing = _orthonormal_columns(dirs)
        if rotation is None:
            raise ValueError(f"{path}: NRRD space directions {dirs.T.tolist()} are not "
                             "orthogonal (sheared grid); resample it onto an orthogonal grid")
        origin = np.zeros(3)
        if "space origin" in fields:
            origin = np.array(_nrrd_numbers(path, "space origin",
                                            fields["space origin"].strip("() "), float, ","))
            if origin.shape != (3,):
                raise ValueError(f"{path}: NRRD 'space origin' must be a 3-vector, got "
                                 f"{fields['space origin']!r}")
        direction, origin = to_world @ rotation, to_world @ origin
    else:
        spacing = np.ones(3)
        if "spacings" in fields:
            values = _nrrd_numbers(path, "spacings", fields["spacings"].replace("nan", "1"),
                                   float, count=ndim)
            spacing = np.abs(np.array([values[a] for a in space_axes]))
        origin = np.zeros(3)
        if "axis mins" in fields or "axismins" in fields:
            mins = _nrrd_numbers(path, "axis mins", fields.get(
                "axis mins", fields.get("axismins")).replace("nan", "0"), float, count=ndim)
            origin = np.array([mins[a] for a in space_axes])
        direction = np.eye(3)
    return data, spacing, origin, direction


def _nrrd_payload(path, fields, body, encoding, dtype, count) -> bytes:
    """Bytes (decompressed) of the samples, honouring ``data file``, line and byte skips."""
    data_file = fields.get("data file")
    if data_file is not None:
        if data_file.split()[0] == "LIST" or len(data_file.split()) >= 4:
            raise ValueError(f"{path}: NRRD data split over several files is not supported")
        target = Path(data_file)
        if not target.is_absolute():
            target = path.parent / target
        if not target.exists():
            raise FileNotFoundError(f"{path}: its data file {target} does not exist")
        body = target.read_bytes()
    line_skip = _nrrd_numbers(path, "line skip",
                              fields.get("line skip", fields.get("lineskip", "0")), int)[0]
    for _ in range(line_skip):
        body = body[body.find(b"\n") + 1:]
    byte_skip = _nrrd_numbers(path, "byte skip",
                              fields.get("byte skip", fields.get("byteskip", "0")), int)[0]
    if encoding == "raw":
        if byte_skip == -1:
            return body[len(body) - count * dtype.itemsize:]
        return body[byte_skip:]
    try:
        if encoding in ("gzip", "gz"):
            body = gzip.decompress(body)
        elif encoding in ("bzip2", "bz2"):
            body = bz2.decompress(body)
        elif encoding == "hex":
            body = bytes.fromhex(body.decode("ascii"))
        elif encoding in ("ascii", "text", "txt"):
            return body.decode("ascii")
        else:
            raise ValueError(f"{path}: unsupported NRRD encoding {encoding!r}; supported: raw, "
                             "gzip, bzip2, hex, ascii")
    except (OSError, EOFError, zlib.error, ValueError) as err:  # gzip.BadGzipFile is an OSError
        if str(err).startswith(f"{path}:"):
            raise
        what = {"gz": "gzip", "bz2": "bzip2", "text": "ascii", "txt": "ascii"}.get(encoding,
                                                                                  encoding)
        raise ValueError(f"{path}: the NRRD data ({what} encoding) is corrupt or truncated "
                         f"({_one_line(err)})") from err
    if byte_skip == -1:
        return body[len(body) - count * dtype.itemsize:]
    return body[byte_skip:]


def _nrrd_numbers(path, key: str, text: str, kind, sep: str | None = None,
                  count: int | None = None) -> list:
    """The numbers of NRRD field ``key`` (``kind`` int or float); errors name file and field."""
    tokens = [t.strip() for t in str(text).split(sep)]
    try:
        values = [kind(t) for t in tokens if t]
    except ValueError:
        noun = "integers" if kind is int else "numbers"
        raise ValueError(f"{path}: NRRD field {key!r} must hold {noun}, got {text!r}") from None
    if not values or (count is not None and len(values) != count):
        raise ValueError(f"{path}: NRRD field {key!r} must hold "
                         f"{'at least one' if count is None else count} value(s), got {text!r}")
    return values


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def _read_nrrd(path, array, component, nan_policy):
    data, spacing, origin, direction = read_nrrd(path)
    image = _image_data(data, Path(path).name.split(".")[0] or "NRRD", spacing, origin, direction)
    return _convert(image, path, array, component, nan_policy)


_READERS = {
    "vti": _read_vti,
    "vtk": _read_vtk,
    "nrrd": _read_nrrd,
    "metaimage": _read_metaimage,
    "nifti": _read_nifti,
}


# --- helpers ------------------------------------------------------------------------------------
def _run_reader(reader, path, set_file_name: bool = True):
    """Run a VTK reader on ``path``; VTK errors become a ``ValueError`` naming the file.

    The file is first checked with the reader's ``CanReadFile`` (so that a wrong
    file gives a clear message rather than VTK's error dump), and the errors VTK
    reports while reading are captured and the first one quoted.
    """
    from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringOutputWindow

    kind = _READER_NAMES.get(reader.GetClassName(), reader.GetClassName())
    if set_file_name:
        reader.SetFileName(str(path))
        if hasattr(reader, "CanReadFile") and not reader.CanReadFile(str(path)):
            raise ValueError(f"{path}: not a readable {kind} file ({reader.GetClassName()} "
                             "does not recognise it)")
        if hasattr(reader, "ReadOutputType") and reader.ReadOutputType() < 0:
            raise ValueError(f"{path}: not a readable {kind} file")
    previous = vtkOutputWindow.GetInstance()  # this Python reference keeps it alive
    capture = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(capture)
    try:
        reader.Update()
    finally:
        vtkOutputWindow.SetInstance(previous)
    message = _first_vtk_error(capture.GetOutput())
    output = reader.GetOutputDataObject(0)
    if message:
        raise ValueError(f"{path}: {reader.GetClassName()} failed: {message}")
    if output is None or output.GetNumberOfPoints() == 0:
        raise ValueError(f"{path}: the file holds no data (is it a valid {kind} file?)")
    return output


_READER_NAMES = {
    "vtkXMLImageDataReader": "VTK XML image (.vti)",
    "vtkDataSetReader": "VTK legacy (.vtk)",
    "vtkMetaImageReader": "MetaImage",
    "vtkNIFTIImageReader": "NIfTI",
    "vtkDICOMImageReader": "DICOM",
}


def _first_vtk_error(text: str) -> str:
    """The first error message in captured VTK output, without file/line and object ids."""
    lines = [line.strip() for line in (text or "").splitlines()]
    for n, line in enumerate(lines):
        if line.startswith("ERROR:") and n + 1 < len(lines):
            return re.sub(r"^vtk\w+ \(0x[0-9a-fA-F]+\): ", "", lines[n + 1])
    return ""


def _image_data(array, name, spacing, origin, direction):
    """vtkImageData holding ``array`` ([i, j, k(, c)]) as active point scalars."""
    from vtkmodules.vtkCommonDataModel import vtkImageData

    from vtkillum.io.convert import add_point_array

    image = vtkImageData()
    image.SetDimensions(*array.shape[:3])
    image.SetSpacing(*spacing)
    image.SetOrigin(*origin)
    image.SetDirectionMatrix(*np.asarray(direction, dtype=np.float64).ravel())
    add_point_array(image, name, array, set_active=True)
    return image


def _convert(image, path, array, component, nan_policy) -> Volume:
    """vtkImageData (or any data set the converter accepts) -> Volume, errors naming ``path``."""
    from vtkillum.io.convert import volume_from_image_data

    try:
        return volume_from_image_data(image, array_name=array, component=component,
                                      nan_policy=nan_policy)
    except (TypeError, ValueError) as err:  # TypeError: not image data
        raise ValueError(f"{path}: {err}") from err


def _rebuild(volume: Volume, scalars=None, spacing=None, origin=None, direction=None,
             nan_policy: str = "raise") -> Volume:
    """A copy of ``volume`` with some of its fields replaced (validated again)."""
    return Volume(
        volume.scalars if scalars is None else scalars,
        volume.spacing if spacing is None else spacing,
        volume.origin if origin is None else origin,
        volume.direction if direction is None else direction,
        nan_policy=nan_policy,
    )


def _orthonormal_columns(matrix, tol: float = 1e-4):
    """Split ``matrix`` into unit columns and their lengths, if the columns are orthogonal.

    Returns ``(rotation, lengths)``, or ``(None, None)`` when a column is zero or
    two columns are not orthogonal (a sheared grid, which a Volume cannot hold).
    """
    m = np.asarray(matrix, dtype=np.float64)
    lengths = np.linalg.norm(m, axis=0)
    if np.any(lengths <= 0):
        return None, None
    unit = m / lengths
    if not np.allclose(unit.T @ unit, np.eye(3), atol=tol):
        return None, None
    # Re-orthonormalise to remove rounding (file headers store few digits).
    u, _, vt = np.linalg.svd(unit)
    return u @ vt, lengths


def supported_formats() -> str:
    """One-line description of the inputs :func:`read_volume` accepts."""
    return SUPPORTED

