"""Input and output of VTK data: conversion to the core's types (:mod:`vtkillum.io.convert`),
volume file readers (:mod:`vtkillum.io.readers`: ``.vti``, ``.vtk``, NRRD, MetaImage,
NIfTI, DICOM series; the time axis of a 4-D NIfTI), time series of volumes and their VTK
source (:mod:`vtkillum.io.time_series`) and animations (:mod:`vtkillum.io.animation`)."""

from vtkillum.io.readers import (
    read_nrrd,
    read_volume,
    supported_formats,
    time_steps,
    volume_format,
)

__all__ = ["read_nrrd", "read_volume", "supported_formats", "time_steps", "volume_format"]
