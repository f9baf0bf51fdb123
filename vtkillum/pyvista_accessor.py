"""pyvista integration: the ``grid.illum`` accessor, :func:`add_illuminated_volume` and
:func:`add_computed_volume`.

Importing this module registers the accessor (pyvista >= 0.48) on
``pyvista.ImageData``::

    import pyvista as pv
    import vtkillum.pyvista_accessor  # noqa: F401  (registers grid.illum)

    grid = pv.examples.download_head()            # any pv.ImageData with point scalars
    lit = grid.illum.transmittance(lights=[vtkillum.DirectionalLight((1, -1, -1))],
                                   cmap="bone", opacity="sigmoid")
    pl = pv.Plotter()
    vtkillum.pyvista_accessor.add_illuminated_volume(pl, grid, illumination=lit,
                                                     cmap="bone", opacity="sigmoid")

or, on the compute path (any method of :data:`vtkillum.METHODS` rendered by warp at the
plotter's camera each time it moves: the fast interactive path with CUDA)::

    pl = pv.Plotter()
    grid.illum.add_computed(pl, "transmittance", cmap="bone", opacity="sigmoid")
    pl.show()

The methods run the filters of :mod:`vtkillum.filters` and return new
``pyvista.ImageData`` holding their arrays; each is also a plain function of this
module taking the grid first (``transmittance(grid, ...)``).

Transfer functions follow ``Plotter.add_volume``: ``cmap`` (a colormap name,
matplotlib colormap, list of colours or ``pyvista.LookupTable``), ``opacity`` (a
name such as ``'linear'``, ``'sigmoid'``, ``'geom_r'``, a float or a list of
values spread over ``clim``), ``clim`` (default: the range of the rendered values;
``(low, high)`` with ``low < high``, or one positive ``c`` for ``(-c, c)``),
``n_colors`` (>= 1) and ``flip_scalars``; the tables are built with ``pyvista.LookupTable`` exactly as
``add_volume`` builds them. ``opacity_unit_distance`` defaults to pyvista's too
(``grid.length / (mean(grid.dimensions) - 1)``), so a given ``cmap``/``opacity``
looks as dense as with ``add_volume``. Alternatively pass ``transfer_function=``
a :class:`vtkillum.TransferFunction`.

The rendered array is ``scalars=`` (a point array, or a cell array averaged onto the
points as ``add_volume`` does; default the active scalars), its ``component=`` for
multi-component arrays (an index, or -1 / ``"magnitude"``) and ``nan_policy=``
(``"raise"`` or ``"fill"``), as the filters' ``InputComponent`` and ``NaNPolicy``.
Every function takes them, and every one reads them (and the transfer function
arguments) through one parser, :func:`_parse_inputs`, so that no function can honour
an option another ignores. NaN or infinity in ``opacity`` (or any transfer function)
is refused. pyvista drops the mask of a numpy masked array when it stores it on a grid:
to render masked samples transparent store ``array.filled(np.nan)`` and pass
``nan_policy="fill"``.

The accessor exists on ``pyvista.ImageData`` only; on other datasets (``PolyData``,
``UnstructuredGrid``, ...) ``mesh.illum`` raises an ``AttributeError`` that says how to
resample onto a uniform grid (``pv.ImageData(...).sample(mesh)``).

Lights are :class:`vtkillum.DirectionalLight` / :class:`vtkillum.PointLight`, or
``pyvista.Light`` objects (a directional light travels from ``position`` towards
``focal_point`` with irradiance ``intensity * color``; a positional one becomes
a point light of intensity ``intensity * color``). Default: one white directional
light travelling along (1, -1, -1) for the filters; :func:`render` takes the command
line's defaults (:mod:`vtkillum.core.defaults`: the data-aware camera, a key light from
its upper front-left, automatic exposure, 256² on a CPU and 512² with CUDA), so that it
draws what ``vtkillum render`` draws.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import numpy as np
import pyvista as pv
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render as core_render
from vtkillum.core.scene import Scene
from vtkillum.core.scene import _short  # repr cut to a readable length (user values)
from vtkillum.core.tonemap import write_png
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.ambient_extinction import AmbientExtinctionFilter
from vtkillum.filters.convection_diffusion_light import ConvectionDiffusionLightFilter
from vtkillum.filters.light_transmittance import LightTransmittanceFilter
from vtkillum.filters.many_lights import ManyLightsFilter
from vtkillum.filters.optical_properties import OpticalPropertiesFilter
from vtkillum.filters.photon_density import PhotonDensityFilter
from vtkillum.filters.rgba_output import DEFAULT_EXPOSURE, with_rgba_output
from vtkillum.io.convert import (
    transfer_function_from_vtk,
    transfer_function_to_vtk,
    volume_from_image_data,
)

#: Name of the accessor on ``pyvista.ImageData``.
ACCESSOR = "illum"

__all__ = [
    "IllumAccessor",
    "add_computed_volume",
    "add_illuminated_volume",
    "ambient_extinction",
    "convection_diffusion",
    "lights_from_pyvista",
    "optical_properties",
    "render",
    "transfer_function_from_pyvista",
    "transmittance",
]


# === conversions ===================================================================================
def pyvista_unit_distance(grid) -> float:
    """``Plotter.add_volume``'s default opacity unit distance for ``grid``."""
    return float(grid.length / (np.mean(grid.dimensions) - 1))


def transfer_function_from_pyvista(grid, scalars=None, cmap=None, opacity="linear", clim=None,
                                   n_colors: int = 256, flip_scalars: bool = False, *,
                                   component=None, nan_policy: str = "raise"):
    """Colour and opacity of ``add_volume``'s conventions as VTK transfer functions.

    Parameters
    ----------
    grid : pyvista.ImageData
        Gives the default ``clim``: the range of the rendered values (``scalars``, its
        ``component``, cell data converted to points as ``add_volume`` does).
    scalars : str, optional
        Point or cell array; default the active scalars.
    cmap, opacity, clim, n_colors, flip_scalars
        As in ``pyvista.Plotter.add_volume``; ``cmap=None`` takes the theme's colormap.
        ``clim`` is ``(low, high)`` with ``low < high``, or one positive number ``c`` for
        ``(-c, c)``; ``n_colors`` an integer >= 1.
    component, nan_policy
        As in :func:`transmittance` (used for the default ``clim`` only).

    Returns
    -------
    (vtkColorTransferFunction, vtkPiecewiseFunction)

    Examples
    --------
    >>> import pyvista as pv
    >>> grid = pv.ImageData(dimensions=(4, 4, 4))
    >>> grid["v"] = range(64)
    >>> ctf, otf = transfer_function_from_pyvista(grid, cmap="viridis", opacity="linear")
    >>> round(otf.GetValue(0.0), 3), round(otf.GetValue(63.0), 3)
    (0.0, 0.998)
    """
    if isinstance(cmap, pv.LookupTable):
        lut = cmap
    else:
        from pyvista.plotting.colors import get_cmap_safe

        opacity = _check_opacity(opacity)
        n_colors = _check_n_colors(n_colors)
        clim = _data_range(_rendered_volume(grid, scalars, component, nan_policy)) \
            if clim is None else _check_clim(clim)
        lut = pv.LookupTable()
        cmap_obj = get_cmap_safe(cmap if cmap is not None else pv.global_theme.cmap)
        if flip_scalars:
            cmap_obj = cmap_obj.reversed()
        lut.apply_cmap(cmap_obj, n_colors)
        lut.apply_opacity(opacity)
        lut.scalar_range = clim
    return lut.to_color_tf(), lut.to_opacity_tf()


def lights_from_pyvista(lights) -> list:
    """Core lights from core lights, ``pyvista.Light`` objects (or one of either), or None.

    Examples
    --------
    >>> import pyvista as pv
    >>> light = pv.Light(position=(0, 0, 5), focal_point=(0, 0, 0), intensity=2.0)
    >>> lights_from_pyvista(light)[0].direction.tolist()
    [0.0, 0.0, -1.0]
    """
    if lights is None:
        return [DirectionalLight((1.0, -1.0, -1.0))]
    if isinstance(lights, (DirectionalLight, PointLight, pv.Light)):
        lights = [lights]
    out = []
    for light in lights:
        if isinstance(light, (DirectionalLight, PointLight)):
            out.append(light)
        elif isinstance(light, pv.Light):
            rgb = np.asarray(light.diffuse_color.float_rgb) * float(light.intensity)
            if light.positional:
                out.append(PointLight(light.position, rgb))
            else:
                travel = np.subtract(light.focal_point, light.position)
                out.append(DirectionalLight(travel, rgb))
        else:
            raise TypeError(f"lights must be vtkillum DirectionalLight/PointLight or pyvista.Light "
                            f"objects, got {type(light).__name__}")
    if not out:
        raise ValueError("lights: give at least one light (or None for the default light)")
    return out


