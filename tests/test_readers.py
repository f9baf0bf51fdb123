"""Volume file readers: values and world placement round-trip for every format.

Every format is checked the same way: each sample of a known array is written
with a known index -> world mapping, and after reading, the sample found at that
world position (through the Volume's origin, spacing and direction) must be the
same value. This catches axis flips, transposes and origin errors alike, and
checks the documented conventions (LPS world coordinates; NIfTI RAS converted).
"""

from __future__ import annotations

import gzip
import os
import re
import struct

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: E402

from vtkillum.io.readers import read_nrrd, read_volume  # noqa: E402

#: NIfTI world (RAS) to ours (LPS): negate x and y.
RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0])

SHAPE = (12, 11, 10)
SPACING = np.array([0.5, 0.7, 0.9])
ORIGIN = np.array([1.0, -2.0, 3.0])
# A proper rotation (det +1) that is not a permutation, so transposes show up.
_c, _s = np.cos(0.4), np.sin(0.4)
ROTATION = np.array([[_c, -_s, 0.0], [_s, _c, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
    [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@pytest.fixture
def data(rng):
    """A float32 array with distinct values (so any index mix-up changes a value)."""
    return rng.permutation(np.prod(SHAPE)).reshape(SHAPE).astype(np.float32)


def world_points(spacing, origin, direction, shape=SHAPE):
    """World position of every index of ``shape`` for a given geometry, (..., 3)."""
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), -1)
    return origin + (ijk * spacing) @ np.asarray(direction).T


def assert_same_samples(volume, data, world):
    """The value of ``volume`` at each world point equals ``data`` at that point's index."""
    local = volume.to_local(world) / volume.spacing
    idx = np.rint(local)
    np.testing.assert_allclose(local, idx, atol=1e-3, err_msg="world points fall between samples")
    idx = idx.astype(int)
    assert np.all(idx >= 0) and np.all(idx < np.array(volume.dims)), "world points outside"
    found = volume.scalars[idx[..., 0], idx[..., 1], idx[..., 2]]
    np.testing.assert_array_equal(found, data)


def image_data(array, spacing=SPACING, origin=ORIGIN, direction=np.eye(3), name="density"):
    img = vtk.vtkImageData()
    img.SetDimensions(*array.shape[:3])
    img.SetSpacing(*spacing)
    img.SetOrigin(*origin)
    img.SetDirectionMatrix(*np.asarray(direction).ravel())
    ncomp = 1 if array.ndim == 3 else array.shape[3]
    flat = array.reshape(-1, ncomp, order="F") if ncomp > 1 else array.ravel(order="F")
    arr = numpy_to_vtk(np.ascontiguousarray(flat), deep=True)
    arr.SetName(name)
    img.GetPointData().AddArray(arr)
    img.GetPointData().SetActiveScalars(name)
    return img


def write(writer, path, image):
    writer.SetFileName(str(path))
    writer.SetInputData(image)
    writer.Write()
    return path


# --- VTK formats ----------------------------------------------------------------------------------
def test_vti_keeps_values_and_geometry(tmp_path, data):
    path = write(vtk.vtkXMLImageDataWriter(), tmp_path / "v.vti",
                 image_data(data, direction=ROTATION))
    vol = read_volume(path)
    assert vol.dims == SHAPE
    np.testing.assert_allclose(vol.spacing, SPACING)
    np.testing.assert_allclose(vol.origin, ORIGIN)
    np.testing.assert_allclose(vol.direction, ROTATION, atol=1e-12)
    np.testing.assert_array_equal(vol.scalars, data)


def test_vti_array_and_component_selection(tmp_path, data):
    image = image_data(np.stack([data, 2 * data, 3 * data], -1), name="vec")
    other = numpy_to_vtk(np.ascontiguousarray((data + 7).ravel(order="F")), deep=True)
    other.SetName("other")
    image.GetPointData().AddArray(other)
    path = write(vtk.vtkXMLImageDataWriter(), tmp_path / "multi.vti", image)
    np.testing.assert_array_equal(read_volume(path, array="vec", component=2).scalars, 3 * data)
    np.testing.assert_array_equal(read_volume(path, array="other").scalars, data + 7)
    with pytest.raises(ValueError, match="component"):
        read_volume(path, array="vec")
    with pytest.raises(ValueError, match="no point or cell array named 'nope'.*other"):
        read_volume(path, array="nope")


def test_legacy_vtk(tmp_path, data):
    path = write(vtk.vtkStructuredPointsWriter(), tmp_path / "v.vtk", image_data(data))
    vol = read_volume(path)
    np.testing.assert_array_equal(vol.scalars, data)
    np.testing.assert_allclose(vol.spacing, SPACING)
    np.testing.assert_allclose(vol.origin, ORIGIN)


@pytest.mark.parametrize("ext", ["mha", "mhd"])
def test_metaimage_keeps_direction(tmp_path, data, ext):
    path = write(vtk.vtkMetaImageWriter(), tmp_path / f"v.{ext}",
                 image_data(data, direction=ROTATION))
    vol = read_volume(path)
    assert_same_samples(vol, data, world_points(SPACING, ORIGIN, ROTATION))


# --- NIfTI ----------------------------------------------------------------------------------------
def nifti_qform(rotation, offset):
    m = vtk.vtkMatrix4x4()
    for r in range(3):
        for c in range(3):
            m.SetElement(r, c, rotation[r, c])
        m.SetElement(r, 3, offset[r])
    return m


@pytest.mark.parametrize("ext,qfac", [("nii", 1), ("nii.gz", 1), ("nii", -1)])
def test_nifti_ras_becomes_lps(tmp_path, data, ext, qfac):
    writer = vtk.vtkNIFTIImageWriter()
    writer.SetQFormMatrix(nifti_qform(ROTATION, ORIGIN))
    writer.SetQFac(qfac)  # -1: slices stored in reverse (a left-handed index frame)
    path = write(writer, tmp_path / f"v.{ext}", image_data(data, origin=(0, 0, 0)))
    vol = read_volume(path)
    # The qform maps VTK data coordinates (spacing * ijk) to RAS; we report LPS.
    ras = world_points(SPACING, ORIGIN, ROTATION)
    assert_same_samples(vol, data, ras @ RAS_TO_LPS.T)


def test_nifti_sform_preferred_and_rescaled(tmp_path, data):
    writer = vtk.vtkNIFTIImageWriter()
    writer.SetQFormMatrix(nifti_qform(np.eye(3), (0.0, 0.0, 0.0)))
    writer.SetSFormMatrix(nifti_qform(ROTATION, ORIGIN))
    writer.SetRescaleSlope(2.0)
    writer.SetRescaleIntercept(-5.0)
    path = write(writer, tmp_path / "s.nii", image_data(data, origin=(0, 0, 0)))
    vol = read_volume(path)
    ras = world_points(SPACING, ORIGIN, ROTATION)
    assert_same_samples(vol, 2.0 * data - 5.0, ras @ RAS_TO_LPS.T)


# --- NRRD -----------------------------------------------------------------------------------------
def nrrd_header(sizes, type_="float", encoding="raw", endian="little", extra=""):
    return ("NRRD0004\n# written by a test\n"
            f"type: {type_}\ndimension: {len(sizes)}\nsizes: {' '.join(map(str, sizes))}\n"
            f"endian: {endian}\nencoding: {encoding}\n{extra}")


def space_fields(space, directions, origin):
    dirs = " ".join("(" + ",".join(f"{v:.17g}" for v in col) + ")" for col in directions.T)
    return (f"space: {space}\nspace directions: {dirs}\n"
            f"space origin: ({','.join(f'{v:.17g}' for v in origin)})\n")


def test_nrrd_attached_raw_with_orientation(tmp_path, data):
    dirs = ROTATION * SPACING
    header = nrrd_header(SHAPE, extra="kinds: domain domain domain\n"
                         + space_fields("left-posterior-superior", dirs, ORIGIN))
    path = tmp_path / "v.nrrd"
    path.write_bytes(header.encode() + b"\n" + data.tobytes(order="F"))
    vol = read_volume(path)
    np.testing.assert_allclose(vol.spacing, SPACING)
    np.testing.assert_allclose(vol.direction, ROTATION, atol=1e-9)
    assert_same_samples(vol, data, world_points(SPACING, ORIGIN, ROTATION))


def test_nrrd_ras_space_matches_nifti(tmp_path, data):
    """The same RAS placement written as NRRD and as NIfTI reads back identically."""
    dirs = ROTATION * SPACING
    header = nrrd_header(SHAPE, extra=space_fields("right-anterior-superior", dirs, ORIGIN))
    nrrd = tmp_path / "v.nrrd"
    nrrd.write_bytes(header.encode() + b"\n" + data.tobytes(order="F"))
    writer = vtk.vtkNIFTIImageWriter()
    writer.SetQFormMatrix(nifti_qform(ROTATION, ORIGIN))
    nii = write(writer, tmp_path / "v.nii", image_data(data, origin=(0, 0, 0)))
    a, b = read_volume(nrrd), read_volume(nii)
    np.testing.assert_allclose(a.origin, b.origin, atol=1e-5)
    np.testing.assert_allclose(a.direction, b.direction, atol=1e-6)
    np.testing.assert_allclose(a.spacing, b.spacing, rtol=1e-6)
    np.testing.assert_array_equal(a.scalars, b.scalars)


def test_nrrd_detached_gzip_big_endian_int16(tmp_path, data):
    values = data.astype(">i2")
    (tmp_path / "v.raw.gz").write_bytes(gzip.compress(values.tobytes(order="F")))
    header = nrrd_header(SHAPE, "short", "gzip", "big",
                         "spacings: 0.5 0.7 0.9\ndata file: v.raw.gz\n")
    (tmp_path / "v.nhdr").write_text(header + "\n")
    vol = read_volume(tmp_path / "v.nhdr")
    np.testing.assert_array_equal(vol.scalars, data)
    np.testing.assert_allclose(vol.spacing, SPACING)
    np.testing.assert_allclose(vol.origin, 0.0)


def test_nrrd_small_first_axis_is_spatial(tmp_path, rng):
    """vtkNrrdReader would take an x axis of <= 9 samples for vector components."""
    small = rng.random((4, 5, 6)).astype(np.float32)
    path = tmp_path / "small.nrrd"
    path.write_bytes(nrrd_header((4, 5, 6)).encode() + b"\n" + small.tobytes(order="F"))
    np.testing.assert_array_equal(read_volume(path).scalars, small)


def test_nrrd_vector_axis_and_ascii_and_byte_skip(tmp_path, data):
    vec = np.stack([data, -data, data + 1], 0)  # components first, as NRRD stores them
    header = nrrd_header((3,) + SHAPE, extra="kinds: vector domain domain domain\n"
                         + space_fields("LPS", np.diag(SPACING), ORIGIN).replace(
                             "space directions: ", "space directions: none "))
    path = tmp_path / "vec.nrrd"
    path.write_bytes(header.encode() + b"\n" + vec.tobytes(order="F"))
    np.testing.assert_array_equal(read_volume(path, component=1).scalars, -data)
    assert read_nrrd(path)[0].shape == SHAPE + (3,)

    ascii_path = tmp_path / "a.nrrd"
    ascii_path.write_text(nrrd_header(SHAPE, encoding="ascii") + "\n"
                          + "\n".join(f"{v:g}" for v in data.ravel(order="F")) + "\n")
    np.testing.assert_array_equal(read_volume(ascii_path).scalars, data)

    skip_path = tmp_path / "skip.nrrd"
    skip_path.write_bytes(nrrd_header(SHAPE, extra="byte skip: -1\n").encode() + b"\n"
                          + b"JUNK" + data.tobytes(order="F"))
    np.testing.assert_array_equal(read_volume(skip_path).scalars, data)


def test_nrrd_errors(tmp_path, data):
    bad = tmp_path / "bad.nrrd"
    bad.write_text("hello\n")
    with pytest.raises(ValueError, match="not a NRRD file"):
        read_volume(bad)
    short = tmp_path / "short.nrrd"
    short.write_bytes(nrrd_header(SHAPE).encode() + b"\n" + data.tobytes()[:100])
    with pytest.raises(ValueError, match="holds 25 samples, the header needs 1320"):
        read_volume(short)
    missing = tmp_path / "m.nhdr"
    missing.write_text(nrrd_header(SHAPE, extra="data file: nothere.raw\n") + "\n")
    with pytest.raises(FileNotFoundError, match="nothere.raw"):
        read_volume(missing)
    sheared = tmp_path / "shear.nrrd"
    sheared.write_bytes(nrrd_header(SHAPE, extra=space_fields(
        "LPS", np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]), ORIGIN)).encode()
        + b"\n" + data.tobytes(order="F"))
    with pytest.raises(ValueError, match="not orthogonal"):
        read_volume(sheared)


