"""An ``illuminated_rgba`` output that any standard volume mapper renders directly.

The baked route, for where the illumination cannot be applied per sample at render
time (ParaView with a remote server or several ranks: the plugin's render-view
illumination, ``paraview_plugin/vtkillum_paraview/display.py``, needs the data in
the client). Every volume mapper renders a 4-component array without a colour map
(``MapScalars = 0``, ``MultiComponentsMapping = 1``): RGB is the sample colour,
the fourth component goes through the scalar-opacity function. This module adds
such an array to the output of an illumination filter (one that produces the RGB
fluence ``fluence``, in the illumination convention ``sum_l T_l E_l + phi_s``)::

    rgb   = clip(Exposure * albedo * color(s) * fluence / (4 pi), 0, 1) ** (1 / Gamma)
    alpha = opacity(s)                    (per opacity unit distance u)

Why this is the illuminated image: VTK's ray caster accumulates, per step,
``C += T * a * rgb`` with ``a = 1 - (1 - alpha) ** (step / u) = 1 - exp(-sigma_t step)``
(its opacity correction). With ``rgb = albedo * color * phi / (4 pi)`` that is
exactly the source term ``sigma_s * phi / (4 pi)`` of
:mod:`vtkillum.core.illumination` integrated over the step (``sigma_t`` cancels),
i.e. what :class:`~vtkillum.mappers.IlluminatedVolume` composites with
``exposure = Exposure`` and the default shading (``S = 1``), as long as
``Gamma = 1`` and nothing is clipped. The mapper's opacity function on the fourth
component must therefore give back ``alpha`` (0 → 0, 1 → 1, or 255 → 1 for
``uint8``) with the filter's opacity unit distance ``u``. (VTK 9.2 corrects the
opacity of RGBA data with the unit distance of the fourth component, which
ParaView 5.11 leaves at 1; the plugin's ``ShowIlluminated`` then maps ``a`` to
``1 - (1 - a) ** (1 / u)`` instead, the same opacity per world unit.)

VTK 9.2 also reads RGBA components raw (0..1 of the type's range) but samples the
opacity function over the fourth component's *data* range, so the opacity of a
sample would depend on the largest opacity in the volume. The filter therefore
declares the array's nominal range, [0, 255] or [0, 1] for every component, as
its cached component range (:func:`declare_nominal_range`); VTK then samples the
opacity function over [0, 255] or [0, 1], consistent with the raw lookup.

Simplifications
---------------
* With ``OutputRGBA`` on, the output grid is the data's: the RGBA array needs the
  data's resolution to look sharp, so an illumination volume computed at a lower
  resolution (``OutputScale`` / ``LightVolumeScale`` < 1) is resampled trilinearly
  onto it, as the ray casters sample it, together with the filter's other arrays.
* For the ambient extinction filter ``phi`` is its radiance cache
  ``ambient_radiance`` (the light reaching each point through the ambient
  extinction) taken at the sample itself: the gather over the ambient sphere of
  Ament et al. (which the ``ambient-scattering`` render method does) is skipped.
* The light is taken as isotropic (``fluence / 4 pi``): no Henyey-Greenstein phase
  function for the direct light (exact only for ``Anisotropy`` 0), which the
  per-sample route applies.
* The product ``color * phi`` is interpolated between grid points by the mapper
  (not ``color`` and ``phi`` separately), and Phong terms (``S``) are not applied.
* ``uint8`` output quantises colour and opacity to 1/255 (``float32`` keeps them);
  values above 1 after the exposure are clipped (lower ``Exposure`` if the lit
  parts saturate).
* The default ``Exposure = 4 pi`` shows a fully lit voxel under one white light
  of irradiance 1 in ``albedo * color``, about the colour ParaView would show
  without illumination.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from vtkmodules.vtkCommonCore import vtkDataArray, vtkInformationVector
from vtkmodules.vtkCommonDataModel import vtkImageData

from vtkillum.core.resample import resample_points
from vtkillum.core.transfer_function import TransferFunction

#: Name of the RGBA array added to the output.
RGBA_ARRAY = "illuminated_rgba"

#: Name of the fluence array the illumination filters produce.
FLUENCE_ARRAY = "fluence"

#: Arrays that serve as ``phi``, in order of preference: the fluence, else the ambient
#: radiance cache of :class:`~vtkillum.filters.ambient_extinction.AmbientExtinctionFilter`.
LIGHT_ARRAYS = (FLUENCE_ARRAY, "ambient_radiance")

#: Default exposure: a fully lit voxel (phi = 1) shows albedo * color.
DEFAULT_EXPOSURE = 4.0 * math.pi

RGBA_TYPES = ("uint8", "float32")


def illuminated_rgba(scalars, transfer_function: TransferFunction, albedo: float, fluence,
                     exposure: float = DEFAULT_EXPOSURE, gamma: float = 1.0,
                     dtype: str = "uint8") -> np.ndarray:
    """Colour times illumination and opacity per grid point (see the module docstring).

    Parameters
    ----------
    scalars : ndarray (nx, ny, nz)
        Data values on the grid of ``fluence``.
    transfer_function : TransferFunction
        Colour and opacity of the data values.
    albedo : float
        Single-scattering albedo in [0, 1].
    fluence : ndarray (nx, ny, nz, 3)
        RGB fluence ``phi`` (the lights' irradiance units).
    exposure : float
        Positive factor on the radiance per step; default ``4 pi``.
    gamma : float
        Positive display gamma applied to the clipped colour; 1 keeps it linear.
    dtype : {"uint8", "float32"}
        ``uint8``: components scaled to 0..255; ``float32``: 0..1.

    Returns
    -------
    ndarray (nx, ny, nz, 4)
        ``(r, g, b, alpha)``.
    """
    scalars = np.asarray(scalars)
    fluence = np.asarray(fluence, dtype=np.float32)
    if fluence.ndim != 4 or fluence.shape[-1] != 3 or fluence.shape[:3] != scalars.shape:
        raise ValueError(
            f"fluence of shape {fluence.shape} does not match the scalars {scalars.shape}; "
            "expected (nx, ny, nz, 3) on the same grid"
        )
    if not (math.isfinite(exposure) and exposure > 0):
        raise ValueError(f"Exposure must be a positive number, got {exposure}")
    if not (math.isfinite(gamma) and gamma > 0):
        raise ValueError(f"Gamma must be a positive number, got {gamma}")
    if dtype not in RGBA_TYPES:
        raise ValueError(f"RGBA type must be one of {RGBA_TYPES}, got {dtype!r}")
    scale = exposure * albedo / (4.0 * math.pi)
    rgb = np.clip(scale * transfer_function.color(scalars) * fluence, 0.0, 1.0)
    if gamma != 1.0:
        rgb = rgb ** (1.0 / gamma)
    rgba = np.concatenate([rgb, transfer_function.alpha(scalars)[..., None]], axis=-1)
    if dtype == "uint8":
        return np.round(rgba * 255.0).astype(np.uint8)
    return rgba.astype(np.float32)


def declare_nominal_range(array) -> None:
    """Cache ``[0, 255]`` (integer types) or ``[0, 1]`` as every component's range of ``array``.

    ``GetRange``/``GetFiniteRange`` then return it until the array is modified. Used on
    the RGBA output so that VTK's opacity table spans the values it is indexed with
    (see the module docstring). Raises ``ValueError`` if a value lies outside.
    """
    top = 1.0 if array.GetDataType() in (10, 11) else 255.0  # VTK_FLOAT, VTK_DOUBLE
    for c in range(array.GetNumberOfComponents()):
        lo, hi = array.GetRange(c)
        if lo < 0.0 or hi > top:
            raise ValueError(f"array {array.GetName()!r} component {c} spans [{lo}, {hi}], "
                             f"outside its nominal range [0, {top}]")
    ranges = vtkInformationVector()
    ranges.SetNumberOfInformationObjects(array.GetNumberOfComponents())
    for c in range(array.GetNumberOfComponents()):
        ranges.GetInformationObject(c).Set(vtkDataArray.COMPONENT_RANGE(), [0.0, top], 2)
    info = array.GetInformation()
    info.Set(vtkDataArray.PER_COMPONENT(), ranges)
    info.Set(vtkDataArray.PER_FINITE_COMPONENT(), ranges)


class IlluminatedRGBAOutput:
    """Mixin for illumination filters: also output :data:`RGBA_ARRAY` (the active scalars).

    Put it before the filter class: ``class F(IlluminatedRGBAOutput,
    LightTransmittanceFilter)``, or use :func:`with_rgba_output`. The filter's
    ``compute`` must return one of :data:`LIGHT_ARRAYS` (RGB).

    Parameters
    ----------
    OutputRGBA : bool
        Add the array (default on). Off: the filter's arrays only.
    Exposure : float
        Factor on the radiance per step; default ``4 pi`` (see the module docstring).
    Gamma : float
        Display gamma of the colour; default 1 (linear, as VTK's frame buffer).
    RGBAType : str
        ``"uint8"`` (default; what every VTK volume mapper renders) or ``"float32"``.
    """

    def __init__(self) -> None:
        super().__init__()
        self._output_rgba = True
        self._exposure = DEFAULT_EXPOSURE
        self._gamma = 1.0
        self._rgba_type = "uint8"

    def SetOutputRGBA(self, on: bool) -> None:
        self.set_parameter("_output_rgba", bool(on))

    def GetOutputRGBA(self) -> bool:
        return self._output_rgba

    def SetExposure(self, exposure: float) -> None:
        exposure = float(exposure)
        if not (math.isfinite(exposure) and exposure > 0):
            raise ValueError(f"Exposure must be a positive number, got {exposure}")
        self.set_parameter("_exposure", exposure)

    def GetExposure(self) -> float:
        return self._exposure

    def SetGamma(self, gamma: float) -> None:
        gamma = float(gamma)
        if not (math.isfinite(gamma) and gamma > 0):
            raise ValueError(f"Gamma must be a positive number, got {gamma}")
        self.set_parameter("_gamma", gamma)

    def GetGamma(self) -> float:
        return self._gamma

    def SetRGBAType(self, dtype) -> None:
        """``"uint8"`` or ``"float32"`` (also 0 / 1, as ParaView's enumeration sends)."""
        if isinstance(dtype, (int, np.integer)) and not isinstance(dtype, bool) \
                and 0 <= int(dtype) < len(RGBA_TYPES):
            dtype = RGBA_TYPES[int(dtype)]
        if dtype not in RGBA_TYPES:
            raise ValueError(f"RGBAType must be one of {RGBA_TYPES}, got {dtype!r}")
        self.set_parameter("_rgba_type", dtype)

    def GetRGBAType(self) -> str:
        return self._rgba_type

    def RequestData(self, request, inInfo, outInfo):
        ok = super().RequestData(request, inInfo, outInfo)
        if ok and self._output_rgba:
            array = vtkImageData.GetData(outInfo).GetPointData().GetArray(RGBA_ARRAY)
            if array is not None:
                declare_nominal_range(array)
        return ok

    def output_shape(self, dims) -> tuple:
        # With RGBA on the output is at the data's resolution (see the module docstring);
        # the illumination itself is computed at the resolution the filter would use.
        if self._output_rgba:
            return tuple(int(n) for n in dims)
        return super().output_shape(dims)

    def distributed_unsupported(self) -> str | None:
        reason = super().distributed_unsupported()
        if reason is None and self._output_rgba and (
                self._output_scale != 1.0 or tuple(self._output_dimensions) != (0, 0, 0)):
            reason = ("the light grid differs from the data grid (OutputScale / "
                      "OutputDimensions); the distributed methods compute on the data grid")
        return reason

    def _light_array(self, arrays: dict) -> str:
        """The name of the light array the RGBA is built from (an error if none)."""
        light = next((name for name in LIGHT_ARRAYS if name in arrays), None)
        if light is None:
            raise ValueError(
                f"{type(self).__name__}: the illumination filter returned none of "
                f"{LIGHT_ARRAYS} (got {sorted(arrays)}), so there is nothing to build the RGBA "
                "output from; switch OutputRGBA off (or ComputeRadiance on)"
            )
        return light

    def compute_piece(self, volume, params, piece):
        """The illumination filter's distributed piece, plus the RGBA of the piece."""
        arrays = super().compute_piece(volume, params, piece)
        if not self._output_rgba:
            return arrays
        light = self._light_array(arrays)
        cut = tuple(slice(piece.extent[2 * a] - piece.data_extent[2 * a],
                          piece.extent[2 * a + 1] - piece.data_extent[2 * a] + 1)
                    for a in range(3))
        rgba = illuminated_rgba(volume.scalars[cut], params.transfer_function, params.albedo,
                                arrays[light], self._exposure, self._gamma, self._rgba_type)
        return {RGBA_ARRAY: rgba, **arrays}

    compute_piece.wraps_compute_piece = True

    def compute(self, volume, params):
        if not self._output_rgba:
            return super().compute(volume, params)
        light_shape = super().output_shape(volume.dims)
        arrays = super().compute(volume, dataclasses.replace(params, output_shape=light_shape))
        if light_shape != params.output_shape:
            arrays = {name: resample_points(values, params.output_shape)
                      for name, values in arrays.items()}
        light = self._light_array(arrays)
        rgba = illuminated_rgba(volume.scalars, params.transfer_function, params.albedo,
                                arrays[light], self._exposure, self._gamma, self._rgba_type)
        return {RGBA_ARRAY: rgba, **arrays}


_RGBA_CLASSES: dict = {}


def with_rgba_output(filter_class):
    """The subclass of ``filter_class`` with :class:`IlluminatedRGBAOutput` mixed in.

    Examples
    --------
    >>> from vtkillum.filters import LightTransmittanceFilter
    >>> cls = with_rgba_output(LightTransmittanceFilter)
    >>> cls.__name__
    'LightTransmittanceRGBAFilter'
    >>> cls().GetExposure() > 12.5
    True
    """
    if filter_class not in _RGBA_CLASSES:
        name = filter_class.__name__.removesuffix("Filter") + "RGBAFilter"
        _RGBA_CLASSES[filter_class] = type(name, (IlluminatedRGBAOutput, filter_class), {
            "__doc__": f"{filter_class.__name__} with an ``{RGBA_ARRAY}`` output "
                       f"(see :class:`IlluminatedRGBAOutput`).",
            "__module__": __name__,
        })
    return _RGBA_CLASSES[filter_class]