def _illumination_lights(image, lights, core_lights) -> list:
    """The lights an illumination image was computed with, or ``core_lights`` without them.

    Raises ``ValueError`` when ``lights`` were given and differ from the image's.
    """
    from vtkillum.io.illumination_arrays import lights_from_field

    stored = lights_from_field(image)
    if not stored:
        return core_lights
    if lights is not None and not _same_lights(core_lights, stored):
        raise ValueError(
            "the illumination was computed with other lights than lights=...; leave lights "
            "out (the illumination's are used) or recompute the illumination with them"
        )
    return stored


def _same_lights(a, b) -> bool:
    def row(light):
        d = light.to_dict()
        return [d["type"] == "point", *d.get("direction", d.get("position")),
                *d.get("irradiance", d.get("intensity"))]

    return len(a) == len(b) and all(np.allclose(row(x), row(y), rtol=1e-6, atol=1e-9)
                                    for x, y in zip(a, b))


#: Filter properties and the accessor arguments that set them (error messages name the latter).
_ARGUMENT_NAMES = {
    "ScalarOpacityUnitDistance": "opacity_unit_distance", "InputComponent": "component",
    "NaNPolicy": "nan_policy", "Albedo": "albedo", "Anisotropy": "anisotropy",
    "Device": "device", "Exposure": "exposure", "StepSize": "step_size",
    "Scattering": "scattering", "Iterations": "iterations", "Tolerance": "tolerance",
    "Solver": "solver", "Photons": "photons", "Radius": "radius", "MaxOrder": "max_order",
    "Seed": "seed", "Passes": "passes", "Historygrams": "historygrams",
    "DirectLight": "direct_light", "RadiusUnits": "radius_units",
    "ComputeRadiance": "compute_radiance", "LightVolumeScale": "light_volume_scale",
    "array_name": "scalars",
}


def _in_accessor_words(err: Exception, names: dict | None = None) -> Exception:
    """``err`` with the filters' property names replaced by the accessor's argument names."""
    if not isinstance(err, (TypeError, ValueError)):
        return err
    message = str(err)
    for prop, arg in {**_ARGUMENT_NAMES, **(names or {})}.items():
        message = re.sub(rf"\b{prop}\b", arg, message)
    if message == str(err):
        return err
    new = type(err)(message)
    new.__cause__ = err
    return new


def _check_grid(grid) -> None:
    if not isinstance(grid, vtkImageData):
        raise TypeError(f"expected a pyvista.ImageData (uniform grid), got {type(grid).__name__}; "
                        "resample other meshes first, e.g. pv.ImageData(...).sample(mesh)")
    dims = tuple(int(n) for n in grid.GetDimensions())
    if min(dims) < 2:
        raise ValueError(
            f"the grid has dimensions {dims}: volume rendering needs at least 2 points along "
            "every axis (a single point or a 2D image has no thickness); pad or resample the "
            "grid")
    spacing = tuple(float(h) for h in grid.GetSpacing())
    if not all(np.isfinite(h) and h > 0 for h in spacing):
        raise ValueError(f"the grid's spacing {spacing} must be positive and finite along every "
                         "axis; set grid.spacing (flip a mirrored axis with grid.flip_x() etc.)")


def _check_component(component):
    """``component`` for the core (None, index, ``"magnitude"``) and for the filters (-1)."""
    if component is None or (isinstance(component, str) and component == "magnitude"):
        return component, (None if component is None else -1)
    if (isinstance(component, (int, np.integer)) and not isinstance(component, bool)
            and component >= -1):
        component = int(component)
        return ("magnitude" if component == -1 else component), component
    raise ValueError(f"component must be an index >= 0, -1 or 'magnitude' (the magnitude of "
                     f"each tuple), or None for a one-component array; got {_short(component)}")


def _check_nan_policy(nan_policy) -> str:
    if not (isinstance(nan_policy, str) and nan_policy in ("raise", "fill")):
        raise ValueError(f"nan_policy must be 'raise' or 'fill' (replace NaN/Inf by the smallest "
                         f"finite value), got {_short(nan_policy)}")
    return nan_policy


def _association(grid, scalars):
    """``"points"``/``"cells"`` where ``scalars`` lives (points first, as add_volume), or None."""
    if scalars is None:
        return None
    if not isinstance(scalars, str):
        raise TypeError(f"scalars must be the name of a point or cell array of the grid, got "
                        f"{type(scalars).__name__}")
    if scalars in grid.point_data:
        return "points"
    if scalars in grid.cell_data:
        return "cells"
    raise ValueError(f"the grid has no point or cell array {_short(scalars)} (point arrays: "
                     f"{list(grid.point_data.keys())}; cell arrays: {list(grid.cell_data.keys())})")


def _rendered_volume(grid, scalars, component, nan_policy):
    """The values the filters and renderers will use, as a core Volume (validates the choice).

    The same conversion as the filters': the named point array, else that cell array
    averaged onto the points; ``component`` of a multi-component array; NaN/Inf by
    ``nan_policy``.
    """
    _check_grid(grid)
    association = _association(grid, scalars)
    core_component, _ = _check_component(component)
    _check_nan_policy(nan_policy)
    if scalars is None and grid.GetPointData().GetScalars() is None \
            and grid.GetPointData().GetNumberOfArrays() == 0 \
            and grid.GetCellData().GetNumberOfArrays() == 0:
        raise ValueError("the grid has no arrays to render; add one (grid['values'] = ...) or "
                         "pass scalars=<name>")
    try:
        return volume_from_image_data(grid, scalars, core_component, nan_policy, association)
    except (TypeError, ValueError) as err:
        raise _in_accessor_words(err) from None


def _data_range(volume) -> tuple:
    """Default ``clim``: the rendered values' range (constant data: ``(v, v + 1)``)."""
    lo, hi = (float(v) for v in volume.value_range)
    return (lo, hi) if hi > lo else (lo, lo + 1.0)


def _check_clim(clim) -> tuple:
    if isinstance(clim, (int, float, np.integer, np.floating)) and not isinstance(clim, bool):
        if not (np.isfinite(clim) and clim > 0):
            raise ValueError(f"clim={clim!r}: one number c means (-c, c) and must be positive and "
                             "finite; or give (low, high)")
        return (-float(clim), float(clim))
    try:
        low, high = (float(v) for v in clim)
    except (TypeError, ValueError):
        raise ValueError(f"clim must be (low, high) or one positive number, got "
                         f"{_short(clim)}") from None
    if not (np.isfinite(low) and np.isfinite(high)):
        raise ValueError(f"clim={tuple(clim)!r} must be finite")
    if not low < high:
        raise ValueError(f"clim={tuple(clim)!r}: give (low, high) with low < high (limits are not "
                         "sorted or widened: pyvista's add_volume does not either, VTK reports a "
                         "bad table range); flip_scalars=True reverses the colormap")
    return (low, high)


def _check_n_colors(n_colors) -> int:
    if isinstance(n_colors, bool) or not isinstance(n_colors, (int, np.integer)) or n_colors < 1:
        raise ValueError(f"n_colors must be an integer >= 1 (the number of colours and opacities "
                         f"spread over clim), got {_short(n_colors)}")
    return int(n_colors)


def _check_unit_distance(u):
    if u is None:
        return None
    if isinstance(u, bool) or not isinstance(u, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(u) and u > 0):
        raise ValueError(f"opacity_unit_distance must be a positive number of world units (or "
                         f"None for pyvista's default), got {_short(u)}")
    return float(u)


#: The arguments every accessor function takes and :func:`_parse_inputs` reads: the
#: rendered array and its transfer function.
COMMON_ARGUMENTS = ("scalars", "component", "nan_policy", "cmap", "opacity", "clim",
                    "n_colors", "flip_scalars", "transfer_function", "opacity_unit_distance")


@dataclass(frozen=True)
class _Inputs:
    """What the common arguments mean for one call (see :func:`_parse_inputs`)."""

    scalars: str | None        #: the array name as given
    component: object          #: the component as given (None, an index, -1, "magnitude")
    filter_component: int | None  #: the filters' InputComponent (-1: magnitude)
    nan_policy: str            #: "raise" or "fill"
    volume: object             #: the rendered values as a core Volume
    ctf: object                #: vtkColorTransferFunction
    otf: object                #: vtkPiecewiseFunction
    unit_distance: float       #: opacity unit distance in world units


