"""ParaView plugin: the vtkillum filters in ParaView's ``vtkIllum`` filter menu.

Load it with *Tools → Manage Plugins → Load New* (this file), or in pvpython /
pvbatch with ``LoadPlugin("…/paraview_plugin/vtkillum_plugin.py", ns=globals())``.
ParaView 5.11 (Debian) needs the environment of ``paraview_plugin/README.md``:
only ``warp`` (and ``sitecustomize.py``) on ``PYTHONPATH``, under ``xvfb-run -a``
when headless.

Every class here subclasses a filter of :mod:`vtkillum.filters` and only declares
its ParaView properties (server-manager XML through ParaView's decorators); the
computation stays in the filters. The few methods defined here adapt ParaView's
calling conventions (a light table, ParaView's colour map object).

Illuminated display: the illumination filters output ``illuminated_rgba``
(:mod:`vtkillum.filters.rgba_output`), colour × illumination and opacity, which the
standard volume representation renders with *Map Scalars* off, *Multi Components
Mapping* on and an opacity function that accounts for the opacity unit distance
(:func:`rgba_opacity_points`); :func:`ShowIlluminated` sets all of that up.
"""

from __future__ import annotations

import sys
from pathlib import Path
from xml.sax.saxutils import escape

try:
    import vtkillum  # noqa: F401
except ImportError:
    # Loaded from a checkout: the package sits next to this directory.
    _repo = Path(__file__).resolve().parents[1]
    if (_repo / "vtkillum" / "__init__.py").is_file():
        sys.path.insert(0, str(_repo))
    else:
        raise
try:
    import warp  # noqa: F401
except ImportError as err:
    raise ImportError(
        "the vtkillum plugin needs the 'warp' package in ParaView's Python; do not add a "
        "virtual environment's site-packages (two VTKs crash ParaView): run `python "
        "paraview_plugin/pvbatch_env.py` from the vtkillum environment and use the "
        "PYTHONPATH it prints (see paraview_plugin/README.md)"
    ) from err

from paraview.util.vtkAlgorithm import smdomain, smhint, smproperty, smproxy
from vtkmodules.vtkCommonCore import vtkWeakReference
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.filters.convection_diffusion_light import SCHEMES, SOLVERS
from vtkillum.filters.ambient_extinction import RADIUS_UNITS, AmbientExtinctionFilter
from vtkillum.filters.base import DEFAULT_CACHE_MB
from vtkillum.filters.convection_diffusion_light import (
    DEFAULT_LIGHT_VOLUME_SCALE,
    ConvectionDiffusionLightFilter,
)
from vtkillum.filters.light_transmittance import LightTransmittanceFilter
from vtkillum.filters.optical_properties import OpticalPropertiesFilter
from vtkillum.filters.rgba_output import (
    DEFAULT_EXPOSURE,
    RGBA_ARRAY,
    RGBA_TYPES,
    IlluminatedRGBAOutput,
)

paraview_plugin_name = "vtkIllum"
paraview_plugin_version = vtkillum.__version__

MENU = "vtkIllum"

# === server-manager XML of the shared properties =============================================
# Written as XML (through smproperty.xml) rather than one decorated method per property:
# the decorators collect methods in alphabetical order and only from the class's own
# __dict__, whereas these keep a deliberate panel order and are shared by every filter.


def _doc(text: str) -> str:
    return f"<Documentation>{escape(text)}</Documentation>"


def _number(kind: str, name: str, command: str, default, doc: str, lo=None, hi=None,
            label: str | None = None, advanced: bool = False, elements: int = 1) -> str:
    """A Double/IntVectorProperty with an optional range domain."""
    tag = "DoubleVectorProperty" if kind == "double" else "IntVectorProperty"
    domain = "DoubleRangeDomain" if kind == "double" else "IntRangeDomain"
    bounds = "".join(f' {key}="{" ".join([str(v)] * elements)}"'
                     for key, v in (("min", lo), ("max", hi)) if v is not None)
    rng = f'<{domain} name="range"{bounds} />' if bounds else ""
    values = default if isinstance(default, str) else " ".join(str(v) for v in
                                                             (default if elements > 1 else [default]))
    return (f'<{tag} name="{name}" command="{command}" number_of_elements="{elements}" '
            f'default_values="{values}"' + (f' label="{label}"' if label else "")
            + (' panel_visibility="advanced"' if advanced else "")
            + f">{rng}{_doc(doc)}</{tag}>")


