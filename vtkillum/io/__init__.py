"""Input and output of VTK data: conversion to the core's types (:mod:`vtkillum.io.convert`)
and volume file readers (:mod:`vtkillum.io.readers`: ``.vti``, ``.vtk``, NRRD, MetaImage,
NIfTI, DICOM series)."""

from vtkillum.io.readers import read_nrrd, read_volume, supported_formats, volume_format

__all__ = ["read_nrrd", "read_volume", "supported_formats", "volume_format"]
