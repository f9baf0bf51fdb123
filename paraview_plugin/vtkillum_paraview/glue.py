"""What the ParaView filter classes add to the library filters (:class:`ParaViewGlue`).

The plugin's classes are ``class X(IlluminatedRGBAOutput, ParaViewGlue, XFilter)``
(``ParaViewGlue`` alone for the optical properties). The glue

* takes the **Lights** table row by row (``AddLight``), checking every row and
  keeping a mistake as an error that names the row and the column;
* takes ParaView's **colour map** and **opacity function** of the coloured array
  (``SetLookupTable``/``SetOpacityFunction``, set by :mod:`.links`): the filter
  re-executes when their content changes (not on every ``Modified`` of ParaView's
  lookup table, which also fires when it is only rebuilt for rendering), and a
  multi-component array is reduced as the colour map says (*Magnitude* or a
  component: ``VectorMode``/``VectorComponent``);
* resolves **ScalarOpacityUnitDistance** 0 to ParaView's default for the display,
  the approximate cell length ``diagonal / cbrt(number of cells)``;
* keeps the output on the data's grid, the selected array as active scalars (so
  the display colours by it with its usual colour map), and adds the
  illumination in the project's convention (``DESIGN.md``):

  ``transmittance`` (L components, ``T_l`` towards light ``l``), ``scattered_fluence``
  (RGB), ``fluence`` (RGB, ``sum_l T_l E_l + phi_s``), field data ``vtkillum_lights``
  (L x 8: type, x, y, z, R, G, B, source radius; :mod:`vtkillum.io.illumination_arrays`)
  and ``vtkillum_render`` (albedo, anisotropy, opacity unit distance, exposure, largest
  spacing of the illumination grid). Illumination computed on a coarser grid
  (``LightVolumeScale`` < 1) is resampled trilinearly onto the data's grid;
* remembers the last computed illumination, so that settings that only change the
  picture (``Exposure``, ``Gamma``, ``RGBAType``, ``OutputRGBA``) do not recompute it;
* reports every error in ParaView's words: the property to change, no traceback,
  no VTK method names (:func:`paraview_message`).
"""

from __future__ import annotations

import math
import re

import numpy as np
from vtkmodules.vtkCommonCore import vtkDoubleArray, vtkStringArray

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.resample import resample_points

#: Point arrays of the illumination convention.
TRANSMITTANCE = "transmittance"
SCATTERED = "scattered_fluence"
FLUENCE = "fluence"
#: Field arrays read by the render view (:mod:`.display`).
LIGHTS_FIELD = "vtkillum_lights"
RENDER_FIELD = "vtkillum_render"
SCALARS_FIELD = "vtkillum_scalars"

#: Default Exposure: a fully lit voxel (irradiance 1, isotropic phase) shows albedo x colour.
DEFAULT_EXPOSURE = 4.0 * math.pi

#: Filter labels warned in this process that no transfer function is linked (pvserver).
_UNLINKED_WARNED: set = set()

#: Filter attributes that change only the picture, not the illumination.
RENDER_ONLY = frozenset({"_exposure", "_gamma", "_rgba_type", "_output_rgba"})
#: Attributes holding the optical model, which enters the memo key only as far as the
#: method depends on it (``relevant_model`` of the library filter).
_MODEL = frozenset({"_tf_key", "_tf_seen", "_albedo", "_anisotropy"})

_VTK_MAGNITUDE, _VTK_COMPONENT = 0, 1


def approximate_cell_length(image) -> float:
    """ParaView's default opacity unit distance: bounding-box diagonal / cbrt(cells)."""
    bounds = image.GetBounds()
    diagonal = math.sqrt(sum((bounds[2 * a + 1] - bounds[2 * a]) ** 2 for a in range(3)))
    cells = image.GetNumberOfCells()
    if cells <= 0 or diagonal <= 0:
        return 1.0
    return diagonal / cells ** (1.0 / 3.0)