def _boolean(name: str, command: str, default: int, doc: str, advanced=False) -> str:
    return (f'<IntVectorProperty name="{name}" command="{command}" number_of_elements="1" '
            f'default_values="{default}"' + (' panel_visibility="advanced"' if advanced else "")
            + f'><BooleanDomain name="bool" />{_doc(doc)}</IntVectorProperty>')


def _string_list(name: str, command: str, values, default: str, doc: str,
                 advanced=False) -> str:
    strings = "".join(f'<String value="{v}" />' for v in values)
    return (f'<StringVectorProperty name="{name}" command="{command}" number_of_elements="1" '
            f'default_values="{default}"' + (' panel_visibility="advanced"' if advanced else "")
            + f'><StringListDomain name="list">{strings}</StringListDomain>{_doc(doc)}'
            "</StringVectorProperty>")


INPUT_ARRAY = """
<StringVectorProperty name="SelectInputScalars" label="Scalars" command="SetInputArrayToProcess"
                      number_of_elements="5" element_types="0 0 0 0 2" animateable="0">
  <ArrayListDomain name="array_list" attribute_type="Scalars" input_domain_name="input_array">
    <RequiredProperties><Property name="Input" function="Input" /></RequiredProperties>
  </ArrayListDomain>
  <Documentation>The point array to illuminate (one component).</Documentation>
</StringVectorProperty>"""

TRANSFER_FUNCTIONS = """
<ProxyProperty name="ScalarOpacityFunction" command="SetScalarOpacity"
               panel_widget="transfer_function_editor">
  <RangedTransferFunctionDomain name="proxy_list">
    <RequiredProperties>
      <Property function="Input" name="Input" />
      <Property function="ArraySelection" name="SelectInputScalars" />
    </RequiredProperties>
  </RangedTransferFunctionDomain>
  <Documentation>Opacity per unit distance as a function of the data value (Edit opens
  ParaView's curve editor; the reset button fits it to the array's range). Python:
  filter.ScalarOpacityFunction.Points = [x0, a0, 0.5, 0, x1, a1, 0.5, 0, ...].</Documentation>
</ProxyProperty>
<ProxyProperty name="ColorTransferFunction" command="SetColorMap">
  <ProxyListDomain name="proxy_list">
    <Proxy group="lookup_tables" name="PVLookupTable" />
  </ProxyListDomain>
  <Documentation>Scattering colour as a function of the data value: the filter's own
  colour map (Python: filter.ColorTransferFunction.ApplyPreset('Inferno (matplotlib)', True),
  .RescaleTransferFunction(lo, hi), .RGBPoints = [...]), or any colour map proxy, e.g.
  GetColorTransferFunction('density').</Documentation>
</ProxyProperty>"""

LIGHTS = """
<DoubleVectorProperty name="Lights" command="AddLight" clean_command="RemoveAllLights"
                      repeat_command="1" number_of_elements_per_command="7"
                      number_of_elements="7" default_values="0 1 -1 -1 1 1 1">
  <Documentation>One row per light: Type (0 directional, 1 point), X Y Z (directional: the
  direction the light travels; point: its position, world units), R G B (directional:
  irradiance; point: intensity, irradiance = intensity / distance^2).</Documentation>
  <Hints>
    <ShowComponentLabels>
      <ComponentLabel component="0" label="Type" />
      <ComponentLabel component="1" label="X" />
      <ComponentLabel component="2" label="Y" />
      <ComponentLabel component="3" label="Z" />
      <ComponentLabel component="4" label="R" />
      <ComponentLabel component="5" label="G" />
      <ComponentLabel component="6" label="B" />
    </ShowComponentLabels>
  </Hints>
</DoubleVectorProperty>"""

CACHE_STATISTICS = """
<DoubleVectorProperty name="CacheStatistics" command="GetCacheStatisticsVector"
                      information_only="1" number_of_elements="4" default_values="0 0 0 0">
  <SimpleDoubleInformationHelper />
  <Documentation>Time-step cache: hits, misses, entries, megabytes.</Documentation>
</DoubleVectorProperty>"""