def _parse_inputs(grid, arguments: dict) -> _Inputs:
    """The one parser of the arguments every accessor function shares.

    Each function hands over its own arguments (``locals()`` at its start), so all read
    ``scalars``, ``component``, ``nan_policy`` and the transfer function the same way
    and none can leave one out (a missing name is a ``TypeError`` here, caught by the
    tests). The volume is converted once and the transfer functions built from either
    convention: ``transfer_function=`` or ``cmap``/``opacity``/``clim``.
    """
    missing = [name for name in COMMON_ARGUMENTS if name not in arguments]
    if missing:
        raise TypeError(f"accessor function without the common argument(s) {missing}")
    a = {name: arguments[name] for name in COMMON_ARGUMENTS}
    volume = _rendered_volume(grid, a["scalars"], a["component"], a["nan_policy"])
    u = _check_unit_distance(a["opacity_unit_distance"])
    transfer_function, cmap, opacity, clim = (a["transfer_function"], a["cmap"], a["opacity"],
                                              a["clim"])
    if transfer_function is not None:
        if cmap is not None or clim is not None or not (isinstance(opacity, str)
                                                        and opacity == "linear"):
            raise ValueError("give either transfer_function=... or cmap/opacity/clim, not both")
        if not isinstance(transfer_function, TransferFunction):
            raise TypeError("transfer_function must be a vtkillum.TransferFunction")
        ctf, otf = transfer_function_to_vtk(transfer_function)
    else:
        n_colors = a["n_colors"]
        if not isinstance(cmap, pv.LookupTable):
            n_colors = _check_n_colors(n_colors)
            clim = _data_range(volume) if clim is None else _check_clim(clim)
        ctf, otf = transfer_function_from_pyvista(grid, a["scalars"], cmap, opacity, clim,
                                                  n_colors, a["flip_scalars"])
    return _Inputs(scalars=a["scalars"], component=a["component"],
                   filter_component=_check_component(a["component"])[1],
                   nan_policy=a["nan_policy"], volume=volume, ctf=ctf, otf=otf,
                   unit_distance=u if u is not None else pyvista_unit_distance(grid))


def _check_unmasked(value, name: str):
    """``value``, refused when it is a numpy masked array with masked values: the arrays it
    goes into have no mask, and whatever lies under the mask would be used as data."""
    if np.ma.isMaskedArray(value) and np.ma.count_masked(value):
        raise ValueError(f"{name}: a masked array with {np.ma.count_masked(value)} masked "
                         "value(s); give a value everywhere (array.filled(value))")
    return value


def _check_opacity(opacity):
    """``opacity`` as ``add_volume`` takes it, refusing NaN, infinity and masked values
    (pyvista would turn them into a fully transparent table without a word)."""
    if isinstance(opacity, str):
        return opacity
    _check_unmasked(opacity, "opacity")
    shown = repr(opacity) if len(repr(opacity)) <= 80 else repr(opacity)[:60] + "..."
    try:
        values = np.asarray(opacity, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"opacity must be a name such as 'linear' or 'sigmoid', a number or a "
                         f"sequence of numbers, got {shown}") from None
    bad = ~np.isfinite(values.reshape(-1))
    if bad.any():
        raise ValueError(f"opacity={shown}: {values.reshape(-1)[bad][0]} at index "
                         f"{int(np.argmax(bad))}; opacities must be finite numbers")
    return opacity


def _run(filter_class, grid, inputs: _Inputs, settings: dict, lights=None, rgba=False,
         exposure=DEFAULT_EXPOSURE, with_filter=False):
    """Configure a filter, run it on ``grid`` and return its output as new pyvista.ImageData.

    ``inputs`` (:func:`_parse_inputs`) gives the array, its component, the NaN policy and
    the transfer functions; ``settings`` maps filter properties to ``(accessor argument,
    value)``; errors of the filter name the accessor's arguments. ``with_filter``: return
    ``(output, filter)`` (for filters with more output ports).
    """
    cls = with_rgba_output(filter_class) if rgba else filter_class
    algorithm = cls()
    names = {prop: arg for prop, (arg, _) in settings.items()}
    try:
        algorithm.SetColorTransferFunction(inputs.ctf)
        algorithm.SetScalarOpacity(inputs.otf)
        algorithm.SetScalarOpacityUnitDistance(inputs.unit_distance)
        if lights is not None:
            algorithm.SetLights(lights_from_pyvista(lights))
        if rgba:
            algorithm.SetExposure(exposure)
        if inputs.scalars is not None:
            field = (vtkDataObject.FIELD_ASSOCIATION_CELLS
                     if _association(grid, inputs.scalars) == "cells"
                     else vtkDataObject.FIELD_ASSOCIATION_POINTS)
            algorithm.SetInputArrayToProcess(0, 0, 0, field, inputs.scalars)
        algorithm.SetInputComponent(inputs.filter_component)
        algorithm.SetNaNPolicy(inputs.nan_policy)
        for key, (_, value) in settings.items():
            if value is None:
                continue
            setter = getattr(algorithm, f"Set{key}")
            setter(*value) if isinstance(value, tuple) else setter(value)
        output = algorithm.execute(grid)
    except (TypeError, ValueError) as err:
        raise _in_accessor_words(err, names) from None
    result = pv.ImageData()
    result.shallow_copy(output)
    return (result, algorithm) if with_filter else result


# === the filters as functions ======================================================================
def optical_properties(grid, scalars=None, *, cmap=None, opacity="linear", clim=None,
                       n_colors=256, flip_scalars=False, transfer_function=None,
                       opacity_unit_distance=None, albedo=0.9, output_scale=1.0,
                       component=None, nan_policy="raise"):
    """Extinction and scattering coefficients per point (:class:`OpticalPropertiesFilter`).

    Returns
    -------
    pyvista.ImageData
        ``sigma_t`` (active), ``scattering_color``, ``sigma_s``, ``sigma_a`` and the
        input arrays.

    Examples
    --------
    >>> import pyvista as pv, vtkillum, vtkillum.pyvista_accessor
    >>> grid = pv.ImageData(dimensions=(8, 8, 8))
    >>> grid["density"] = [1.0] * grid.n_points
    >>> tf = vtkillum.TransferFunction([0.0, 1.0], [0.5, 0.5])
    >>> out = grid.illum.optical_properties(transfer_function=tf, opacity_unit_distance=1.0)
    >>> round(float(out["sigma_t"].max()), 4)       # -ln(1 - 0.5) / 1
    0.6931

    pyvista's opacity tables hold 8-bit values: ``opacity=0.5`` is 127/255.

    >>> out = grid.illum.optical_properties(opacity=0.5, opacity_unit_distance=1.0)
    >>> round(float(out["sigma_t"].max()), 4)       # -ln(1 - 127/255)
    0.6892
    """
    inputs = _parse_inputs(grid, locals())
    return _run(OpticalPropertiesFilter, grid, inputs,
                {"Albedo": ("albedo", albedo), "OutputScale": ("output_scale", output_scale)},
               )


