"""Medical image readers for ParaView, through vtkillum's own readers.

ParaView 5.11 has no NIfTI reader, and its NRRD, MetaImage and DICOM readers drop
the direction matrix (and, for NRRD, read ``space directions`` only as lengths).
These readers hand ParaView what :func:`vtkillum.io.readers.read_volume` returns,
the volume the CLI renders (``vtkillum render head.nii.gz``), placed in the same
world coordinates (LPS for the medical formats; origin, spacing and the direction
matrix of the file, see :mod:`vtkillum.io.readers`):

* :class:`MedicalImageReader` (*vtkIllum Medical Image Reader*): ``.nii``,
  ``.nii.gz``, ``.nrrd``, ``.nhdr``, ``.mha``, ``.mhd`` and ``.dcm`` (a DICOM
  file: the whole series of its directory is read);
* :class:`DICOMDirectoryReader` (*vtkIllum DICOM Directory Reader*, in *Sources →
  vtkIllum*): a directory holding one DICOM series, whatever its files are named.
  It is not a File → Open reader (see the comment at the class).

The output is one ``vtkImageData`` (float32 point scalars named after the file,
the values ``read_volume`` gives: NIfTI ``scl_slope``/``scl_inter`` and DICOM
rescaling applied). A 4-D NIfTI (``dim[4]`` > 1) is offered as time steps
(``TIME_STEPS``: ``toffset + t * pixdim[4]``) that ParaView's time controls step
through: the times come from :func:`vtkillum.io.readers.time_steps`, each volume from
``read_volume(path, time_step=t)`` and a requested time maps to its step with
:func:`vtkillum.io.time_series.step_at`, the functions the CLI (``vtkillum render
functional.nii``) and :class:`vtkillum.io.time_series.TimeSeriesSource` use, so all
three agree. A multi-component array (RGB, vectors) is reduced to its magnitude, with
a warning.
Errors (a missing, unknown or corrupt file) name the reader, the file and the
problem, in ParaView's Output Messages, never a traceback.

The plugin module imports the two classes (ParaView's Python-plugin loader
collects every decorated class in the plugin module's namespace, imported ones
included: ``paraview.detail.pythonalgorithm.get_plugin_xmls``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from paraview.util.vtkAlgorithm import (
    VTKPythonAlgorithmBase,
    smdomain,
    smhint,
    smproperty,
    smproxy,
)
from vtkmodules.vtkCommonCore import vtkOutputWindow
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

#: File name extensions the file reader claims (ParaView's reader factory matches them).
EXTENSIONS = "nii nii.gz nrrd nhdr mha mhd dcm"
FILE_DESCRIPTION = "Medical images, oriented (vtkIllum: NIfTI, NRRD, MetaImage, DICOM)"
#: The Sources menu of the directory reader (the plugin's filters use the same name).
MENU = "vtkIllum"


def read_image(path, time_index: int = 0) -> tuple[vtkImageData, list[str]]:
    """Read ``path`` (file or DICOM directory) with vtkillum's readers.

    Parameters
    ----------
    path : str or Path
        A file of a format :func:`vtkillum.io.readers.read_volume` reads, or a
        DICOM directory.
    time_index : int
        Volume of a 4-D NIfTI (0: the first, which is what ``read_volume`` gives).

    Returns
    -------
    image : vtkImageData
        Float32 point scalars (named after the file) on the file's grid: origin,
        spacing and direction matrix as ``read_volume`` gives them.
    warnings : list of str
        What the reader changed (magnitude of a multi-component array, NaN filled).

    Raises
    ------
    FileNotFoundError, ValueError
        The message names the file and the problem (from ``read_volume``).
    """
    from vtkillum.io.convert import image_data_from_volume

    path = Path(path)
    warnings: list[str] = []
    volume = _read_checked(path, warnings, time_index)
    volume = _metaimage_direction(path, volume)
    volume = _dicom_pixel_spacing(path, volume)
    return image_data_from_volume(volume, array_name(path)), warnings


def _read_checked(path: Path, warnings: list[str], time_index: int = 0):
    """``read_volume`` (volume ``time_index`` of a 4-D NIfTI) with the plugin's fallbacks,
    each announced in ``warnings``: the magnitude of a multi-component array (ParaView has
    no component to choose here) and NaN/Inf filled; any other error is passed on."""
    from vtkillum.io.readers import read_volume

    component, nan_policy = None, "raise"
    while True:  # each fallback is taken at most once
        try:
            return read_volume(path, component=component, nan_policy=nan_policy,
                               time_step=time_index)
        except ValueError as err:
            text = str(err)
            if component is None and re.search(r"has \d+ components; choose one", text):
                component = "magnitude"
                warnings.append(f"{path}: the data has several components per voxel; "
                                "their magnitude (Euclidean norm) is read")
            elif nan_policy == "raise" and "NaN or Inf" in text:
                nan_policy = "fill"
                warnings.append(f"{path}: NaN/Inf samples were replaced by the smallest "
                                "finite value")
            else:
                raise


def _metaimage_direction(path: Path, volume):
    """``volume`` with the MetaImage header's ``TransformMatrix`` as its direction.

    VTK 9.2's ``vtkMetaImageReader`` (ParaView 5.11's) ignores ``TransformMatrix``,
    where the newer VTK of vtkillum's environment reads it, row by row, as the
    direction matrix; this gives ParaView the same volume. Only an identity direction
    (what 9.2 returns) is replaced, so a VTK that reads the matrix is left alone.
    """
    from vtkillum.core.volume import Volume

    if not path.name.lower().endswith((".mha", ".mhd")) or not np.allclose(
            volume.direction, np.eye(3)):
        return volume
    matrix = None
    with open(path, "rb") as f:
        for raw in f:
            key, sep, value = raw.decode("latin-1").partition("=")
            key = key.strip()
            if not sep or key == "ElementDataFile":
                break  # the header ends with ElementDataFile
            if key in ("TransformMatrix", "Rotation", "Orientation"):
                try:
                    matrix = np.array(value.split(), dtype=np.float64).reshape(3, 3)
                except ValueError:
                    return volume  # not a 3-D matrix: keep what the reader gave
    if matrix is None or not np.allclose(matrix @ matrix.T, np.eye(3), atol=1e-4):
        return volume
    return Volume(volume.scalars, volume.spacing, volume.origin, matrix,
                  nan_policy=volume.nan_policy)


def _dicom_pixel_spacing(path: Path, volume):
    """``volume`` with x = column spacing, y = row spacing, as DICOM's Pixel Spacing says.

    VTK 9.2's ``vtkDICOMImageReader`` (ParaView 5.11's) swaps the two values of Pixel
    Spacing (0028,0030), "row spacing \\ column spacing"; newer VTK (vtkillum's
    environment) does not. When the file's values are unequal and the volume has
    them in the swapped order, they are put back, so ParaView gets what vtkillum reads.
    """
    from vtkillum.core.volume import Volume

    files = ([path] if path.is_file() else sorted(path.iterdir()) if path.is_dir() else [])
    text = None
    for name in files:
        text = _pixel_spacing_text(name)
        if text is not None:
            break
    if text is None:
        return volume
    try:
        row, column = (float(v) for v in text.split("\\")[:2])
    except ValueError:
        return volume
    spacing = np.array(volume.spacing, dtype=np.float64)
    if abs(row - column) > 1e-6 * max(row, column) and np.allclose(spacing[:2], (row, column)):
        spacing[:2] = column, row
        return Volume(volume.scalars, spacing, volume.origin, volume.direction,
                      nan_policy=volume.nan_policy)
    return volume


def _pixel_spacing_text(path: Path) -> str | None:
    """The text of Pixel Spacing (0028,0030) of a DICOM Part-10 file, little endian
    (explicit or implicit VR), or None."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return None
    if head[128:132] != b"DICM":
        return None
    head = head.split(b"\xe0\x7f\x10\x00", 1)[0]  # not into the pixel data
    at = head.find(b"\x28\x00\x30\x00")
    if at < 0:
        return None
    if head[at + 4:at + 6] == b"DS":  # explicit VR: 2-byte length
        length, start = int.from_bytes(head[at + 6:at + 8], "little"), at + 8
    else:  # implicit VR: 4-byte length
        length, start = int.from_bytes(head[at + 4:at + 8], "little"), at + 8
    if not 0 < length < 64:
        return None
    return head[start:start + length].decode("ascii", "replace").strip(" \0")