def optical_model_xml(albedo=True) -> str:
    """Input array, transfer functions, opacity unit distance (and albedo)."""
    parts = [INPUT_ARRAY, TRANSFER_FUNCTIONS,
             _number("double", "ScalarOpacityUnitDistance", "SetScalarOpacityUnitDistance", 0.0,
                     "Opacity unit distance u (world units): the opacity function gives the "
                     "opacity of a slab of thickness u. 0 means the mean voxel spacing.", lo=0.0)]
    if albedo:
        parts.append(_number("double", "Albedo", "SetAlbedo", 0.9,
                             "Single-scattering albedo: the fraction of extinction that scatters.",
                             lo=0.0, hi=1.0))
    return "".join(parts)


def lighting_xml() -> str:
    """Anisotropy, lights and device."""
    return "".join([
        _number("double", "Anisotropy", "SetAnisotropy", 0.0,
                "Henyey-Greenstein g in (-1, 1): > 0 forward, < 0 backward scattering.",
                lo=-0.99, hi=0.99),
        LIGHTS,
        _string_list("Device", "SetDevice", ("auto", "cpu", "cuda"), "auto",
                     "Warp device: auto (CUDA when present, else CPU; VTKILLUM_DEVICE "
                     "overrides), cpu or cuda."),
    ])


def output_xml(scale_command="SetOutputScale", scale_default=1.0, rgba=True) -> str:
    """Resolution, RGBA output and cache properties."""
    parts = [_number("double", "LightVolumeScale", scale_command, scale_default,
                     "Resolution of the illumination volume relative to the data, in (0, 1].",
                     lo=0.05, hi=1.0)]
    if rgba:
        parts += [
            _boolean("OutputRGBA", "SetOutputRGBA", 1,
                     f"Add '{RGBA_ARRAY}' (colour x illumination, opacity) as active scalars, "
                     "rendered by the Volume representation with Map Scalars off."),
            _number("double", "Exposure", "SetExposure", round(DEFAULT_EXPOSURE, 6),
                    "Factor on the radiance per step; 4 pi shows a fully lit voxel under "
                    "irradiance 1 in albedo x colour.", lo=0.0, hi=100.0),
            _number("double", "Gamma", "SetGamma", 1.0,
                    "Display gamma of the RGBA colour (1: linear like VTK).", lo=0.2, hi=5.0,
                    advanced=True),
            '<IntVectorProperty name="RGBAType" command="SetRGBAType" number_of_elements="1" '
            'default_values="0" panel_visibility="advanced"><EnumerationDomain name="enum">'
            + "".join(f'<Entry value="{i}" text="{t}" />' for i, t in enumerate(RGBA_TYPES))
            + "</EnumerationDomain>" + _doc("Component type of the RGBA array.")
            + "</IntVectorProperty>",
        ]
    parts += [
        _number("double", "CacheSizeMB", "SetCacheSizeMB", DEFAULT_CACHE_MB,
                "Memory for outputs kept per time step (0: no cache).", lo=0.0, hi=65536.0,
                advanced=True),
        CACHE_STATISTICS,
    ]
    return "".join(parts)


# === glue between ParaView's calling conventions and the filters ================================
class ParaViewGlue:
    """Methods ParaView calls that the filters spell differently.

    * ``AddLight(type, x, y, z, r, g, b)``: one row of the ``Lights`` table.
    * ``SetColorMap(lut)``: ParaView's colour map is a
      ``vtkDiscretizableColorTransferFunction``, which the filters read through a
      plain ``vtkColorTransferFunction`` copy kept in sync with it.
    * ``GetCacheStatisticsVector()``: the cache counters as numbers for an
      information property.
    """

    def AddLight(self, kind, x, y, z, r, g, b) -> int:
        kind = int(round(kind))
        if kind == 0:
            return self.AddDirectionalLight((x, y, z), (r, g, b))
        if kind == 1:
            return self.AddPointLight((x, y, z), (r, g, b))
        raise ValueError(f"light Type must be 0 (directional) or 1 (point), got {kind}")

    def SetColorMap(self, lut) -> None:
        previous = getattr(self, "_paraview_lut", None)
        if previous is not None:
            previous[0].RemoveObserver(previous[1])
            self._paraview_lut = None
        if lut is None:
            self.SetColorTransferFunction(None)
            return
        copy = vtkColorTransferFunction()
        copy.DeepCopy(lut)
        ref = vtkWeakReference()
        ref.Set(copy)

        def sync(caller, event, ref=ref):
            target = ref.Get()
            if target is not None:
                target.DeepCopy(caller)  # modifies the copy: the filter re-executes

        self._paraview_lut = (lut, lut.AddObserver("ModifiedEvent", sync))
        self.SetColorTransferFunction(copy)

    def GetCacheStatisticsVector(self) -> list:
        stats = self.GetCacheStatistics()
        return [float(stats.hits), float(stats.misses), float(stats.entries),
                stats.bytes / 2.0**20]