def transmittance(grid, lights=None, scalars=None, *, cmap=None, opacity="linear", clim=None,
                  n_colors=256, flip_scalars=False, transfer_function=None,
                  opacity_unit_distance=None, albedo=0.9, light_volume_scale=1.0,
                  step_size=None, device=None, rgba=False, exposure=DEFAULT_EXPOSURE,
                  component=None, nan_policy="raise"):
    """Shadow rays towards every light (:class:`LightTransmittanceFilter`).

    Parameters
    ----------
    lights : light or list of lights, optional
        See the module docstring.
    scalars : str, optional
        Point or cell array to render (cell data are averaged onto the points, as
        ``add_volume`` does); default the active scalars.
    light_volume_scale : float
        Resolution of the light grid relative to the data, in (0, 1].
    step_size : float, optional
        Longest step along shadow rays (world units); default half the smallest spacing.
    device : str, optional
        ``"cpu"``, ``"cuda"``; default CUDA when present.
    rgba : bool
        Also output ``illuminated_rgba`` (:mod:`vtkillum.filters.rgba_output`) with ``exposure``.
    component : int or str, optional
        Component of a multi-component array: an index, or -1 / ``"magnitude"`` for the
        magnitude of each tuple (the filters' ``InputComponent``). Required for
        multi-component arrays.
    nan_policy : {"raise", "fill"}
        NaN/Inf values raise ``ValueError`` (default) or are replaced by the smallest
        finite value (the filters' ``NaNPolicy``).

    Returns
    -------
    pyvista.ImageData
        ``fluence`` (RGB, active), ``transmittance`` (one component per light),
        ``scattered_fluence`` (zeros), and at full resolution the input arrays
        (:mod:`vtkillum.io.illumination_arrays`).

    Examples
    --------
    A slab of extinction 1 per unit lit from +z: the transmittance at the bottom is
    ``exp(-height)``.

    >>> import numpy as np, pyvista as pv, vtkillum, vtkillum.pyvista_accessor
    >>> grid = pv.ImageData(dimensions=(6, 6, 11), spacing=(0.1, 0.1, 0.1))
    >>> grid["density"] = np.ones(grid.n_points)
    >>> tf = vtkillum.TransferFunction([0.0, 1.0], [1 - np.exp(-1.0)] * 2)
    >>> out = grid.illum.transmittance(vtkillum.DirectionalLight((0, 0, -1)),
    ...                                transfer_function=tf, opacity_unit_distance=1.0,
    ...                                device="cpu")
    >>> t = out["transmittance"].reshape(11, 6, 6)         # [k, j, i], one light
    >>> round(float(t[0, 3, 3]), 3), round(float(np.exp(-1.0)), 3)
    (0.368, 0.368)
    """
    inputs = _parse_inputs(grid, locals())
    return _run(LightTransmittanceFilter, grid, inputs,
                {"Albedo": ("albedo", albedo),
                 "OutputScale": ("light_volume_scale", light_volume_scale),
                 "StepSize": ("step_size", step_size), "Device": ("device", device)},
                lights=lights, rgba=rgba, exposure=exposure)


def convection_diffusion(grid, lights=None, scalars=None, *, cmap=None, opacity="linear",
                         clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
                         opacity_unit_distance=None, albedo=0.9, scattering=(0.0, 0.0, 0.0),
                         light_volume_scale=0.5, iterations=0, tolerance=3e-4,
                         solver="multigrid", device=None, rgba=False,
                         exposure=DEFAULT_EXPOSURE, diffusion_model="physical", anisotropy=0.0,
                         component=None, nan_policy="raise"):
    """Zhang & Ma's convection–diffusion light volume (:class:`ConvectionDiffusionLightFilter`).

    ``diffusion_model`` is ``"physical"`` (default: radiative-transfer diffusion from
    ``albedo``, ``anisotropy`` and the transfer functions) or ``"paper"`` (Zhang & Ma's
    diffusion with ``scattering``, the coefficient per RGB channel in world units², one
    number for all channels); other parameters as in :func:`transmittance`.

    Returns
    -------
    pyvista.ImageData
        ``fluence`` (active), ``transmittance`` (physical model), ``scattered_fluence`` on
        the light grid (or, with ``rgba=True``, on the data grid with ``illuminated_rgba``),
        and its lights as field data. :func:`add_illuminated_volume` and :func:`render` read
        it with :func:`vtkillum.io.illumination_arrays.illumination_from_image`.
    """
    if np.ndim(scattering) == 0:
        scattering = (float(scattering),) * 3
    inputs = _parse_inputs(grid, locals())
    return _run(ConvectionDiffusionLightFilter, grid, inputs,
                {"Albedo": ("albedo", albedo), "Anisotropy": ("anisotropy", anisotropy),
                 "DiffusionModel": ("diffusion_model", diffusion_model),
                 "LightVolumeScale": ("light_volume_scale", light_volume_scale),
                 "Scattering": ("scattering", tuple(float(s) for s in scattering)),
                 "Iterations": ("iterations", iterations), "Tolerance": ("tolerance", tolerance),
                 "Solver": ("solver", solver), "Device": ("device", device)},
                lights=lights, rgba=rgba, exposure=exposure)


def photon_density(grid, lights=None, scalars=None, *, cmap=None, opacity="linear",
                   clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
                   opacity_unit_distance=None, albedo=0.9, anisotropy=0.0, photons=0,
                   radius=0.0, max_order=0, seed=0, passes=1, historygrams=True,
                   direct_light="exact", output_scale=1.0, device=None, rgba=False,
                   exposure=DEFAULT_EXPOSURE, component=None, nan_policy="raise"):
    """Jönsson et al.'s photon density light volume (:class:`PhotonDensityFilter`).

    ``photons`` per pass and ``radius`` in voxels (0, the defaults: chosen from the data, as
    the filter's ``Photons`` and ``Radius``), ``max_order`` the maximum scattering
    order S_n (0: unbounded, Russian roulette), ``passes`` of progressive photon mapping,
    ``direct_light`` ``"exact"`` (per-light transmittance, photons only for scattered
    light) or ``"photons"`` (the paper's all-photon estimate); other parameters as in
    :func:`transmittance`.

    Returns
    -------
    pyvista.ImageData
        ``fluence`` (active), ``transmittance`` (one component per light) and
        ``scattered_fluence`` on the light grid, its lights as field data (see
        :func:`convection_diffusion`).
    """
    inputs = _parse_inputs(grid, locals())
    return _run(PhotonDensityFilter, grid, inputs,
                {"Albedo": ("albedo", albedo), "Anisotropy": ("anisotropy", anisotropy),
                 "Photons": ("photons", photons), "Radius": ("radius", radius),
                 "MaxOrder": ("max_order", max_order), "Seed": ("seed", seed),
                 "Passes": ("passes", passes), "Historygrams": ("historygrams", historygrams),
                 "DirectLight": ("direct_light", direct_light),
                 "OutputScale": ("output_scale", output_scale), "Device": ("device", device)},
                lights=lights, rgba=rgba, exposure=exposure)


def many_lights(grid, lights=None, scalars=None, *, cmap=None, opacity="linear", clim=None,
                n_colors=256, flip_scalars=False, transfer_function=None,
                opacity_unit_distance=None, albedo=0.9, anisotropy=0.0, count=1024,
                vsl_radius=0.0, transmittance="avsm", avsm_resolution=16, avsm_nodes=8,
                seed=0, output_scale=1.0, device=None, rgba=False, exposure=DEFAULT_EXPOSURE,
                component=None, nan_policy="raise", return_virtual_lights=False):
    """Weber et al.'s many-light illumination volume (:class:`ManyLightsFilter`).

    ``count`` virtual lights from random walks, clamped within ``vsl_radius`` voxels (0,
    the default: from the data, as the filter's ``VSLRadius``),
    their transmittance from adaptive volumetric shadow maps (``transmittance="avsm"``,
    ``avsm_resolution``² texels per cube face, ``avsm_nodes`` nodes per texel) or ray
    marched (``"ray-marched"``); other parameters as in :func:`transmittance`.

    Returns
    -------
    pyvista.ImageData or (pyvista.ImageData, pyvista.PolyData)
        ``fluence`` (active), ``transmittance`` (one component per light) and
        ``scattered_fluence`` (the virtual lights' light) on the light grid; with
        ``return_virtual_lights=True`` also the virtual lights as points (``position``,
        ``radiance``, ``radius``, ... arrays) to show with ``plotter.add_points``.
    """
    inputs = _parse_inputs(grid, locals())
    out, algorithm = _run(
        ManyLightsFilter, grid, inputs,
        {"Albedo": ("albedo", albedo), "Anisotropy": ("anisotropy", anisotropy),
         "Count": ("count", count), "VSLRadius": ("vsl_radius", vsl_radius),
         "Transmittance": ("transmittance", transmittance),
         "AVSMResolution": ("avsm_resolution", avsm_resolution),
         "AVSMNodes": ("avsm_nodes", avsm_nodes), "Seed": ("seed", seed),
         "OutputScale": ("output_scale", output_scale), "Device": ("device", device)},
        lights=lights, rgba=rgba, exposure=exposure, with_filter=True)
    if not return_virtual_lights:
        return out
    return out, pv.wrap(algorithm.GetVirtualLightsOutput())