def _corrupt_payloads(data):
    packed = gzip.compress(data.tobytes(order="F"))
    import bz2

    return {
        "truncated-gzip": ("gzip", packed[: len(packed) // 2]),
        "not-gzip": ("gzip", b"plain bytes, no gzip magic" * 10),
        "bad-bzip2": ("bzip2", b"BZh9" + b"garbage" * 40),
        "truncated-bzip2": ("bzip2", bz2.compress(data.tobytes(order="F"))[:200]),
        "bad-hex": ("hex", b"zz" * 4000),
        "bad-ascii": ("ascii", b"1 2 three " * 500),
    }


@pytest.mark.parametrize("case", ["truncated-gzip", "not-gzip", "bad-bzip2", "truncated-bzip2",
                                  "bad-hex", "bad-ascii"])
def test_nrrd_corrupt_data_is_a_value_error_naming_the_file(tmp_path, data, case):
    """Issue 15 row 4: zlib/gzip/bz2 errors (OSError, EOFError) escaped as tracebacks."""
    encoding, payload = _corrupt_payloads(data)[case]
    path = tmp_path / f"{case}.nrrd"
    path.write_bytes(nrrd_header(SHAPE, encoding=encoding).encode() + b"\n" + payload)
    with pytest.raises(ValueError, match=rf"{case}\.nrrd: the NRRD .*(corrupt|not a float)"):
        read_volume(path)


@pytest.mark.parametrize("field,value,message", [
    ("dimension", "three", "'dimension' must hold integers, got 'three'"),
    ("sizes", "12 eleven 10", "'sizes' must hold integers"),
    ("sizes", "12 0 10", "must be positive"),
    ("spacings", "0.5 0.7", "'spacings' must hold 3 value"),
    ("axis mins", "0 x 0", "'axis mins' must hold numbers"),
    ("space origin", "(1,2)", "'space origin' must be a 3-vector"),
    ("space directions", "(1,0,0) (0,one,0) (0,0,1)", "'space directions' must hold numbers"),
    ("byte skip", "some", "'byte skip' must hold integers"),
    ("line skip", "-", "'line skip' must hold integers"),
])
def test_nrrd_header_errors_name_the_file_and_field(tmp_path, data, field, value, message):
    """Issue 15 row 10: ``invalid literal for int() ... 'three'`` named neither."""
    header = nrrd_header(SHAPE)
    if field in ("dimension", "sizes"):
        header = "\n".join(f"{field}: {value}" if line.startswith(f"{field}:") else line
                           for line in header.split("\n"))
    else:
        header += f"{field}: {value}\n"
        if field == "space origin":
            header += "space: LPS\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
    path = tmp_path / "hdr.nrrd"
    path.write_bytes(header.encode() + b"\n" + data.tobytes(order="F"))
    with pytest.raises(ValueError, match="hdr\\.nrrd: NRRD .*" + re.escape(message)):
        read_volume(path)


# --- DICOM ----------------------------------------------------------------------------------------
def _element(group, elem, vr, value):
    """One explicit-VR little-endian data element."""
    raw = value.encode("ascii") if isinstance(value, str) else value
    if len(raw) % 2:
        raw += b"\0" if vr == "UI" else b" "
    if vr in ("OB", "OW", "SQ", "UN", "UT"):
        return struct.pack("<HH2s2xI", group, elem, vr.encode(), len(raw)) + raw
    return struct.pack("<HH2sH", group, elem, vr.encode(), len(raw)) + raw


def write_dicom_series(directory, volume, spacing, origin, row_dir, col_dir, slope=1.0,
                       intercept=0.0, names=None):
    """Write ``volume[i, j, k]`` (int16; i: column, j: row, k: slice) as CT slices.

    A minimal DICOM Part-10 writer (explicit VR little endian, uncompressed), enough
    for vtkDICOMImageReader; slice k lies at ``origin + k * spacing[2] * (row x col)``.
    """
    os.makedirs(directory, exist_ok=True)
    nx, ny, nz = volume.shape
    normal = np.cross(row_dir, col_dir)
    us = lambda v: struct.pack("<H", v)  # noqa: E731
    for k in range(nz):
        pos = np.asarray(origin, dtype=float) + k * spacing[2] * normal
        uid = f"1.2.826.0.1.3680043.2.1125.1.{k + 1}"
        meta = (_element(2, 1, "OB", b"\0\1") + _element(2, 2, "UI", "1.2.840.10008.5.1.4.1.1.2")
                + _element(2, 3, "UI", uid) + _element(2, 0x10, "UI", "1.2.840.10008.1.2.1"))
        body = b"".join([
            _element(8, 0x16, "UI", "1.2.840.10008.5.1.4.1.1.2"), _element(8, 0x18, "UI", uid),
            _element(8, 0x60, "CS", "CT"), _element(0x10, 0x10, "PN", "Phantom"),
            _element(0x18, 0x50, "DS", f"{spacing[2]:g}"),
            _element(0x20, 0x0D, "UI", "1.2.826.0.1.3680043.2.1125.2"),
            _element(0x20, 0x0E, "UI", "1.2.826.0.1.3680043.2.1125.3"),
            _element(0x20, 0x13, "IS", str(k + 1)),
            _element(0x20, 0x32, "DS", "\\".join(f"{v:g}" for v in pos)),
            _element(0x20, 0x37, "DS", "\\".join(f"{v:g}" for v in (*row_dir, *col_dir))),
            _element(0x28, 2, "US", us(1)), _element(0x28, 4, "CS", "MONOCHROME2"),
            _element(0x28, 0x10, "US", us(ny)), _element(0x28, 0x11, "US", us(nx)),
            _element(0x28, 0x30, "DS", f"{spacing[1]:g}\\{spacing[0]:g}"),  # row\column
            _element(0x28, 0x100, "US", us(16)), _element(0x28, 0x101, "US", us(16)),
            _element(0x28, 0x102, "US", us(15)), _element(0x28, 0x103, "US", us(1)),
            _element(0x28, 0x1052, "DS", f"{intercept:g}"),
            _element(0x28, 0x1053, "DS", f"{slope:g}"),
            _element(0x7FE0, 0x10, "OW", volume[:, :, k].astype("<i2").tobytes(order="F")),
        ])
        name = names[k] if names else f"slice{k:03d}.dcm"
        with open(os.path.join(directory, name), "wb") as f:
            f.write(b"\0" * 128 + b"DICM" + _element(2, 0, "UL", struct.pack("<I", len(meta)))
                    + meta + body)


def test_dicom_series_geometry_and_rescale(tmp_path, data):
    values = data.astype(np.int16)
    row_dir, col_dir = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0])  # sagittal
    # File names in reverse slice order: the reader must sort by position.
    names = [f"im{SHAPE[2] - k:02d}" for k in range(SHAPE[2])]
    write_dicom_series(tmp_path / "series", values, SPACING, ORIGIN, row_dir, col_dir,
                       slope=2.0, intercept=-100.0, names=names)
    vol = read_volume(tmp_path / "series")
    direction = np.stack([row_dir, col_dir, np.cross(row_dir, col_dir)], 1)
    np.testing.assert_allclose(vol.direction, direction, atol=1e-6)
    np.testing.assert_allclose(vol.spacing, SPACING, rtol=1e-6)
    assert_same_samples(vol, 2.0 * values - 100.0, world_points(SPACING, ORIGIN, direction))
    # A file of the series names its directory too.
    np.testing.assert_array_equal(read_volume(tmp_path / "series" / "im01").scalars,
                                  vol.scalars)