def _proxy(name: str, label: str, *property_xmls: str):
    """Declare a filter proxy: image-data input, ``property_xmls`` in panel order, and the
    ``vtkIllum`` menu and Volume-representation hints."""

    def decorate(cls):
        cls = smdomain.datatype(dataTypes=["vtkImageData"], composite_data_supported=False)(cls)
        cls = smdomain.xml('<InputArrayDomain name="input_array" attribute_type="point" '
                           'number_of_components="1" />')(cls)
        cls = smproperty.input(name="Input", port_index=0)(cls)
        for xml in property_xmls:
            cls = smproperty.xml(xml)(cls)
        cls = smhint.xml(f'<ShowInMenu category="{MENU}" />'
                         '<RepresentationType view="RenderView" type="Volume" />')(cls)
        return smproxy.filter(name=name, label=label)(cls)

    return decorate


# === the filters ===================================================================================
@_proxy("vtkIllumOpticalProperties", "vtkIllum Optical Properties",
        optical_model_xml(),
        _number("double", "OutputScale", "SetOutputScale", 1.0,
                "Output resolution relative to the data, in (0, 1].", lo=0.05, hi=1.0),
        _number("double", "CacheSizeMB", "SetCacheSizeMB", DEFAULT_CACHE_MB,
                "Memory for outputs kept per time step (0: no cache).", lo=0.0, hi=65536.0,
                advanced=True),
        CACHE_STATISTICS)
class OpticalProperties(ParaViewGlue, OpticalPropertiesFilter):
    """sigma_t, scattering colour, sigma_s and sigma_a per point (OpticalPropertiesFilter)."""


@_proxy("vtkIllumLightTransmittance", "vtkIllum Light Transmittance",
        optical_model_xml(),
        lighting_xml(),
        _number("double", "StepSize", "SetStepSize", 0.0,
                "Longest step along shadow rays (world units); 0: half the smallest spacing.",
                lo=0.0, advanced=True),
        output_xml())
class LightTransmittance(ParaViewGlue, IlluminatedRGBAOutput, LightTransmittanceFilter):
    """Shadow rays to every light: fluence, transmittance_i and illuminated_rgba."""


@_proxy("vtkIllumConvectionDiffusionLight", "vtkIllum Convection-Diffusion Light",
        optical_model_xml(),
        lighting_xml(),
        _number("double", "Scattering", "SetScattering", "0 0 0",
                "Diffusion coefficient per RGB channel (world units^2): how far light spreads "
                "by multiple scattering; 0 0 0 is shadows only.", lo=0.0, elements=3),
        _number("int", "Iterations", "SetIterations", 0,
                "Diffusion iterations per update; 0 iterates until Tolerance.", lo=0,
                hi=10000, advanced=True),
        _number("double", "Tolerance", "SetTolerance", 1e-4,
                "Relative residual at which the diffusion stops.", lo=1e-8, hi=0.5,
                advanced=True),
        _string_list("Solver", "SetSolver", SOLVERS, SOLVERS[0],
                     "Linear solver of the implicit diffusion step.", advanced=True),
        _number("double", "SourceRadius", "SetSourceRadius", 0.0,
                "Source region of point lights (world units); 0: two light-grid spacings.",
                lo=0.0, advanced=True),
        _string_list("ConvectionScheme", "SetConvectionScheme", sorted(SCHEMES),
                     ConvectionDiffusionLightFilter().GetConvectionScheme(),
                     "Discretisation of the light transport along the light direction.",
                     advanced=True),
        output_xml("SetLightVolumeScale", DEFAULT_LIGHT_VOLUME_SCALE))
class ConvectionDiffusionLight(ParaViewGlue, IlluminatedRGBAOutput,
                               ConvectionDiffusionLightFilter):
    """Zhang & Ma's convection-diffusion light volume: fluence and illuminated_rgba."""