def transfer_function_signature(function) -> tuple:
    """The content of a colour map or opacity function (what the illumination depends on)."""
    if function is None:
        return ()
    size = function.GetSize()
    width = 6 if hasattr(function, "GetColorSpace") else 4
    nodes = []
    for i in range(size):
        node = [0.0] * width
        function.GetNodeValue(i, node)
        nodes.append(tuple(node))
    extra = ()
    if width == 6:
        extra = (function.GetColorSpace(), function.GetScale(), function.GetHSVWrap(),
                 function.GetVectorMode(), function.GetVectorComponent())
    return (tuple(nodes), extra)


class _LightRowError(ValueError):
    pass


class ParaViewGlue:
    """Mixin for the plugin's filter classes; see the module docstring."""

    #: The label of the menu entry (set by the plugin), used in error messages.
    paraview_label = "vtkIllum"
    #: Whether the output stays on the data's grid (illumination resampled onto it).
    full_resolution_output = True
    #: Attributes ``compute`` sets besides its arrays, restored when the remembered
    #: illumination is reused (see :meth:`compute`).
    memo_attributes: tuple = ()
    #: The glue keeps its own memo of the last illumination (:meth:`compute`), which also
    #: restores :attr:`memo_attributes`; the library filters' shared memo is not used.
    reuses_results = False

    def __init__(self) -> None:
        super().__init__()
        self._light_rows: list = []
        self._light_error: str | None = None
        self._lookup_table = None
        self._opacity_function = None
        self._tf_observers: list = []
        self._tf_key = ((), ())
        self._memo = None  # (key, arrays) of the last computed illumination
        if not hasattr(self, "_exposure"):
            self._exposure = DEFAULT_EXPOSURE
        try:  # ParaView's server-manager links (client side, builtin sessions)
            from vtkillum_paraview import links

            links.install()
        except Exception:  # noqa: BLE001 - on a pvserver there is no client to link
            pass

    # === properties ================================================================================
    @staticmethod
    def property_setter(method):
        """Wrap a property's ``SetX``: a value it refuses becomes an error of the next
        execution (named after the property, no traceback), not an exception inside
        ParaView's property push."""
        import functools

        name = method.__name__[3:]

        @functools.wraps(method)
        def setter(self, *args):
            errors = self.__dict__.setdefault("_property_errors", {})
            try:
                result = method(self, *args)
            except (TypeError, ValueError) as err:
                message = paraview_message(err)
                errors[name] = message if name in message else f"{name}: {message}"
                self.Modified()
                return None
            if errors.pop(name, None) is not None:
                self.Modified()
            return result

        return setter

    # === Lights table ===========================================================================
    def AddLight(self, kind, x, y, z, r, g, b, radius=0.0) -> None:
        """One row of the ``Lights`` table: Type (0 directional, 1 point), X Y Z, R G B, Radius."""
        row = len(self._light_rows) + 1
        self._light_rows.append((kind, x, y, z, r, g, b, radius))
        if self._light_error is not None:
            self.Modified()
            return
        try:
            self._add_light_row(row, kind, (x, y, z), (r, g, b), radius)
        except _LightRowError as err:
            self._light_error = str(err)
            self.Modified()
        except ValueError as err:  # the core's own limits (e.g. values beyond float32)
            self._light_error = f"Lights row {row}: {err}".replace("light.", "")
            self.Modified()

    def _add_light_row(self, row, kind, xyz, rgb, radius) -> None:
        values = [float(v) for v in (kind, *xyz, *rgb, radius)]
        if not all(math.isfinite(v) for v in values):
            raise _LightRowError(f"Lights row {row}: every column must be a finite number")
        if values[0] not in (0.0, 1.0):
            raise _LightRowError(f"Lights row {row}: Type must be 0 (directional) or 1 (point), "
                                 f"got {kind:g}")
        if min(values[4:7]) < 0:
            name = "irradiance" if values[0] == 0 else "intensity"
            raise _LightRowError(f"Lights row {row}: R G B (the {name}) must not be negative")
        if values[7] < 0:
            raise _LightRowError(f"Lights row {row}: Radius must not be negative (0: half a "
                                 "voxel)")
        if values[0] == 0:
            if not any(values[1:4]):
                raise _LightRowError(f"Lights row {row}: X Y Z (the direction the light travels) "
                                     "must not be 0 0 0")
            self._add_light(DirectionalLight(values[1:4], values[4:7]))
        else:
            self._add_light(PointLight(values[1:4], values[4:7], values[7]))

    def RemoveAllLights(self) -> None:
        self._light_rows = []
        if self._light_error is not None:
            self._light_error = None
            self.Modified()
        super().RemoveAllLights()

    def GetLightsTable(self) -> list:
        """The lights as table rows ``[type, x, y, z, r, g, b, radius]`` (world coordinates)."""
        return [light_row(light) for light in self.GetLights()]

    # === ParaView's colour map and opacity function ============================================
    def SetLookupTable(self, lut) -> None:
        """ParaView's colour map of the coloured array (a ``vtkDiscretizableColorTransferFunction``)."""
        lut = lut if hasattr(lut, "GetNodeValue") else None  # ParaView sends 0 for "none"
        if lut is self._lookup_table:
            return
        self._lookup_table = lut
        self._watch_transfer_functions()

    def GetLookupTable(self):
        return self._lookup_table

    def SetOpacityFunction(self, function) -> None:
        """ParaView's scalar opacity function of the coloured array (opacity per unit distance)."""
        function = function if hasattr(function, "GetNodeValue") else None
        if function is self._opacity_function:
            return
        self._opacity_function = function
        self._watch_transfer_functions()

    def GetOpacityFunction(self):
        return self._opacity_function

    def _watch_transfer_functions(self) -> None:
        for obj, tag in self._tf_observers:
            obj.RemoveObserver(tag)
        self._tf_observers = []
        from vtkmodules.vtkCommonCore import vtkWeakReference

        ref = vtkWeakReference()
        ref.Set(self)

        def changed(caller, event, ref=ref):
            target = ref.Get()
            if target is not None:
                target._transfer_functions_changed()

        for obj in (self._lookup_table, self._opacity_function):
            if obj is not None:
                self._tf_observers.append((obj, obj.AddObserver("ModifiedEvent", changed)))
        self._transfer_functions_changed(force=True)

    def _transfer_functions_changed(self, force: bool = False) -> None:
        key = (transfer_function_signature(self._lookup_table),
               transfer_function_signature(self._opacity_function))
        if force or key != self._tf_key:
            self._tf_key = key
            # The base class reads these two; edits reach it through this observer only.
            self._color_tf = self._lookup_table
            self._opacity_tf = self._opacity_function
            self.Modified()

    # === execution ===============================================================================
    def output_shape(self, dims) -> tuple:
        # The data's grid: the display renders the passed-through array, the illumination is
        # resampled onto it (see compute).
        if self.full_resolution_output:
            return tuple(int(n) for n in dims)
        return super().output_shape(dims)

    def light_grid_shape(self, dims) -> tuple:
        """The grid the illumination is computed on (LightVolumeScale / OutputScale)."""
        return super().output_shape(dims)

    def _execute(self, image, out_info):
        return self._with_paraview_defaults(image, image,
                                            lambda: super(ParaViewGlue, self)._execute(image,
                                                                                       out_info))

    def _execute_piece(self, image, in_info, out_info, piece, pieces):
        # Distributed mode: the defaults one rank takes from the whole image (its bounds
        # and cells give the opacity unit distance), not from this rank's piece.
        from vtkmodules.vtkCommonDataModel import vtkImageData
        from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

        whole = vtkImageData()  # the whole extent's geometry, no arrays
        whole.SetExtent(in_info.Get(SDDP.WHOLE_EXTENT()))
        whole.SetOrigin(image.GetOrigin())
        whole.SetSpacing(image.GetSpacing())
        whole.SetDirectionMatrix(image.GetDirectionMatrix())
        return self._with_paraview_defaults(
            image, whole, lambda: super(ParaViewGlue, self)._execute_piece(
                image, in_info, out_info, piece, pieces))

    def _with_paraview_defaults(self, image, whole, execute):
        """Run ``execute()`` with ParaView's defaults resolved (the colour map's component,
        the unit distance of ``whole``), then finish its output."""
        if self._light_error is not None:
            raise ValueError(self._light_error)
        for message in self.__dict__.get("_property_errors", {}).values():
            raise ValueError(message)
        name, association = self._selected_array(image)
        if name is None and image.GetPointData().GetScalars() is not None:
            name = image.GetPointData().GetScalars().GetName()  # the default: active scalars
        array = None
        if name is not None:
            data = image.GetCellData() if association == "cells" else image.GetPointData()
            array = data.GetArray(name)
            if array is None and association is None:
                array = image.GetCellData().GetArray(name)
            if array is None:
                raise ValueError(f"Scalars: the input has no array {name!r}; "
                                 + _describe_arrays(image))
        self._warn_unlinked_on_server()
        saved = (self._input_component, self._unit_distance)
        try:
            if array is not None and array.GetNumberOfComponents() > 1:
                self._input_component = self._component_from_colour_map(array)
            if self._unit_distance == 0:
                self._unit_distance = approximate_cell_length(whole)
            self._resolved_unit_distance = self._unit_distance
            output = execute()
        finally:
            self._input_component, self._unit_distance = saved
        self._finish_output(output, name)
        return output

    def _component_from_colour_map(self, array) -> int:
        lut = self._lookup_table
        ncomp = array.GetNumberOfComponents()
        if lut is None or lut.GetVectorMode() != _VTK_COMPONENT:
            return -1  # magnitude, as ParaView colours a vector by default
        return min(max(int(lut.GetVectorComponent()), 0), ncomp - 1)

    def compute(self, volume, params):
        shape = self.light_grid_shape(volume.dims)
        # The largest spacing of the grid the illumination is computed on (the render view
        # marches two of its cells exactly before it reads the transmittance).
        self._light_spacing = float(max(
            e / max(n - 1, 1) for e, n in zip(volume.extent, shape)))
        key = self._memo_key(volume, params, shape)
        if self._memo is not None and self._memo[0] == key:
            arrays = self._memo[1]
            for name, value in self._memo[2].items():  # e.g. the virtual lights of port 1
                setattr(self, name, value)
        else:
            self._memo = None
            light_params = _replace(params, output_shape=shape)
            arrays = convention_arrays(super().compute(volume, light_params), params.lights)
            self._memo = (key, arrays, {name: getattr(self, name, None)
                                        for name in self.memo_attributes})
        if shape != tuple(params.output_shape):
            arrays = {k: resample_points(v, params.output_shape) for k, v in arrays.items()}
        return dict(arrays)

    def compute_piece(self, volume, params, piece):
        # Distributed mode (the data grid): the light spacing one rank finds for the whole
        # grid, and the arrays in the convention, as compute gives them.
        dims = [piece.whole[2 * a + 1] - piece.whole[2 * a] + 1 for a in range(3)]
        self._light_spacing = float(max((n - 1) * s / max(n - 1, 1)
                                        for s, n in zip(volume.spacing, dims)))
        return convention_arrays(super().compute_piece(volume, params, piece), params.lights)

    compute_piece.wraps_compute_piece = True

    def _memo_key(self, volume, params, shape) -> tuple:
        image = self.GetInputDataObject(0, 0)
        own = tuple(sorted((k, _plain(v)) for k, v in vars(self).items()
                           if k not in RENDER_ONLY and k not in _MODEL
                           and _plain(v) is not None))
        # Only what the method's illumination depends on (a colour-map edit does not
        # recompute Light Transmittance's shadows: its baked RGBA and the render view take
        # the colours afterwards).
        return (id(image), image.GetMTime() if image is not None else 0, volume.dims, shape,
                self.relevant_model(params), own)

    def _finish_output(self, output, name) -> None:
        pd = output.GetPointData()
        if name is not None and pd.GetArray(name) is not None and \
                not getattr(self, "_output_rgba", False):
            pd.SetActiveScalars(name)
        fd = output.GetFieldData()  # (the lights, vtkillum_lights, come from the base class)
        render = vtkDoubleArray()
        render.SetName(RENDER_FIELD)
        for value in (self.GetAlbedo(), self.GetAnisotropy(),
                      getattr(self, "_resolved_unit_distance", 1.0), self._exposure,
                      getattr(self, "_light_spacing", 0.0)):
            render.InsertNextValue(float(value))
        fd.AddArray(render)
        scalars = vtkStringArray()
        scalars.SetName(SCALARS_FIELD)
        scalars.InsertNextValue(name or "")
        fd.AddArray(scalars)

    def _warn_unlinked_on_server(self) -> None:
        """Once, in a pvserver process: no colour map or opacity function is linked.

        The links to the display's transfer functions are made by the plugin's client-side
        Python (:mod:`vtkillum_paraview.links`); a plugin loaded on the server only leaves
        them empty, and the filter would silently use its default ramp instead of the
        colour map the user sees."""
        if self._lookup_table is not None or self._opacity_function is not None or \
                self.paraview_label in _UNLINKED_WARNED:
            return
        try:
            from paraview.modules.vtkRemotingCore import vtkProcessModule
        except ImportError:
            return
        module = vtkProcessModule.GetProcessModule()
        if module is None or module.GetProcessType() not in (
                vtkProcessModule.PROCESS_SERVER, vtkProcessModule.PROCESS_DATA_SERVER,
                vtkProcessModule.PROCESS_RENDER_SERVER):
            return
        _UNLINKED_WARNED.add(self.paraview_label)  # once per filter kind and process
        from vtkmodules.vtkCommonCore import vtkOutputWindow

        vtkOutputWindow.GetInstance().DisplayWarningText(
            f"{self.paraview_label}: no colour map or opacity function is linked, so the "
            "illumination uses a default ramp over the data range, not your colour map: load "
            "the vtkIllum plugin on the client too (Tools > Manage Plugins > Load New under "
            "Local Plugins, or LoadPlugin(path, remote=False) in pvpython)\n")

    # === errors ==================================================================================
    def _report(self, err: Exception) -> None:
        self._last_error = err
        message = f"{self.paraview_label}: {paraview_message(err)}"
        if self.HasObserver("ErrorEvent"):
            self.InvokeEvent("ErrorEvent", message)
        else:
            from vtkmodules.vtkCommonCore import vtkOutputWindow

            vtkOutputWindow.GetInstance().DisplayErrorText(message + "\n")

    # === information property ====================================================================
    def GetCacheStatisticsVector(self) -> list:
        stats = self.GetCacheStatistics()
        return [float(stats.hits), float(stats.misses), float(stats.entries),
                stats.bytes / 2.0**20]