def ambient_extinction(grid, lights=None, scalars=None, *, cmap=None, opacity="linear",
                       clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
                       opacity_unit_distance=None, albedo=0.9, anisotropy=0.0, radius=4.0,
                       radius_units="voxels", compute_radiance=True, output_scale=1.0,
                       device=None, component=None, nan_policy="raise"):
    """Ament et al.'s ambient extinction and radiance cache (:class:`AmbientExtinctionFilter`).

    Returns
    -------
    pyvista.ImageData
        ``ambient_extinction`` (active), ``ambient_radiance`` and
        ``ambient_radiance_<l>`` per light, its lights and ``radius`` as field data:
        :func:`add_illuminated_volume` shows it (ambient volume scattering).
    """
    inputs = _parse_inputs(grid, locals())
    out = _run(AmbientExtinctionFilter, grid, inputs,
               {"Albedo": ("albedo", albedo), "Anisotropy": ("anisotropy", anisotropy),
                "Radius": ("radius", radius), "RadiusUnits": ("radius_units", radius_units),
                "ComputeRadiance": ("compute_radiance", compute_radiance),
                "OutputScale": ("output_scale", output_scale), "Device": ("device", device)},
               lights=lights)
    # The filter keeps no lights with its output (sigma~t alone needs none): record them and
    # the radius, for add_illuminated_volume to show the output as it was computed.
    _add_ambient_field(out, radius, radius_units)
    if compute_radiance:
        from vtkillum.io.illumination_arrays import add_lights_field

        add_lights_field(out, lights_from_pyvista(lights))
    return out


def render(grid, method="single", scalars=None, *, lights=None, cmap=None, opacity="linear",
           clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
           opacity_unit_distance=None, albedo=0.9, anisotropy=0.0, camera=None, width=None,
           height=None, background=(0.0, 0.0, 0.0), device=None, filename=None,
           exposure="auto", gamma=2.2, frame=None, component=None, nan_policy="raise",
           **options):
    """Render ``grid`` with a registered method of :data:`vtkillum.METHODS`.

    The defaults are the command line's (:mod:`vtkillum.core.defaults`): the same data,
    transfer function and method give the same picture as ``vtkillum render``.

    Parameters
    ----------
    method : str
        ``"emission"``, ``"single"``, ``"illumination"`` (give ``illumination=`` an
        output of :func:`transmittance` / :func:`convection_diffusion`, or an
        ``IlluminationVolume``), ``"path"``, ...
    lights : optional
        See the module docstring. Default: one white key light from the upper
        front-left of the camera (:func:`vtkillum.core.defaults.key_light`). With
        ``illumination=`` a filter output, default: the lights it was computed with
        (stored with it); other lights are an error.
    anisotropy : float
        Henyey–Greenstein ``g`` of the phase function (also applied to the direct light
        of an illumination volume).
    camera : vtkillum.Camera or pyvista.Camera, optional
        Default: the data-aware view of :func:`vtkillum.core.defaults.default_camera`,
        framing the voxels above the histogram's air threshold (seen from the front
        with ``frame`` given, else VTK's default view turned with the grid's
        direction). A camera inside the data's box warns (``UserWarning``).
    width, height : int, optional
        Image size; default 256 x 256 on a CPU, 512 x 512 with CUDA
        (:func:`vtkillum.core.defaults.default_image_size`); one given: a square.
    filename : str, optional
        Also write the picture as PNG (all-or-nothing:
        :func:`vtkillum.io.writers.write_atomically`): the radiance composited over
        ``background``, times ``exposure``, gamma-encoded
        (:func:`vtkillum.core.defaults.picture`).
    exposure : "auto" or float
        ``"auto"``: the 99.5th percentile of the pixels the volume covers becomes white
        (as ``vtkillum render``); a positive factor fixes the scaling.
    frame : {None, "LPS", "RAS"}
        Anatomical frame of the grid's world coordinates for the default camera
        (``"LPS"``: what :func:`vtkillum.io.readers.read_volume` gives for NIfTI,
        DICOM and MetaImage files): a medical image is then seen from the front,
        superior up.
    **options
        Method options (``spp`` for ``path``, ``illumination`` for ``illumination``...).

    Returns
    -------
    vtkillum.RenderResult
        Linear ``radiance`` (H, W, 3), ``alpha`` (H, W) and ``info``.

    Examples
    --------
    >>> import numpy as np, pyvista as pv, vtkillum.pyvista_accessor
    >>> grid = pv.ImageData(dimensions=(9, 9, 9), spacing=(0.25, 0.25, 0.25))
    >>> grid["density"] = np.ones(grid.n_points)
    >>> result = grid.illum.render("emission", opacity=0.5, width=24, height=24, device="cpu")
    >>> result.radiance.shape, bool(result.alpha.max() > 0.5)
    ((24, 24, 3), True)
    """
    import warnings

    from vtkillum.core.defaults import camera_inside_warning, picture
    from vtkillum.core.device import resolve_device

    inputs = _parse_inputs(grid, locals())
    volume = inputs.volume
    core_lights, illumination = _lights_and_illumination(volume, lights,
                                                         options.get("illumination"))
    if "illumination" in options:
        options["illumination"] = illumination
    if isinstance(exposure, str) and exposure.lower() != "auto":
        raise ValueError(f"exposure must be a positive number or 'auto', got {_short(exposure)}")
    device = resolve_device(device)
    width, height = _image_size(width, height, device)
    if camera is not None and isinstance(camera, pv.Camera):
        from vtkillum.mappers.camera_bridge import camera_from_vtk

        camera = camera_from_vtk(camera, aspect=width / height)
    scene = _scene(inputs, core_lights, camera, albedo=albedo, anisotropy=anisotropy,
                   background=background, frame=frame, aspect=width / height)
    warning = camera_inside_warning(scene.resolved_camera(volume), volume)
    if warning:
        warnings.warn(warning, UserWarning, stacklevel=3)
    result = core_render(volume, scene, method, width, height, device=device, **options)
    if filename is not None:
        from vtkillum.io.writers import write_atomically

        rgb8 = picture(result.radiance, result.alpha, background, exposure, gamma=gamma)
        # Under its final name, old picture kept and nothing hidden left on any failure.
        write_atomically([(filename, lambda f: write_png(f, rgb8))])
    return result


def _lights_and_illumination(volume, lights, illumination):
    """``(core lights or None, illumination)`` of :func:`render` and :func:`add_computed_volume`.

    ``lights`` as given (None: the caller's default light); an ``illumination`` image (a
    light filter's output) is checked to cover ``volume`` and read as an
    ``IlluminationVolume``, and the lights it was computed with replace ``lights``
    (other ``lights`` given are an error, :func:`_illumination_lights`). Other
    ``illumination`` values (None, an ``IlluminationVolume``, an array) pass unchanged.
    """
    core_lights = lights_from_pyvista(lights) if lights is not None else None
    illumination = _check_unmasked(illumination, "illumination")
    if isinstance(illumination, vtkImageData):
        from vtkillum.io.illumination_arrays import illumination_from_image
        from vtkillum.mappers.inputs import check_covers

        check_covers(illumination, volume)
        core_lights = _illumination_lights(illumination, lights, core_lights)
        illumination = illumination_from_image(illumination, volume)
    return core_lights, illumination


def _scene(inputs: _Inputs, core_lights, camera, *, albedo, anisotropy,
           background=(0.0, 0.0, 0.0), frame=None, aspect=1.0) -> Scene:
    """The :class:`Scene` of :func:`render` and :func:`add_computed_volume`.

    The transfer function of ``inputs`` (:func:`_parse_inputs`); the command line's
    defaults (:func:`vtkillum.core.defaults.default_scene`, one function for both: the
    same data and transfer function look the same from Python and from the shell) where
    ``camera`` or ``core_lights`` is None: the data-aware camera, and the key light from
    the upper front-left of the (given or default) camera.
    """
    from vtkillum.core.defaults import default_scene

    scene = Scene(transfer_function=transfer_function_from_vtk(inputs.ctf, inputs.otf),
                  opacity_unit_distance=inputs.unit_distance, albedo=albedo,
                  anisotropy=anisotropy, lights=core_lights or lights_from_pyvista(None),
                  camera=camera, background=background)
    fill = {name for name, given in (("camera", camera), ("lights", core_lights))
            if given is None}
    return default_scene(inputs.volume, frame, base=scene, fill=fill, aspect=aspect)


def _image_size(width, height, device) -> tuple[int, int]:
    """``(width, height)``: as given, one given for both, or the default for ``device``."""
    from vtkillum.core.defaults import default_image_size

    if width is None and height is None:
        return default_image_size(device)
    width = height if width is None else width
    height = width if height is None else height
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {_short(value)}")
    return int(width), int(height)