def test_dicom_errors(tmp_path, data):
    values = data.astype(np.int16)
    write_dicom_series(tmp_path / "one", values[:, :, :1], SPACING, ORIGIN, (1, 0, 0), (0, 1, 0))
    with pytest.raises(ValueError, match="single DICOM slice"):
        read_volume(tmp_path / "one")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("nothing")
    with pytest.raises(ValueError, match="holds no DICOM files; supported: .vti"):
        read_volume(tmp_path / "empty")
    # Uneven slice spacing: two series interleaved at different steps.
    write_dicom_series(tmp_path / "uneven", values[:, :, :3], SPACING, ORIGIN, (1, 0, 0),
                       (0, 1, 0))
    write_dicom_series(tmp_path / "uneven", values[:, :, :1], SPACING, ORIGIN + (0, 0, 10),
                       (1, 0, 0), (0, 1, 0), names=["extra.dcm"])
    with pytest.raises(ValueError, match="slice spacing is not uniform"):
        read_volume(tmp_path / "uneven")


# --- general errors -------------------------------------------------------------------------------
def test_missing_and_unknown_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_volume(tmp_path / "nothere.vti")
    odd = tmp_path / "volume.xyz"
    odd.write_text("1 2 3")
    with pytest.raises(ValueError, match=r"unknown volume format '\.xyz'; supported: .*\.nrrd"):
        read_volume(odd)
    for name in ("bad.vti", "bad.mha", "bad.nii", "bad.vtk"):
        (tmp_path / name).write_text("garbage")
        with pytest.raises(ValueError, match="not a readable"):
            read_volume(tmp_path / name)


def test_legacy_vtk_that_is_not_an_image(tmp_path):
    sphere = vtk.vtkSphereSource()
    sphere.Update()
    path = write(vtk.vtkPolyDataWriter(), tmp_path / "mesh.vtk", sphere.GetOutput())
    with pytest.raises(ValueError, match="mesh.vtk: vtkPolyData is not image data.*resample"):
        read_volume(path)