def light_row(light) -> list:
    """``[type, x, y, z, r, g, b, radius]`` of a core light (0 directional, 1 point)."""
    if isinstance(light, PointLight):
        return [1.0, *map(float, light.position), *map(float, light.intensity),
                float(light.radius)]
    return [0.0, *map(float, light.direction), *map(float, light.irradiance), 0.0]


def convention_arrays(arrays: dict, lights) -> dict:
    """The filter's arrays in the illumination convention (see the module docstring).

    ``transmittance_<l>`` are stacked into one L-component ``transmittance``; a
    ``direct_fluence`` becomes ``scattered_fluence = fluence - direct_fluence``; a
    method without scattered light gets zeros; the ambient radiance cache becomes
    ``fluence``. Arrays already in the convention pass unchanged.
    """
    out = dict(arrays)
    per_light = [out.pop(f"{TRANSMITTANCE}_{i}") for i in range(len(lights))
                 if f"{TRANSMITTANCE}_{i}" in out]
    if TRANSMITTANCE not in out and per_light and len(per_light) == len(lights):
        out[TRANSMITTANCE] = np.stack(per_light, axis=-1).astype(np.float32)
    if FLUENCE not in out and "ambient_radiance" in out:
        out[FLUENCE] = out["ambient_radiance"]
    if TRANSMITTANCE in out and SCATTERED not in out:
        direct = out.pop("direct_fluence", None)
        if direct is not None and FLUENCE in out:
            out[SCATTERED] = np.maximum(np.asarray(out[FLUENCE]) - direct, 0.0).astype(np.float32)
        else:
            shape = np.asarray(out[TRANSMITTANCE]).shape[:3]
            out[SCATTERED] = np.zeros(shape + (3,), dtype=np.float32)
    return out