# === plotting =========================================================================================
def add_illuminated_volume(plotter, grid, illumination=None, scalars=None, *, cmap=None,
                           opacity="linear", clim=None, n_colors=256, flip_scalars=False,
                           transfer_function=None, opacity_unit_distance=None, lights=None,
                           albedo=0.9, anisotropy=0.0, exposure=4 * np.pi, shading=None,
                           step_size=None, jitter=True, name=None, reset_camera=None,
                           render=True, component=None, nan_policy="raise"):
    """Add ``grid`` shaded by an illumination volume to a pyvista plotter.

    Builds an :class:`~vtkillum.mappers.IlluminatedVolume` (VTK's GPU ray caster
    with the phase-aware illumination-volume source term: the direct light per light
    with the Henyey–Greenstein phase function, the scattered light isotropic; see
    :mod:`vtkillum.core.illumination`) and adds it with ``plotter.add_actor``;
    ``cmap``, ``opacity``, ``clim`` follow ``Plotter.add_volume``. The output of
    :func:`ambient_extinction` is shown with ambient volume scattering instead
    (:class:`~vtkillum.mappers.AmbientScatteringVolume`: Ament et al.'s gather in the GPU
    ray caster, with the output's radius and lights).

    Parameters
    ----------
    plotter : pyvista.Plotter
    grid : pyvista.ImageData
        Point scalars (``scalars``, default the active ones).
    illumination : optional
        The illumination: the output of any of this module's light filters --
        :func:`transmittance`, :func:`convection_diffusion`, :func:`photon_density`,
        :func:`many_lights` (any pyvista/VTK image covering the grid's box with the arrays
        of :mod:`vtkillum.io.illumination_arrays`: per-light ``transmittance`` and
        ``scattered_fluence``, or only a ``fluence`` taken as isotropic scattered light)
        or :func:`ambient_extinction` (an image with an ``ambient_extinction`` array) --,
        a VTK algorithm or output port producing one (an ``AmbientExtinctionFilter``
        included), an ``IlluminationVolume`` or
        ``(nx, ny, nz, 3)`` scattered-fluence array, the name of one of those functions
        (``"transmittance"``, ``"convection_diffusion"``, ``"photon_density"``,
        ``"many_lights"``, ``"ambient_extinction"``: computed here with these lights,
        transfer function, albedo and anisotropy, the other settings their defaults), or
        ``None`` for unshadowed direct light. A named illumination follows edits: the
        returned volume's ``set_scene`` with another transfer function, unit distance,
        albedo, anisotropy or lights computes it again (``volume.relight``; the ambient
        mapper recomputes what an edit invalidates itself). An illumination given as
        data is what it is: after such an edit compute it again and pass it to
        ``volume.set_illumination``. Grids given as warp arrays are written straight into
        VTK's textures (the returned volume's ``device_upload``).
    lights : optional
        As in :func:`transmittance`; also the Phong directions. A filter output carries
        the lights it was computed with, and those are used (other ``lights`` are an
        error).
    albedo, anisotropy : float
        Scattering albedo; Henyey–Greenstein ``g`` applied to the direct light (ambient
        scattering: to the gather and its radiance cache, which the mapper recomputes
        with these values).
    exposure : float
        Factor on the radiance written to the frame buffer. The default 4π shows a fully
        lit voxel under irradiance 1 as albedo × colour when ``g = 0`` (the isotropic
        phase function spreads scattered light over 4π sr), as the ParaView plugin does;
        with ``g > 0`` the side facing away from the light (forward scattering) is
        brighter. Ambient scattering's radiance has the same units, so the same exposure
        shows it as bright.
    shading : dict, optional
        ``{"ambient", "diffuse", "specular", "shininess"}`` of the illumination
        shading (default ambient 1: pure scattering; ambient scattering uses
        ``shininess`` for its optional specular lobe).
    step_size : float, optional
        Sample distance of the ray caster; default half the smallest spacing.
    jitter : bool
        Per-pixel offset of the samples (noise instead of wood-grain rings at sharp
        surfaces); ``False`` samples step midpoints. Ambient scattering never jitters
        (it samples as its warp gather does).
    name, reset_camera, render
        As in ``Plotter.add_actor``.

    Returns
    -------
    vtkillum.mappers.IlluminatedVolume or vtkillum.mappers.AmbientScatteringVolume
        The actor (a ``vtkVolume`` / ``vtkMultiVolume``).

    Notes
    -----
    Ambient scattering computes its ambient extinction and radiance cache in the mapper
    (the OpenGL path needs them as its own textures, at most 4 lights): from the
    output of :func:`ambient_extinction` it takes the radius and the lights (recorded
    with the output; an :class:`~vtkillum.filters.AmbientExtinctionFilter` given itself,
    or its output port, gives its own; its output image alone records neither: the
    filter's default radius, 4 voxels, and ``lights`` are used), not the arrays.

    Examples
    --------
    >>> import numpy as np, pyvista as pv, vtkillum
    >>> from vtkillum.pyvista_accessor import add_illuminated_volume
    >>> grid = pv.ImageData(dimensions=(12, 12, 12), spacing=(0.2, 0.2, 0.2))
    >>> grid["density"] = np.linspace(0.0, 1.0, grid.n_points)
    >>> pl = pv.Plotter(off_screen=True, window_size=(64, 64))
    >>> actor = add_illuminated_volume(pl, grid, illumination="transmittance",
    ...                                cmap="bone", opacity="linear", exposure=8.0)
    >>> image = pl.screenshot()
    >>> image.shape, bool(image.max() > 0)
    ((64, 64, 3), True)
    >>> pl.close()
    """
    import inspect

    from vtkillum.core.scene import SHADING_DEFAULTS
    from vtkillum.mappers.illuminated_volume_mapper import IlluminatedVolume

    inputs = _parse_inputs(grid, locals())
    illumination = _check_unmasked(illumination, "illumination")
    core_lights = lights_from_pyvista(lights)
    tf = transfer_function_from_vtk(inputs.ctf, inputs.otf)
    relight = None
    if isinstance(illumination, str):
        methods = {"transmittance": transmittance, "convection_diffusion": convection_diffusion,
                   "photon_density": photon_density, "many_lights": many_lights,
                   "ambient_extinction": ambient_extinction}
        if illumination not in methods:
            raise ValueError(f"illumination={_short(illumination)}: name one of "
                             f"{sorted(methods)}, or pass a filter output")
        method = methods[illumination]
        anisotropic = "anisotropy" in inspect.signature(method).parameters
        relight = functools.partial(_relit, method, grid, scalars, component, nan_policy,
                                    anisotropic)
        illumination = relight(Scene(transfer_function=tf,
                                     opacity_unit_distance=inputs.unit_distance,
                                     albedo=albedo, anisotropy=anisotropy,
                                     lights=core_lights))
    ambient = _ambient_settings(illumination)  # None, or (radius options, stored lights)
    if ambient is not None and ambient[1]:
        if lights is not None and not _same_lights(core_lights, ambient[1]):
            raise ValueError(
                "the illumination was computed with other lights than lights=...; leave lights "
                "out (the illumination's are used) or recompute the illumination with them")
        core_lights = ambient[1]
    elif isinstance(illumination, vtkImageData):
        core_lights = _illumination_lights(illumination, lights, core_lights)
    scene = Scene(transfer_function=tf, opacity_unit_distance=inputs.unit_distance,
                  albedo=albedo, anisotropy=anisotropy, lights=core_lights,
                  step_size=step_size, shading=dict(SHADING_DEFAULTS, **(shading or {})))
    data, array_name = _mapper_input(grid, inputs)
    if ambient is not None:
        from vtkillum.mappers.ambient_volume_mapper import AmbientScatteringVolume

        volume = AmbientScatteringVolume(data, scene, array_name=array_name, exposure=exposure,
                                         **ambient[0])
    else:
        volume = IlluminatedVolume(data, scene, illumination=illumination,
                                   array_name=array_name, exposure=exposure, jitter=jitter)
        volume.relight = relight
    plotter.add_actor(volume, name=name, reset_camera=reset_camera, render=render)
    return volume


def _relit(method, grid, scalars, component, nan_policy, anisotropic: bool, scene):
    """A named illumination of ``grid`` computed with ``scene``'s transfer function, unit
    distance, albedo, anisotropy (where the method has one) and lights."""
    settings = dict(transfer_function=scene.transfer_function,
                    opacity_unit_distance=scene.opacity_unit_distance, albedo=scene.albedo,
                    component=component, nan_policy=nan_policy)
    if anisotropic:
        settings["anisotropy"] = scene.anisotropy
    return method(grid, list(scene.lights), scalars, **settings)