@_proxy("vtkIllumAmbientExtinction", "vtkIllum Ambient Extinction",
        optical_model_xml(),
        lighting_xml(),
        _number("double", "Radius", "SetRadius", 4.0,
                "Radius of the ambient sphere, in RadiusUnits.", lo=0.1, hi=64.0),
        _string_list("RadiusUnits", "SetRadiusUnits", RADIUS_UNITS, RADIUS_UNITS[0],
                     "voxels: Radius times the mean spacing; world: world units."),
        _boolean("ComputeRadiance", "SetComputeRadiance", 1,
                 "Also tube-march the radiance cache (needed for the RGBA output)."),
        output_xml())
class AmbientExtinction(ParaViewGlue, IlluminatedRGBAOutput, AmbientExtinctionFilter):
    """Ament et al.'s ambient extinction and radiance cache; illuminated_rgba from the cache."""


# === pvpython helpers =================================================================================
def ShowIlluminated(source, view=None, array: str = RGBA_ARRAY):
    """Show an illumination filter's ``illuminated_rgba`` as an illuminated volume.

    Volume representation coloured directly by the RGBA array (Map Scalars off,
    Multi Components Mapping on) with the opacity function of
    :func:`rgba_opacity_points`. Returns the representation.
    """
    from paraview import simple

    view = view or simple.GetActiveViewOrCreate("RenderView")
    display = simple.Show(source, view)
    display.SetRepresentationType("Volume")
    simple.ColorBy(display, ("POINTS", array))
    display.MapScalars = 0
    display.MultiComponentsMapping = 1
    info = source.GetDataInformation().GetPointDataInformation().GetArrayInformation(array)
    if info is None:
        raise ValueError(f"{source.GetXMLLabel()} has no point array {array!r}; switch its "
                         "OutputRGBA on")
    top = 1.0 if info.GetDataType() in (10, 11) else 255.0  # VTK_FLOAT, VTK_DOUBLE
    simple.GetOpacityTransferFunction(array).Points = rgba_opacity_points(
        unit_distance(source), top)
    display.ScalarOpacityUnitDistance = 1.0
    simple.HideScalarBarIfNotNeeded(simple.GetColorTransferFunction(array), view)
    return display


def rgba_opacity_points(unit_distance: float, top: float = 255.0, n: int = 256) -> list:
    """Opacity-function points for the RGBA array's fourth component (``a`` in 0..``top``).

    VTK 9.2's ray caster corrects the opacity of dependent (RGBA) components with the
    unit distance of the *last* component, which ParaView 5.11 never sets (its
    ``ScalarOpacityUnitDistance`` goes to component 0), so it is always 1. The points
    therefore map the stored opacity per unit distance ``u`` to the opacity per world
    unit, ``1 - (1 - a) ** (1 / u)``, and the representation's unit distance is set to 1
    (which also holds where VTK uses component 0's). Where that reaches 1 in single
    precision (optical depth above about 16 per world unit) a sample becomes opaque.
    """
    points = []
    for k in range(n):
        a = k / (n - 1)
        points += [a * top, 1.0 - (1.0 - a) ** (1.0 / unit_distance), 0.5, 0.0]
    return points


def unit_distance(source) -> float:
    """The opacity unit distance a filter proxy uses (0 resolves to the mean spacing)."""
    u = float(source.ScalarOpacityUnitDistance)
    if u > 0:
        return u
    info = source.Input.GetDataInformation()
    extent, bounds = info.GetExtent(), info.GetBounds()
    spacings = [(bounds[2 * a + 1] - bounds[2 * a]) / max(extent[2 * a + 1] - extent[2 * a], 1)
                for a in range(3)]
    return float(sum(spacings) / 3.0) if any(spacings) else 1.0


def SetLights(source, lights) -> None:
    """Fill a filter proxy's light table from core ``DirectionalLight``/``PointLight`` objects."""
    rows = []
    for light in lights:
        point = light.to_dict()["type"] == "point"
        vector = light.position if point else light.direction
        rgb = light.intensity if point else light.irradiance
        rows += [float(point), *map(float, vector), *map(float, rgb)]
    source.Lights = rows


__all__ = ["OpticalProperties", "LightTransmittance", "ConvectionDiffusionLight",
           "AmbientExtinction", "ShowIlluminated", "SetLights", "rgba_opacity_points", "unit_distance"]