_API_WORDS = [
    (re.compile(r"choose one with component=<index> \(0 \.\. (\d+)\) or component='magnitude'"),
     r"colour by Magnitude or by one component (0 .. \1) in the display (the filter follows "
     "the colour map)"),
    (re.compile(r"add one with AddDirectionalLight\([^)]*\)( or AddPointLight\(\.\.\.\))?"),
     "add a row to Lights"),
    (re.compile(r"call ComputeRadianceOff\(\) for the ambient extinction alone"),
     "switch ComputeRadiance off for the ambient extinction alone"),
    (re.compile(r"name one with array_name=\.\.\."), "choose one in Scalars"),
    (re.compile(r"the scalar opacity function has no points; add some with AddPoint\(x, a\)"),
     "the opacity function of the colour map has no points; add some in the Color Map Editor"),
    (re.compile(r"\bScalarOpacityUnitDistance\b"), "Scalar Opacity Unit Distance"),
    (re.compile(r"\bOutputScale\b"), "LightVolumeScale"),
    (re.compile(r"\bAnisotropy \(Henyey-Greenstein g\)"), "Anisotropy"),
    (re.compile(r"\(Update\(\)\)"), "(Apply it)"),
    (re.compile(r"\bNaNPolicy\b"), "NaN handling"),
]