def add_computed_volume(plotter, grid, method="transmittance", scalars=None, *, lights=None,
                        cmap=None, opacity="linear", clim=None, n_colors=256, flip_scalars=False,
                        transfer_function=None, opacity_unit_distance=None, albedo=0.9,
                        anisotropy=0.0, device=None, exposure=1.0, gamma=1.0,
                        resolution_scale=1.0, component=None, nan_policy="raise", **options):
    """Show ``grid`` rendered by a warp method in a pyvista plotter: the compute path.

    Builds a :class:`~vtkillum.mappers.ComputeVolumeRenderer` on ``plotter.renderer``:
    ``method`` (any of :data:`vtkillum.METHODS`) renders the grid at the plotter's
    camera and window size, and the tone-mapped picture becomes the renderer's textured
    background. It re-renders whenever the camera (the user's mouse) or the window size
    has changed, in the same frame (the renderer's ``StartEvent``). With CUDA this is
    the fast interactive path (a 512³ CT-like volume orbits at 46-92 frames per second on
    an H200 in a 1024² window, depending on the method; ``docs/benchmarks.md``); on a CPU
    use a small grid or ``resolution_scale < 1``.

    The scene is built as :func:`render` builds it (same arguments, same transfer
    function, :func:`vtkillum.core.defaults.default_scene` for the lights), except the
    camera: the plotter's, which follows the mouse.

    Parameters
    ----------
    plotter : pyvista.Plotter
    grid : pyvista.ImageData
        The data (``scalars``, ``component``, ``nan_policy`` as in :func:`transmittance`).
    method : str
        ``"emission"``, ``"single"``, ``"transmittance"`` (default), ``"ambient-scattering"``,
        ``"convection-diffusion"``, ``"illumination"`` (give ``illumination=`` the output
        of a light filter such as ``grid.illum.transmittance(...)``, or an
        ``IlluminationVolume``), progressive ``"path"`` and ``"many-lights"``, ...
    lights : optional
        See the module docstring. Default: one white key light from the upper front-left
        of the plotter's camera at the time of this call (fixed in the world afterwards;
        :func:`vtkillum.core.defaults.key_light`). With ``illumination=`` a filter output,
        default: the lights it was computed with; other lights are an error.
    cmap, opacity, clim, n_colors, flip_scalars, transfer_function, opacity_unit_distance
        The transfer function, as in :func:`transmittance`.
    albedo, anisotropy : float
        Scattering albedo and Henyey–Greenstein ``g``, as in :func:`render`.
    device : str, optional
        Warp device (``"cpu"``, ``"cuda"``); default CUDA when present.
    exposure, gamma : float
        Display: ``tonemap(exposure * radiance, alpha, background, gamma=gamma)`` over the
        plotter's background colour (``gamma = 1``: linear, as VTK's ray caster writes).
    resolution_scale : float
        Render at this fraction of the window size, in (0, 1] (interpolated up).
    **options
        Method options (``illumination`` for ``"illumination"``; ``step_size``,
        ``jitter``; ``spp``, ``max_bounces``, ``seed`` for ``"path"`` ...).

    Returns
    -------
    vtkillum.mappers.ComputeVolumeRenderer
        Its ``display_image()`` is the 8-bit picture shown, ``result`` the last
        :class:`vtkillum.RenderResult`; ``set_method``, ``set_scene`` change what it
        shows; ``detach()`` removes it from the plotter (the plotter's own background
        comes back); the progressive methods ``"path"`` and
        ``"many-lights"`` start with one pass per camera change and refine while the
        camera rests after ``start_refinement()`` (a repeating interactor timer; or call
        ``refine()``).

    Notes
    -----
    Nothing is depth-composited: the picture is the background, and other actors of the
    plotter are drawn over it. So that the camera frames the grid (pyvista's first
    view, ``reset_camera``, the ``r`` key), a fully transparent actor of the grid's eight
    corners is added to the plotter, and ``detach()``
    removes it again; a plotter whose camera has not been set yet is given pyvista's
    default view of the grid before the key light is placed. The first picture is
    rendered by this call, so that a bad method option is reported here rather than
    from inside a window render (the cost: one frame, which the window's first render
    then reuses when the camera and size are unchanged).

    Examples
    --------
    >>> import numpy as np, pyvista as pv
    >>> import vtkillum.pyvista_accessor  # noqa: F401  (registers grid.illum)
    >>> grid = pv.ImageData(dimensions=(12, 12, 12), spacing=(0.2, 0.2, 0.2))
    >>> grid["density"] = np.linspace(0.0, 1.0, grid.n_points)
    >>> pl = pv.Plotter(off_screen=True, window_size=(48, 48))
    >>> shown = grid.illum.add_computed(pl, "emission", cmap="bone", device="cpu")
    >>> pl.camera.azimuth += 30              # the next render follows the camera
    >>> image = pl.screenshot()
    >>> bool(np.abs(image.astype(int) - shown.display_image()).max() <= 1)
    True
    >>> pl.close()
    """
    inputs_given = dict(locals())
    renderer = _plotter_renderer(plotter)
    if not isinstance(grid, vtkImageData):
        raise TypeError(f"grid must be a pyvista.ImageData (uniform grid), got "
                        f"{type(grid).__name__}; resample other meshes first, e.g. "
                        "pv.ImageData(...).sample(mesh)")
    method = _check_method(method)
    exposure = _check_positive(exposure, "exposure")
    gamma = _check_positive(gamma, "gamma")
    resolution_scale = _check_positive(resolution_scale, "resolution_scale")
    if resolution_scale > 1.0:
        raise ValueError(f"resolution_scale must lie in (0, 1] (a fraction of the window "
                         f"size), got {_short(resolution_scale)}")
    inputs = _parse_inputs(grid, inputs_given)
    illumination = options.pop("illumination", None)
    if illumination is not None and method != "illumination":
        raise ValueError(f"illumination= is for method='illumination', not {method!r}")
    from vtkillum.core.device import resolve_device
    from vtkillum.mappers.camera_bridge import camera_from_vtk

    try:
        device = resolve_device(device)
        core_lights, illumination = _lights_and_illumination(inputs.volume, lights,
                                                             illumination)
    except (TypeError, ValueError) as err:
        raise _in_accessor_words(err) from None
    camera_was_set = plotter.renderer.camera_set
    bounds = _add_bounds_actor(plotter, grid)
    shown = None
    try:
        width, height = (max(1, n) for n in renderer.GetSize())
        # plotter.camera gives an unset camera pyvista's default view of the bounds
        camera = camera_from_vtk(plotter.camera, aspect=width / height)
        scene = _scene(inputs, core_lights, camera, albedo=albedo, anisotropy=anisotropy)
        shown = _plotter_compute_class()(
            renderer, inputs.volume, scene, method=method, illumination=illumination,
            device=device, exposure=exposure, gamma=gamma, resolution_scale=resolution_scale,
            **options)
        shown._bounds_actor = (plotter, bounds)
        shown.update()  # the first picture: a bad option fails here, not inside a render
    except (TypeError, ValueError) as err:
        # leave the plotter as it was: no background, no bounds, the camera still unset
        if shown is not None:
            shown.detach()
        else:
            plotter.remove_actor(bounds, reset_camera=False, render=False)
        plotter.renderer.camera_set = camera_was_set
        raise _in_accessor_words(err) from None
    return shown


def _plotter_renderer(plotter):
    """``plotter.renderer`` (a vtkRenderer), or a TypeError/ValueError naming ``plotter``."""
    from vtkmodules.vtkRenderingCore import vtkRenderer

    renderer = getattr(plotter, "renderer", None) if isinstance(plotter, pv.BasePlotter) \
        else None
    if not isinstance(renderer, vtkRenderer):
        raise TypeError(f"plotter must be a pyvista.Plotter, got {type(plotter).__name__}")
    if getattr(plotter, "render_window", None) is None:
        raise ValueError("plotter is closed: make a new pyvista.Plotter")
    return renderer


def _check_method(method) -> str:
    """``method``, a registered name, or a ValueError listing them (and the spelling meant)."""
    from vtkillum.core.render import METHODS

    if isinstance(method, str) and method in METHODS:
        return method
    hint = ""
    if isinstance(method, str) and method.replace("_", "-") in METHODS:
        hint = f" (did you mean {method.replace('_', '-')!r}?)"
    raise ValueError(f"method={_short(method)} is not a rendering method{hint}; choose one "
                     f"of {sorted(METHODS)}")


