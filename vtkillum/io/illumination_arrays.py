"""Illumination volumes as VTK arrays: what illumination filters write and mappers read.

An :class:`~vtkillum.core.illumination.IlluminationVolume` (direct light per light,
isotropic scattered fluence; see :mod:`vtkillum.core.illumination`) travels through a
VTK pipeline as point arrays of a ``vtkImageData`` covering the data's box (any
resolution):

``fluence`` (3 components, active scalars)
    ``sum_l T_l E_l + phi_s``, the total light as an isotropic fluence: a picture of
    the light for display and for consumers that cannot apply a phase function
    (point-light irradiance taken at the grid points, see
    :meth:`IlluminationVolume.fluence`).
``transmittance`` (one component per light)
    ``T_l`` in [0, 1] towards light ``l``, in the order of the lights below.
``scattered_fluence`` (3 components)
    ``phi_s``, the isotropic fluence of scattered light (zeros without scattering).

and field data ``vtkillum_lights``, one tuple of 8 per light: kind (0 directional,
1 point), travel direction or position (world), RGB irradiance or intensity, source
radius (0: half a voxel; 0 for directional lights; tuples of 7 are read as radius 0). A
consumer rebuilds the illumination volume with :func:`illumination_from_image`; an
image with only a ``fluence`` array (e.g. from another tool) is taken as an
isotropic scattered fluence.
"""

from __future__ import annotations

import numpy as np
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.lights import DIRECTIONAL, DirectionalLight, PointLight
from vtkillum.core.resample import resample_points
from vtkillum.io.convert import point_array

FLUENCE_ARRAY = "fluence"
TRANSMITTANCE_ARRAY = "transmittance"
SCATTERED_ARRAY = "scattered_fluence"
LIGHTS_FIELD = "vtkillum_lights"


def illumination_arrays(illumination: IlluminationVolume, volume, lights, shape) -> dict:
    """Point arrays of ``illumination`` on a grid of ``shape`` points (``fluence`` first).

    Parameters
    ----------
    illumination : IlluminationVolume
    volume : vtkillum.core.volume.Volume
        The data it covers (world frame of the lights).
    lights : sequence of lights
        The lights of its transmittance channels.
    shape : (3,) int
        Output grid; parts on another grid are resampled trilinearly.

    Returns
    -------
    dict
        ``fluence`` (nx, ny, nz, 3), ``transmittance`` (nx, ny, nz, n_lights) when the
        illumination has direct light, ``scattered_fluence`` (nx, ny, nz, 3).
    """
    shape = tuple(int(n) for n in shape)

    def on_grid(a):
        return a if a.shape[:3] == shape else resample_points(a, shape)

    arrays = {FLUENCE_ARRAY: on_grid(illumination.fluence(volume, lights))}
    if illumination.transmittance is not None:
        t = np.moveaxis(illumination.transmittance, 0, -1)
        arrays[TRANSMITTANCE_ARRAY] = np.clip(on_grid(t), 0.0, 1.0)
    scattered = illumination.scattered
    arrays[SCATTERED_ARRAY] = (np.zeros((*shape, 3), np.float32) if scattered is None
                               else on_grid(scattered))
    return arrays


def add_lights_field(image, lights) -> None:
    """Store ``lights`` as the field-data array ``vtkillum_lights`` (n, 8) of ``image``."""
    rows = np.zeros((len(lights), 8), np.float64)
    for i, light in enumerate(lights):
        if light.kind == DIRECTIONAL:
            rows[i] = [0, *light.direction, *light.irradiance, 0.0]
        else:
            rows[i] = [1, *light.position, *light.intensity, light.radius]
    array = numpy_to_vtk(rows, deep=True)
    array.SetName(LIGHTS_FIELD)
    image.GetFieldData().AddArray(array)


def lights_from_field(image) -> list | None:
    """The lights stored by :func:`add_lights_field`, or ``None`` when ``image`` has none."""
    array = image.GetFieldData().GetArray(LIGHTS_FIELD) if image is not None else None
    if array is None:
        return None
    width = array.GetNumberOfComponents()
    rows = vtk_to_numpy(array).reshape(-1, width)
    return [DirectionalLight(r[1:4], r[4:7]) if r[0] < 0.5
            else PointLight(r[1:4], r[4:7], r[7] if width > 7 else 0.0) for r in rows]


def illumination_array_names(image) -> tuple:
    """``(transmittance, scattered)``: the names of an illumination image's arrays to draw.

    ``(transmittance, scattered_fluence or None)`` when it has a transmittance (the
    phase-aware convention), else ``(None, fluence)`` (an isotropic scattered fluence);
    a ``ValueError`` when it has neither.
    """
    pd = image.GetPointData()
    if pd.GetArray(TRANSMITTANCE_ARRAY) is not None:
        return TRANSMITTANCE_ARRAY, (SCATTERED_ARRAY if pd.GetArray(SCATTERED_ARRAY) is not None
                                     else None)
    if pd.GetArray(FLUENCE_ARRAY) is not None:
        return None, FLUENCE_ARRAY
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    raise ValueError(
        f"the illumination image has neither a {TRANSMITTANCE_ARRAY!r} nor a "
        f"{FLUENCE_ARRAY!r} point array (it has {names}); connect an illumination "
        "filter's output"
    )


def illumination_from_image(image, volume) -> IlluminationVolume:
    """Rebuild an :class:`IlluminationVolume` covering ``volume`` from an image's arrays.

    ``transmittance`` + ``scattered_fluence`` when present (the phase-aware
    convention), else ``fluence`` as an isotropic scattered fluence (1 or 3
    components). The caller checks that the image covers the data's box.
    """
    transmittance = None
    t_name, name = illumination_array_names(image)
    if t_name is not None:
        t = point_array(image, t_name)
        t = t[..., None] if t.ndim == 3 else t
        transmittance = np.moveaxis(t, -1, 0)
    scattered = None
    if name is not None:
        values = point_array(image, name)
        if values.ndim == 3:
            values = np.repeat(values[..., None], 3, axis=-1)
        if values.shape[-1] != 3:
            raise ValueError(f"the {name!r} array must have 1 (grey) or 3 (RGB) components, "
                             f"got {values.shape[-1]}")
        scattered = values
    if transmittance is not None and scattered is not None and not np.any(scattered):
        scattered = None
    return IlluminationVolume.for_volume(volume, scattered, transmittance)