def array_name(path) -> str:
    """Name of the point array: the file's name without its extensions (``head`` for
    ``head.nii.gz``), else ``scalars``."""
    stem = Path(path).name.split(".")[0]
    stem = re.sub(r"[^\w-]+", "_", stem).strip("_")
    return stem or "scalars"


def nifti_times(path) -> list[float]:
    """Times of the volumes of a 4-D NIfTI file (``[]`` for anything else).

    ``toffset + t * pixdim[4]`` (``t`` when ``pixdim[4]`` is not positive), in the
    file's time unit (``xyzt_units``, usually seconds): vtkillum's
    :func:`~vtkillum.io.readers.time_steps`, for the files this reader opens.
    """
    from vtkillum.io.readers import time_steps

    name = Path(path).name.lower()
    if not name.endswith((".nii", ".nii.gz")):
        return []
    return time_steps(path)


class _VolumeReader(VTKPythonAlgorithmBase):
    """Shared body of the readers: a file name in, one oriented ``vtkImageData`` out.

    The image of the current file (and time step) is kept, so ParaView's repeated
    information and data requests read the file once; a changed file (its size or
    modification time) is read again.
    """

    #: The menu label, used in error messages.
    label = "vtkIllum Medical Image Reader"

    def __init__(self) -> None:
        super().__init__(nInputPorts=0, nOutputPorts=1, outputType="vtkImageData")
        self._file_name = ""
        self._image = None  # (key, image, warnings) of the last read
        self._times: list[float] = []
        self._last_error: str | None = None
        self._failed = False  # RequestInformation could not read the file

    # --- properties (ParaView calls these) ---------------------------------------------------
    def _set_file_name(self, name) -> None:
        name = "" if name is None else str(name)
        if name != self._file_name:
            self._file_name = name
            self.Modified()

    def GetFileName(self) -> str:
        return self._file_name

    def _timestep_values(self):
        """Times of a 4-D NIfTI's volumes (None for a 3-D file)."""
        return self._times or None

    # --- pipeline ----------------------------------------------------------------------------
    def RequestInformation(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        try:
            path = self._path()
            self._times = nifti_times(path)
            image, _ = self._read(path, 0)
        except Exception as err:  # noqa: BLE001 - shown as a message, see _report
            # Reported once, here; an empty extent and success (not 0) keep VTK's executive
            # from adding its own request dumps, and RequestData leaves the output empty.
            self._report(err)
            self._failed = True
            info.Set(SDDP.WHOLE_EXTENT(), (0, -1, 0, -1, 0, -1), 6)
            info.Remove(SDDP.TIME_STEPS())
            info.Remove(SDDP.TIME_RANGE())
            return 1
        self._failed = False
        info.Set(SDDP.WHOLE_EXTENT(), image.GetExtent(), 6)
        info.Set(vtkDataObject.ORIGIN(), image.GetOrigin(), 3)
        info.Set(vtkDataObject.SPACING(), image.GetSpacing(), 3)
        matrix = image.GetDirectionMatrix()
        info.Set(vtkDataObject.DIRECTION(),
                 tuple(matrix.GetElement(r, c) for r in range(3) for c in range(3)), 9)
        if self._times:
            info.Set(SDDP.TIME_STEPS(), self._times, len(self._times))
            info.Set(SDDP.TIME_RANGE(), [self._times[0], self._times[-1]], 2)
        else:
            info.Remove(SDDP.TIME_STEPS())
            info.Remove(SDDP.TIME_RANGE())
        return 1

    def RequestData(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        output = vtkImageData.GetData(info)
        if self._failed:  # already reported by RequestInformation
            output.Initialize()
            return 1
        try:
            index = 0
            if self._times and info.Has(SDDP.UPDATE_TIME_STEP()):
                from vtkillum.io.time_series import step_at

                # The last volume at or before the requested time (ParaView's convention).
                index = step_at(self._times, info.Get(SDDP.UPDATE_TIME_STEP()))
            image, _ = self._read(self._path(), index)
        except Exception as err:  # noqa: BLE001 - shown as a message, see _report
            output.Initialize()
            self._report(err)
            return 1  # an empty output and the message only (see RequestInformation)
        output.ShallowCopy(image)
        if self._times:
            output.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(), self._times[index])
        self._last_error = None
        return 1

    # --- internals ---------------------------------------------------------------------------
    def _path(self) -> Path:
        if not self._file_name:
            raise ValueError("no file name given")
        return Path(self._file_name)

    def _read(self, path: Path, index: int):
        """The image of ``path`` at volume ``index`` (read once per file state)."""
        try:
            stat = path.stat()
            key = (str(path), index, stat.st_mtime_ns, stat.st_size)
        except OSError:
            key = None  # read_volume says what is wrong
        if key is not None and self._image is not None and self._image[0] == key:
            return self._image[1], []  # its warnings were shown when it was read
        image, warnings = read_image(path, index)
        self._image = (key, image, warnings)
        for text in warnings:  # once per read, whichever request read the file
            vtkOutputWindow.GetInstance().DisplayWarningText(f"{self.label}: {text}\n")
        return image, warnings

    def _report(self, err: Exception) -> None:
        """Show ``err`` as one line naming the reader, the file and the problem."""
        text = " ".join(str(err).split()) or type(err).__name__
        name = self._file_name
        if name and name not in text:  # read_volume's messages start with the path
            text = f"{name}: {text}"
        if isinstance(err, (FileNotFoundError, ValueError)):
            message = f"{self.label}: {text}"
        else:  # an unexpected failure: still one line, with its kind
            message = f"{self.label}: cannot read {name or 'the file'}: {type(err).__name__}: {text}"
        self._last_error = message
        if self.HasObserver("ErrorEvent"):
            self.InvokeEvent("ErrorEvent", message)
        else:
            vtkOutputWindow.GetInstance().DisplayErrorText(message + "\n")


# ParaView's decorators collect properties from each class's own __dict__ only: the
# decorated methods are repeated in both classes and delegate to the base.
@smproxy.reader(name="vtkIllumMedicalImageReader", label="vtkIllum Medical Image Reader",
                extensions=EXTENSIONS, file_description=FILE_DESCRIPTION, support_reload=False)
class MedicalImageReader(_VolumeReader):
    """NIfTI, NRRD, MetaImage or DICOM volume, oriented, as vtkillum reads it.

    Parameters
    ----------
    FileName : str
        ``.nii``, ``.nii.gz``, ``.nrrd``, ``.nhdr``, ``.mha``, ``.mhd``, or a DICOM
        file (``.dcm``): then every DICOM file of its directory is read as one series.

    Notes
    -----
    World coordinates are the file's, in millimetres for the medical formats, LPS
    axes (NIfTI's RAS converted as ITK does); see :mod:`vtkillum.io.readers`.
    ``TimestepValues`` (information): the times of a 4-D NIfTI's volumes.
    """

    label = "vtkIllum Medical Image Reader"

    @smproperty.stringvector(name="FileName", panel_visibility="never")
    @smdomain.filelist()
    @smhint.filechooser(extensions=EXTENSIONS, file_description=FILE_DESCRIPTION)
    def SetFileName(self, name):
        """The volume file to read."""
        self._set_file_name(name)

    @smproperty.doublevector(name="TimestepValues", information_only="1",
                             si_class="vtkSITimeStepsProperty")
    def GetTimestepValues(self):
        return self._timestep_values()


# Not a File → Open reader: ParaView 5.11 matches an ``is_directory`` reader by the
# directory's name (``filename_patterns``), and DICOM directories have no common name;
# a pattern of "*" would make the file dialog open every directory instead of entering
# it (and list every file under "Supported Types"). File → Open of one DICOM file of
# the series (MedicalImageReader) reads the whole directory.
@smproxy.source(name="vtkIllumDICOMDirectoryReader", label="vtkIllum DICOM Directory Reader",
                support_reload=False)
@smhint.xml(f'<ShowInMenu category="{MENU}" />')
class DICOMDirectoryReader(_VolumeReader):
    """A directory holding one DICOM series, oriented, as vtkillum reads it
    (*Sources → vtkIllum*).

    Parameters
    ----------
    DirectoryName : str
        The directory; every DICOM Part-10 file in it (any file name) is a slice of
        the series.

    Notes
    -----
    Slices are ordered along their normal from Image Position (Patient); the
    series must be evenly spaced and untilted (see :mod:`vtkillum.io.readers`).
    """

    label = "vtkIllum DICOM Directory Reader"

    @smproperty.stringvector(name="DirectoryName")
    @smdomain.filelist()
    @smhint.xml("<UseDirectoryName />")
    def SetDirectoryName(self, name):
        """The directory of the DICOM series."""
        self._set_file_name(name)

    @smproperty.doublevector(name="TimestepValues", information_only="1",
                             si_class="vtkSITimeStepsProperty")
    def GetTimestepValues(self):
        return self._timestep_values()


__all__ = ["DICOMDirectoryReader", "MedicalImageReader", "array_name", "nifti_times",
           "read_image"]