def _check_positive(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {_short(value)}")
    return float(value)


def _add_bounds_actor(plotter, grid):
    """A fully transparent actor of the grid's 8 corners: it draws nothing visible but gives
    the plotter the grid's bounds (camera framing, ``reset_camera``, the ``r`` key).

    VTK counts only points that belong to cells in a mapper's bounds, so the corners are
    vertices, and opacity 0 hides them (blending leaves the frame buffer unchanged).
    """
    corners = pv.PolyData(np.array([[x, y, z] for x in grid.bounds[0:2]
                                    for y in grid.bounds[2:4] for z in grid.bounds[4:6]],
                                   dtype=np.float64))
    actor = pv.Actor(mapper=pv.DataSetMapper(corners))
    actor.prop.opacity = 0.0
    plotter.add_actor(actor, reset_camera=None, render=False, pickable=False)
    return actor


_PLOTTER_COMPUTE_CLASS = []


def _plotter_compute_class():
    """``ComputeVolumeRenderer`` whose ``detach`` also removes the bounds actor (imported
    here: the mappers need VTK's rendering modules, which importing this module does not)."""
    if not _PLOTTER_COMPUTE_CLASS:
        from vtkillum.mappers.compute_mapper import ComputeVolumeRenderer

        class PlotterComputeVolume(ComputeVolumeRenderer):
            __doc__ = ComputeVolumeRenderer.__doc__
            _bounds_actor = None

            def detach(self) -> None:
                super().detach()
                if self._bounds_actor is not None:
                    plotter, actor = self._bounds_actor
                    self._bounds_actor = None
                    if getattr(plotter, "render_window", None) is not None:
                        plotter.remove_actor(actor, reset_camera=False, render=False)

        PlotterComputeVolume.__module__ = __name__
        _PLOTTER_COMPUTE_CLASS.append(PlotterComputeVolume)
    return _PLOTTER_COMPUTE_CLASS[0]


#: Field data of an :func:`ambient_extinction` output: ``(radius, units)``, units 0 voxels,
#: 1 world (what the mapper needs to show it as the filter computed it).
AMBIENT_FIELD = "vtkillum_ambient"


def _add_ambient_field(image, radius, radius_units) -> None:
    from vtkmodules.util.numpy_support import numpy_to_vtk

    row = np.array([[float(radius), 1.0 if radius_units == "world" else 0.0]])
    array = numpy_to_vtk(row, deep=True)
    array.SetName(AMBIENT_FIELD)
    image.GetFieldData().AddArray(array)


def _ambient_settings(illumination):
    """``(options, lights)`` when ``illumination`` is ambient extinction, else ``None``.

    An :class:`AmbientExtinctionFilter` (or its output port) gives its own ``Radius``,
    ``RadiusUnits`` and lights (it need not have run: the mapper computes what it
    shows). An image with an ``ambient_extinction`` point array and no illumination-volume
    arrays (those take precedence) gives what :func:`ambient_extinction` recorded with it
    (nothing recorded: the filter's default radius, no lights).
    """
    from vtkmodules.vtkCommonExecutionModel import vtkAlgorithmOutput

    from vtkillum.io.illumination_arrays import lights_from_field

    producer = (illumination.GetProducer() if isinstance(illumination, vtkAlgorithmOutput)
                else illumination)
    if isinstance(producer, AmbientExtinctionFilter):
        options = {"radius": producer.GetRadius(), "radius_units": producer.GetRadiusUnits()}
        return options, list(producer.GetLights()) if producer.GetComputeRadiance() else []
    if not isinstance(illumination, vtkImageData):
        return None
    pd = illumination.GetPointData()
    if (pd.GetArray("ambient_extinction") is None or pd.GetArray("transmittance") is not None
            or pd.GetArray("fluence") is not None):
        return None
    options = {}
    array = illumination.GetFieldData().GetArray(AMBIENT_FIELD)
    if array is not None and array.GetNumberOfComponents() >= 2:
        radius, units = (array.GetComponent(0, c) for c in range(2))
        options = {"radius": float(radius), "radius_units": "world" if units > 0.5 else "voxels"}
    return options, lights_from_field(illumination) or []


def _mapper_input(grid, inputs: _Inputs):
    """``(image, array name)`` for the illuminated mapper, which renders one point array.

    The grid itself when ``scalars`` is a one-component point array (the mapper then
    follows edits of the grid); otherwise a grid of the same structure holding the values
    the filters render (cell data averaged onto the points, the chosen ``component``,
    NaN/Inf filled).
    """
    scalars = inputs.scalars
    pd = grid.GetPointData()
    array = pd.GetScalars() if scalars is None else pd.GetArray(scalars)
    if (array is not None and array.GetName() and array.GetNumberOfComponents() == 1
            and inputs.component is None
            and (scalars is not None or pd.GetScalars() is not None)
            and np.all(np.isfinite(np.asarray(grid.point_data[array.GetName()])))):
        return grid, scalars
    name = scalars or (array.GetName() if array is not None else None) or "values"
    data = pv.ImageData()
    data.copy_structure(grid)
    data.point_data[name] = np.asarray(inputs.volume.scalars).ravel(order="F")
    data.point_data.active_scalars_name = name
    return data, name


# === the accessor ======================================================================================
class IllumAccessor:
    """``grid.illum``: the vtkillum filters and renderers on a ``pyvista.ImageData``.

    Each method is the module function of the same name with the grid first.
    """

    def __init__(self, grid) -> None:
        self._grid = grid

    def optical_properties(self, *args, **kwargs):
        return optical_properties(self._grid, *args, **kwargs)

    def transmittance(self, *args, **kwargs):
        return transmittance(self._grid, *args, **kwargs)

    def convection_diffusion(self, *args, **kwargs):
        return convection_diffusion(self._grid, *args, **kwargs)

    def photon_density(self, *args, **kwargs):
        return photon_density(self._grid, *args, **kwargs)

    def many_lights(self, *args, **kwargs):
        return many_lights(self._grid, *args, **kwargs)

    def ambient_extinction(self, *args, **kwargs):
        return ambient_extinction(self._grid, *args, **kwargs)

    def render(self, *args, **kwargs):
        return render(self._grid, *args, **kwargs)

    def add_to(self, plotter, *args, **kwargs):
        """:func:`add_illuminated_volume` of this grid."""
        return add_illuminated_volume(plotter, self._grid, *args, **kwargs)

    def add_computed(self, plotter, *args, **kwargs):
        """:func:`add_computed_volume` of this grid."""
        return add_computed_volume(plotter, self._grid, *args, **kwargs)


for _method in ("optical_properties", "transmittance", "convection_diffusion",
                "ambient_extinction", "render"):
    getattr(IllumAccessor, _method).__doc__ = globals()[_method].__doc__


class NotImageDataAccessor:
    """``mesh.illum`` on any other pyvista dataset: an ``AttributeError`` (``hasattr``
    stays False) that says how to get a ``pyvista.ImageData``."""

    def __init__(self, mesh) -> None:
        raise AttributeError(not_image_data_message(mesh))


def not_image_data_message(mesh) -> str:
    """Why ``mesh`` has no ``illum`` accessor and what to do instead."""
    kind = type(mesh).__name__
    head = (f"{kind!r} object has no attribute {ACCESSOR!r}: vtkillum renders uniform grids "
            "(pyvista.ImageData)")
    if isinstance(mesh, pv.MultiBlock):
        return (f"{head}; pick an ImageData block (e.g. blocks[0].{ACCESSOR}), or resample a "
                "block onto pv.ImageData with sample()")
    return (f"{head}; resample the {kind} onto one first: grid = pv.ImageData(dimensions=(n, n, "
            "n), spacing=(dx, dy, dz), origin=mesh.bounds[::2]).sample(mesh) (spacing: the "
            f"size of mesh.bounds / (n - 1)), then grid.{ACCESSOR}.<method>(...)")


def register() -> None:
    """Register ``grid.illum`` on ``pyvista.ImageData`` once (importing this module does it),
    and on every other dataset an accessor whose ``AttributeError`` says to resample
    (:class:`NotImageDataAccessor`).

    With pyvista < 0.48 (no accessors) this warns and the module functions still work.
    """
    if not hasattr(pv, "register_dataset_accessor"):
        import warnings

        warnings.warn(f"pyvista {pv.__version__} has no dataset accessors (>= 0.48 needed): "
                      "use the functions of vtkillum.pyvista_accessor instead of grid.illum",
                      stacklevel=2)
        return
    if ACCESSOR not in vars(pv.ImageData):
        pv.register_dataset_accessor(ACCESSOR, pv.ImageData)(IllumAccessor)
    if ACCESSOR not in vars(pv.DataObject):  # ImageData's own accessor comes first in its MRO
        pv.register_dataset_accessor(ACCESSOR, pv.DataObject)(NotImageDataAccessor)


register()