def paraview_message(err: Exception) -> str:
    """``err`` reworded for a ParaView user: property names, no VTK or Python API names."""
    text = str(err)
    for pattern, replacement in _API_WORDS:
        text = pattern.sub(replacement, text)
    # "LightTransmittanceFilter has no lights" -> "no lights" (the label is prefixed).
    text = re.sub(r"^\w+Filter(:| has)", lambda m: "the filter" + ("" if m.group(1) == ":"
                                                                    else " has"), text)
    return text


def _describe_arrays(image) -> str:
    names = []
    for data, where in ((image.GetPointData(), "point"), (image.GetCellData(), "cell")):
        names += [f"{data.GetArrayName(i)} ({where})" for i in range(data.GetNumberOfArrays())]
    return "it has " + (", ".join(names) if names else "no arrays")


def _plain(value):
    """A hashable form of simple attribute values (others give None and are left out)."""
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    if isinstance(value, (tuple, list)) and all(isinstance(v, (bool, int, float, str)) for v in value):
        return tuple(value)
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        items = tuple(sorted((k, _plain(v)) for k, v in value.items()))
        return items if all(v is not None or value[k] is None for k, v in items) else None
    return None


def _replace(params, **changes):
    import dataclasses

    return dataclasses.replace(params, **changes)


__all__ = [
    "DEFAULT_EXPOSURE",
    "FLUENCE",
    "LIGHTS_FIELD",
    "RENDER_FIELD",
    "SCALARS_FIELD",
    "SCATTERED",
    "TRANSMITTANCE",
    "ParaViewGlue",
    "approximate_cell_length",
    "convention_arrays",
    "light_row",
    "paraview_message",
    "transfer_function_signature",
]
