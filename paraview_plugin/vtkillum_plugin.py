"""ParaView plugin: the vtkillum filters in ParaView's ``vtkIllum`` filter menu.

Load it with *Tools → Manage Plugins → Load New* (this file), or in pvpython /
pvbatch with ``LoadPlugin("…/paraview_plugin/vtkillum_plugin.py", ns=globals())``.
ParaView 5.11 (Debian) needs the environment of ``paraview_plugin/README.md``:
only ``warp`` (and ``sitecustomize.py``) on ``PYTHONPATH``, under ``xvfb-run -a``
when headless.

Every class here subclasses a filter of :mod:`vtkillum.filters` and only declares
its ParaView properties (server-manager XML through ParaView's decorators); the
computation stays in the filters. What ParaView needs on top (a light table,
ParaView's colour map, errors in ParaView's words, the output arrays the render
view reads) is :class:`vtkillum_paraview.glue.ParaViewGlue`.

One transfer function: the filters have no colour or opacity editor of their own.
They take the colour map and opacity function of the array their display colours
by (hidden properties ``LookupTable`` and ``ScalarOpacityFunction``, kept linked
by :mod:`vtkillum_paraview.links`), so editing it in the Color Map Editor
re-executes the filter.

Rendered, not baked: in the render view the illumination (per-light
transmittance, scattered fluence, lights) is applied per sample by the GPU ray
caster (:mod:`vtkillum_paraview.display`). ``OutputRGBA`` adds the older baked
``illuminated_rgba`` array for remote or parallel rendering (:func:`ShowIlluminated`).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from xml.sax.saxutils import escape

_HERE = Path(__file__).resolve().parent
if str(_HERE) not in sys.path:  # the vtkillum_paraview package next to this file
    sys.path.insert(0, str(_HERE))
try:
    import vtkillum
except ImportError:
    # Loaded from a checkout: the package sits next to this directory.
    _repo = _HERE.parent
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
from vtkillum_paraview.glue import DEFAULT_EXPOSURE, ParaViewGlue, light_row

from vtkillum.core.photon.mapper import DIRECT_MODES
from vtkillum.filters.ambient_extinction import RADIUS_UNITS, AmbientExtinctionFilter
from vtkillum.filters.base import DEFAULT_CACHE_MB
from vtkillum.filters.convection_diffusion_light import (
    DEFAULT_LIGHT_VOLUME_SCALE,
    SCHEMES,
    SOLVERS,
    ConvectionDiffusionLightFilter,
)
from vtkillum.filters.convection_diffusion_light import MODELS as CD_MODELS
from vtkillum.filters.light_transmittance import LightTransmittanceFilter
from vtkillum.filters.many_lights import _CHOICES as MANY_LIGHTS_CHOICES
from vtkillum.filters.many_lights import ManyLightsFilter
from vtkillum.filters.optical_properties import OpticalPropertiesFilter
from vtkillum.filters.photon_density import PhotonDensityFilter
from vtkillum.filters.refraction_render import (
    DEFAULT_IMAGE_SIZE,
    DEFAULT_LIGHT_DIRECTION,
    MAX_IMAGE_SIZE,
    RefractionRenderFilter,
)
from vtkillum.filters.refraction_render import RGB_ARRAY as REFRACTION_RGB
from vtkillum.filters.rgba_output import RGBA_ARRAY, RGBA_TYPES, IlluminatedRGBAOutput

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
  <Documentation>The point array to illuminate. Its colour map and opacity function (the
  Color Map Editor's, for this array) are the filter's transfer function; the display
  colours by it. A vector array is reduced as the display colours it (Magnitude or one
  component).</Documentation>
</StringVectorProperty>"""

# No editor of their own: the display's colour map and opacity function of the Scalars array,
# set and kept up to date by vtkillum_paraview.links (a filter-owned colour map property
# crashed ParaView 5.11's Properties panel, issue 12).
TRANSFER_FUNCTIONS = """
<ProxyProperty name="LookupTable" command="SetLookupTable" null_on_empty="1"
               panel_visibility="never">
  <ProxyGroupDomain name="groups"><Group name="lookup_tables" /></ProxyGroupDomain>
  <Documentation>The colour map of the Scalars array (scattering colour), the one the
  Color Map Editor edits; set by the plugin from the display.</Documentation>
</ProxyProperty>
<ProxyProperty name="ScalarOpacityFunction" command="SetOpacityFunction" null_on_empty="1"
               panel_visibility="never">
  <ProxyGroupDomain name="groups"><Group name="piecewise_functions" /></ProxyGroupDomain>
  <Documentation>The opacity function of the Scalars array (opacity per Scalar Opacity Unit
  Distance); set by the plugin from the display.</Documentation>
</ProxyProperty>"""

LIGHTS = """
<DoubleVectorProperty name="Lights" command="AddLight" clean_command="RemoveAllLights"
                      repeat_command="1" number_of_elements_per_command="8"
                      number_of_elements="8" default_values="0 1 -1 -1 1 1 1 0">
  <Documentation>One row per light, world coordinates: Type (0 directional, 1 point),
  X Y Z (directional: the direction the light travels; point: its position), R G B
  (directional: irradiance; point: intensity, irradiance = intensity / max(distance,
  radius)^2), Radius (point lights: the size of the source, 0 = half a voxel).</Documentation>
  <Hints>
    <ShowComponentLabels>
      <ComponentLabel component="0" label="Type" />
      <ComponentLabel component="1" label="X" />
      <ComponentLabel component="2" label="Y" />
      <ComponentLabel component="3" label="Z" />
      <ComponentLabel component="4" label="R" />
      <ComponentLabel component="5" label="G" />
      <ComponentLabel component="6" label="B" />
      <ComponentLabel component="7" label="Radius" />
    </ShowComponentLabels>
  </Hints>
</DoubleVectorProperty>"""

CACHE_DOC = (f"Memory (MB) for outputs kept per time step, so stepping back through a "
             f"series does not recompute (0: no cache). Default: a quarter of the memory "
             f"free when the plugin was loaded ({DEFAULT_CACHE_MB:.0f} MB here); a message "
             f"says when a series does not fit.")

CACHE_STATISTICS = """
<DoubleVectorProperty name="CacheStatistics" command="GetCacheStatisticsVector"
                      information_only="1" number_of_elements="4" default_values="0 0 0 0"
                      panel_visibility="advanced">
  <SimpleDoubleInformationHelper />
  <Documentation>Time-step cache: hits, misses, entries, megabytes.</Documentation>
</DoubleVectorProperty>"""


def optical_model_xml(albedo=True) -> str:
    """Input array, (hidden) transfer functions, opacity unit distance (and albedo)."""
    parts = [INPUT_ARRAY, TRANSFER_FUNCTIONS,
             _number("double", "ScalarOpacityUnitDistance", "SetScalarOpacityUnitDistance", 0.0,
                     "Opacity unit distance u (world units): the opacity function gives the "
                     "opacity of a slab of thickness u. 0: the display's (it follows the "
                     "display's Scalar Opacity Unit Distance; ParaView's default is the "
                     "approximate cell length).", lo=0.0, advanced=True)]
    if albedo:
        parts.append(_number("double", "Albedo", "SetAlbedo", 0.9,
                             "Single-scattering albedo: the fraction of extinction that scatters.",
                             lo=0.0, hi=1.0))
    return "".join(parts)


def lighting_xml() -> str:
    """Lights, anisotropy, exposure and device."""
    return "".join([
        LIGHTS,
        _number("double", "Anisotropy", "SetAnisotropy", 0.0,
                "Henyey-Greenstein g in (-1, 1): > 0 forward, < 0 backward scattering; the "
                "render view applies the phase function per sample.", lo=-0.99, hi=0.99),
        _number("double", "Exposure", "SetExposure", round(DEFAULT_EXPOSURE, 6),
                "Factor on the scattered radiance; 4 pi shows a fully lit voxel under "
                "irradiance 1 in albedo x colour. Does not recompute the illumination.",
                lo=0.0, hi=100.0),
        _string_list("Device", "SetDevice", ("auto", "cpu", "cuda"), "auto",
                     "Warp device: auto (CUDA when present, else CPU; VTKILLUM_DEVICE "
                     "overrides), cpu or cuda.", advanced=True),
    ])


def output_xml(scale_command="SetOutputScale", scale_default=1.0, rgba=True) -> str:
    """Resolution, RGBA output and cache properties."""
    parts = [_number("double", "LightVolumeScale", scale_command, scale_default,
                     "Resolution of the illumination grid relative to the data, in (0, 1]; "
                     "the output stays on the data's grid (illumination resampled).",
                     lo=0.05, hi=1.0)]
    if rgba:
        parts += [
            _boolean("OutputRGBA", "SetOutputRGBA", 0,
                     f"Also bake '{RGBA_ARRAY}' (colour x illumination, opacity) as active "
                     "scalars, for remote or parallel rendering (vtkillum_plugin."
                     "ShowIlluminated); the render view does not need it.", advanced=True),
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
                CACHE_DOC, lo=0.0, hi=1048576.0),
        CACHE_STATISTICS,
    ]
    return "".join(parts)


def distributed_xml() -> str:
    """The MPI mode switch of the filters with a distributed core (on by default)."""
    return _boolean("Distributed", "SetDistributed", 1,
                    "Under MPI (pvbatch/pvserver on several ranks): compute only this rank's "
                    "piece, exchanging planes and ghost layers with the other ranks (the "
                    "one-rank result); off: every rank computes the whole volume and keeps "
                    "its piece. One Output Messages line per rank names the mode.",
                    advanced=True)


def _proxy(name: str, label: str, *property_xmls: str, ports=("Illumination",),
           representation: str = "Volume", hints: str = ""):
    """Declare a filter proxy: image-data input, ``property_xmls`` in panel order, output
    ``ports`` (the first is shown as ``representation``), the ``vtkIllum`` menu hint and
    further ``hints`` (XML)."""

    def decorate(cls):
        cls.paraview_label = label
        # A value the filter refuses is kept as an error of the next execution, reported
        # without a traceback (see ParaViewGlue.property_setter).
        for xml in property_xmls:
            for command in re.findall(r'\bcommand="(Set\w+)"', xml):
                if command in dir(cls):
                    setattr(cls, command, ParaViewGlue.property_setter(getattr(cls, command)))
        cls = smdomain.datatype(dataTypes=["vtkImageData"], composite_data_supported=False)(cls)
        cls = smdomain.xml('<InputArrayDomain name="input_array" attribute_type="point" />')(cls)
        cls = smproperty.input(name="Input", port_index=0)(cls)
        for xml in property_xmls:
            cls = smproperty.xml(xml)(cls)
        if len(ports) > 1:
            cls = smproperty.xml("".join(f'<OutputPort name="{port}" index="{i}" />'
                                         for i, port in enumerate(ports)))(cls)
        cls = smhint.xml(f'<ShowInMenu category="{MENU}" />'
                         f'<RepresentationType view="RenderView" type="{representation}" '
                         f'port="0" />{hints}')(cls)
        return smproxy.filter(name=name, label=label, support_reload=False)(cls)

    return decorate


# === the filters ===================================================================================
@_proxy("vtkIllumOpticalProperties", "vtkIllum Optical Properties",
        optical_model_xml(),
        _number("double", "OutputScale", "SetOutputScale", 1.0,
                "Output resolution relative to the data, in (0, 1].", lo=0.05, hi=1.0),
        _number("double", "CacheSizeMB", "SetCacheSizeMB", DEFAULT_CACHE_MB,
                CACHE_DOC, lo=0.0, hi=1048576.0),
        CACHE_STATISTICS)
class OpticalProperties(ParaViewGlue, OpticalPropertiesFilter):
    """sigma_t, scattering colour, sigma_s and sigma_a per point (OpticalPropertiesFilter)."""

    full_resolution_output = False


@_proxy("vtkIllumLightTransmittance", "vtkIllum Light Transmittance",
        optical_model_xml(),
        lighting_xml(),
        _number("double", "StepSize", "SetStepSize", 0.0,
                "Longest step along shadow rays (world units); 0: half the smallest spacing.",
                lo=0.0, advanced=True),
        _number("int", "SegmentPlanes", "SetSegmentPlanes", 16,
                "Directional lights: chained shadow-ray segments, T interpolated every "
                "this many grid planes (cost N^3 L instead of N^4; sharp shadows blur by "
                "about sqrt(N/L)/2 cells). 0: one exact shadow ray per point. Distributed "
                "runs give the one-rank result either way.",
                lo=0, advanced=True),
        distributed_xml(),
        output_xml())
class LightTransmittance(IlluminatedRGBAOutput, ParaViewGlue, LightTransmittanceFilter):
    """Shadow rays to every light: transmittance per light (single scattering)."""


@_proxy("vtkIllumConvectionDiffusionLight", "vtkIllum Convection-Diffusion Light",
        optical_model_xml(),
        lighting_xml(),
        _string_list("DiffusionModel", "SetDiffusionModel", CD_MODELS, CD_MODELS[0],
                     "physical: the diffusion approximation of radiative transfer (multiple "
                     "scattering from Albedo, Anisotropy and the colour map; Scattering "
                     "unused); paper: Zhang & Ma's diffusion of the light volume with "
                     "Scattering."),
        _number("double", "Scattering", "SetScattering", "0 0 0",
                "DiffusionModel paper only: diffusion coefficient per RGB channel (world "
                "units^2): how far light spreads; 0 0 0 is shadows only.", lo=0.0, elements=3,
                advanced=True),
        _number("int", "Iterations", "SetIterations", 0,
                "Diffusion iterations per update; 0 iterates until Tolerance.", lo=0,
                hi=10000, advanced=True),
        _number("double", "Tolerance", "SetTolerance", 3e-4,
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
        distributed_xml(),
        output_xml("SetLightVolumeScale", DEFAULT_LIGHT_VOLUME_SCALE))
class ConvectionDiffusionLight(IlluminatedRGBAOutput, ParaViewGlue,
                               ConvectionDiffusionLightFilter):
    """Zhang & Ma's convection-diffusion light volume: transmittance and scattered fluence."""


@_proxy("vtkIllumAmbientExtinction", "vtkIllum Ambient Extinction",
        optical_model_xml(),
        lighting_xml(),
        _number("double", "Radius", "SetRadius", 4.0,
                "Radius of the ambient sphere, in RadiusUnits.", lo=0.1, hi=64.0),
        _string_list("RadiusUnits", "SetRadiusUnits", RADIUS_UNITS, RADIUS_UNITS[0],
                     "voxels: Radius times the mean spacing; world: world units."),
        _boolean("ComputeRadiance", "SetComputeRadiance", 1,
                 "Also tube-march the radiance cache (the light the render view shows)."),
        distributed_xml(),
        output_xml())
class AmbientExtinction(IlluminatedRGBAOutput, ParaViewGlue, AmbientExtinctionFilter):
    """Ament et al.'s ambient extinction and radiance cache (the cache is the fluence)."""


@_proxy("vtkIllumPhotonDensity", "vtkIllum Photon Density",
        optical_model_xml(),
        lighting_xml(),
        _number("int", "Photons", "SetPhotons", 0,
                "Photon paths traced per pass; 0: from a pilot trace.", lo=0, hi=100000000),
        _number("double", "Radius", "SetRadius", 0.0,
                "Photon radius of the first pass, in voxels (x mean spacing); 0: from the "
                "photon map.", lo=0.0, hi=64.0),
        _number("int", "MaxOrder", "SetMaxOrder", 0,
                "Interactions per photon at most: 1 = single scattering, 0 = unbounded "
                "(Russian roulette).", lo=0, hi=1000, advanced=True),
        _number("int", "Passes", "SetPasses", 1,
                "Progressive passes averaged (radius shrinking).", lo=1, hi=1000, advanced=True),
        _number("int", "Seed", "SetSeed", 0, "Seed of the photons.", lo=0, hi=2147483646,
                advanced=True),
        _boolean("Historygrams", "SetHistorygrams", 1,
                 "After a colour map or opacity edit retrace only the photons it affects.",
                 advanced=True),
        _string_list("DirectLight", "SetDirectLight", DIRECT_MODES, DIRECT_MODES[0],
                     "exact: transmittance per light (phase function at render time) plus "
                     "scattered photons; photons: all light from photons (isotropic).",
                     advanced=True),
        _number("double", "StepSize", "SetStepSize", 0.0,
                "Ray-marching step of photon flights and shadow rays (world units); 0: half "
                "the smallest spacing.", lo=0.0, advanced=True),
        output_xml(scale_default=1.0))
class PhotonDensity(IlluminatedRGBAOutput, ParaViewGlue, PhotonDensityFilter):
    """Jönsson et al.'s volumetric photon mapping gathered onto a light volume."""


def _choice(name: str, doc: str) -> str:
    values = MANY_LIGHTS_CHOICES[name][1]
    return _string_list(name, f"Set{name}", values, values[0], doc, advanced=True)


@_proxy("vtkIllumManyLights", "vtkIllum Many Lights",
        optical_model_xml(),
        lighting_xml(),
        _number("int", "Count", "SetCount", 1024,
                "Virtual lights per set (random walks from the lights).", lo=1, hi=100000),
        _number("double", "VSLRadius", "SetVSLRadius", 0.0,
                "Radius of the clamped or spherical virtual lights, in voxels; 0: automatic.",
                lo=0.0, hi=64.0),
        _number("double", "VSLRadiusMFP", "SetVSLRadiusMFP", 0.0,
                "Radius bound in mean free paths at the light (0: no bound).", lo=0.0,
                advanced=True),
        _number("int", "AVSMResolution", "SetAVSMResolution", 16,
                "Texels per cube-map face of each virtual light's shadow map.", lo=2, hi=512,
                advanced=True),
        _number("int", "AVSMNodes", "SetAVSMNodes", 8,
                "Depth samples per shadow-map texel.", lo=2, hi=16, advanced=True),
        _number("double", "DensityScale", "SetDensityScale", 1.0,
                "Global density scale (eqs. 7-8 of Weber et al.).", lo=0.0, advanced=True),
        _number("int", "Seed", "SetSeed", 0, "Seed of the random walks.", lo=0,
                hi=2147483646, advanced=True),
        _choice("VirtualLights", "clamped (bounded, the clamped light spread nearby), "
                "spherical (the paper's VSLs) or point virtual lights."),
        _choice("Transmittance", "avsm: cached in adaptive volumetric shadow maps; "
                "ray-marching: exact."),
        _choice("AVSMLookup", "Shadow-map lookup: trilinear or point."),
        _choice("DistanceSampling", "Free-path sampling of the random walks."),
        _choice("PhaseSampling", "Scattering directions of the random walks: hg or isotropic."),
        _number("double", "StepSize", "SetStepSize", 0.0,
                "Ray-marching step (world units); 0: half the smallest spacing.", lo=0.0,
                advanced=True),
        output_xml(scale_default=0.5),
        ports=("Illumination", "Virtual Lights"),
        # Apply shows the illumination only: the VLs' points would stay in every later view
        # (View type None: not shown on Apply; the eye in the Pipeline Browser shows them,
        # and the Pipeline Browser gives "None" the render view's icon).
        hints='<View type="None" port="1" />')
class ManyLights(IlluminatedRGBAOutput, ParaViewGlue, ManyLightsFilter):
    """Weber et al.'s virtual spherical lights gathered onto a light volume (port 0); the
    virtual lights as points (port 1)."""

    memo_attributes = ("_latest_lights", "state")


def _table(name: str, add: str, clean: str, columns, default: str, doc: str) -> str:
    """A control-point table: ``add`` is called once per row after ``clean``."""
    labels = "".join(f'<ComponentLabel component="{i}" label="{c}" />'
                     for i, c in enumerate(columns))
    n = len(columns)
    return (f'<DoubleVectorProperty name="{name}" command="{add}" clean_command="{clean}" '
            f'repeat_command="1" number_of_elements_per_command="{n}" '
            f'number_of_elements="{n}" default_values="{default}">{_doc(doc)}'
            f"<Hints><ShowComponentLabels>{labels}</ShowComponentLabels></Hints>"
            "</DoubleVectorProperty>")


def _group(label: str, *names: str, advanced: bool = False) -> str:
    return (f'<PropertyGroup label="{label}"'
            + (' panel_visibility="advanced"' if advanced else "") + ">"
            + "".join(f'<Property name="{n}" />' for n in names) + "</PropertyGroup>")


def refraction_xml() -> str:
    """The refraction render's own properties: the two transfer-function tables, the light,
    the method's options, the image and the camera."""
    def vec(values) -> str:
        return " ".join(f"{v:g}" for v in values)

    return "".join([
        _table("RefractiveIndex", "AddRefractiveIndexPoint", "RemoveAllRefractiveIndexPoints",
               ("Value", "Eta"), "0 1",
               "Refractive-index transfer function: one row per control point, data value and "
               "refractive index eta > 0 (1 air, 1.33 water, 1.5 glass); piecewise linear, "
               "constant outside the points. Rays bend where eta changes; one row (or none): "
               "straight rays."),
        _table("MediumColor", "AddMediumColorPoint", "RemoveAllMediumColorPoints",
               ("Value", "R", "G", "B"), "0 1 1 1",
               "Medium-colour transfer function: one row per control point, data value and "
               "the RGB fraction a path of one Scalar Opacity Unit Distance transmits, in "
               "[0, 1] (tinted glass, wine); white: no tint."),
        _number("double", "LightDirection", "SetLightDirection", vec(DEFAULT_LIGHT_DIRECTION),
                "Direction the one distant light travels (world coordinates); it must lie "
                "within 85 degrees of the view direction (the method's limit).", elements=3),
        _number("double", "LightIrradiance", "SetLightIrradiance", "1 1 1",
                "RGB irradiance of the light.", lo=0.0, elements=3),
        _number("double", "Softness", "SetSoftness", 0.0,
                "Soft light: tan of the light's angular radius (0: hard shadows and sharp "
                "caustics).", lo=0.0, hi=2.0),
        _number("double", "Anisotropy", "SetAnisotropy", 0.0,
                "Henyey-Greenstein g in (-1, 1) of the diffuse (particle) term.", lo=-0.99,
                hi=0.99),
        _number("double", "SampleDistance", "SetSampleDistance", 1.0,
                "Spacing of the planes swept through the volume, in voxels (1: the paper's "
                "setting; larger is faster and coarser).", lo=0.1, hi=8.0),
        _number("int", "ImageSize", "SetImageSize", vec(DEFAULT_IMAGE_SIZE),
                "Width and height of the rendered image in pixels (vtkillum_plugin."
                "CopyViewCamera(filter, image_size=True) takes the view's).", lo=1,
                hi=MAX_IMAGE_SIZE, elements=2),
        _number("double", "CameraPosition", "SetCameraPosition", "0 0 0",
                "Camera position; equal to CameraFocalPoint (0 0 0 both, the default): an "
                "automatic camera that frames the data. vtkillum_plugin.CopyViewCamera(filter) "
                "copies the render view's camera.", elements=3),
        _number("double", "CameraFocalPoint", "SetCameraFocalPoint", "0 0 0",
                "Point the camera looks at.", elements=3),
        _number("double", "CameraViewUp", "SetCameraViewUp", "0 1 0",
                "Camera view-up direction.", elements=3),
        _number("double", "CameraViewAngle", "SetCameraViewAngle", 30.0,
                "Vertical view angle in degrees (perspective).", lo=1.0, hi=179.0),
        _boolean("CameraParallelProjection", "SetCameraParallelProjection", 0,
                 "Orthographic projection of half-height CameraParallelScale.", advanced=True),
        _number("double", "CameraParallelScale", "SetCameraParallelScale", 1.0,
                "Half the view height in world units (parallel projection).", lo=0.0,
                advanced=True),
        _boolean("PlaceFacingCamera", "SetPlaceFacingCamera", 1,
                 "Place the picture where the camera sees it: on the plane through the focal "
                 "point, facing the camera, at the data's size (on: shown beside the data in "
                 "a 3D view it faces the camera it was rendered from). Off: in pixel units "
                 "(spacing 1, origin 0) in the xy plane."),
        _number("double", "Exposure", "SetExposure", 0.0,
                "Factor on the radiance in the displayed colours; 0: automatic (the 99.5th "
                "percentile of the brightest channel shows as full brightness).", lo=0.0,
                hi=1000.0),
        _number("double", "Gamma", "SetGamma", 2.2, "Display gamma of the colours.", lo=0.2,
                hi=5.0, advanced=True),
        _number("double", "Background", "SetBackground", "0 0 0",
                "Linear RGB radiance seen where the (bent) rays leave the volume.", lo=0.0,
                elements=3),
        _number("double", "DirectionBlur", "SetDirectionBlur", 1.0,
                "The soft-light kernel applied to the light directions (paper section 4.2).",
                lo=0.0, hi=4.0, advanced=True),
        _boolean("IntensityCorrection", "SetIntensityCorrection", 1,
                 "Caustics from the intensity law (eqs. 11-13).", advanced=True),
        _number("double", "Specular", "SetSpecular", 1.0,
                "Weight of the Cook-Torrance term at refractive boundaries (0: off).", lo=0.0,
                hi=10.0, advanced=True),
        _number("double", "Roughness", "SetRoughness", 0.3,
                "Beckmann RMS slope of the specular lobe.", lo=0.01, hi=1.0, advanced=True),
        _number("int", "Seed", "SetSeed", 0, "Seed of the soft-light kernel's rotations.",
                lo=0, hi=2147483646, advanced=True),
        _string_list("Device", "SetDevice", ("auto", "cpu", "cuda"), "auto",
                     "Warp device: auto (CUDA when present, else CPU; VTKILLUM_DEVICE "
                     "overrides), cpu or cuda.", advanced=True),
        _number("double", "CacheSizeMB", "SetCacheSizeMB", DEFAULT_CACHE_MB,
                CACHE_DOC, lo=0.0, hi=1048576.0),
        CACHE_STATISTICS,
        _group("Refraction", "RefractiveIndex", "MediumColor"),
        _group("Light", "LightDirection", "LightIrradiance", "Softness", "Anisotropy"),
        _group("Image", "SampleDistance", "ImageSize", "Exposure", "Gamma", "Background"),
        _group("Camera", "CameraPosition", "CameraFocalPoint", "CameraViewUp",
               "CameraViewAngle", "CameraParallelProjection", "CameraParallelScale",
               "PlaceFacingCamera"),
    ])


@_proxy("vtkIllumRefractionRender", "vtkIllum Refraction Render",
        optical_model_xml(),
        refraction_xml(),
        ports=("Image",), representation="Slice",
        # The input stays shown: its colour map is the transfer function (and the one to edit).
        hints='<Visibility replace_input="0" />')
class RefractionRender(ParaViewGlue, RefractionRenderFilter):
    """Magnus & Bruckner's refraction and caustics, rendered into a 2D image (port 0): the
    refractive-index and medium-colour tables, one distant light, a camera
    (:func:`CopyViewCamera`); show the picture with :func:`ShowRendered`."""


# === pvpython helpers =================================================================================
def ShowIlluminated(source, view=None, array: str = RGBA_ARRAY):
    """Show a filter's baked ``illuminated_rgba`` (OutputRGBA on) as a volume.

    For remote or parallel rendering, where the render view's per-sample
    illumination (:mod:`vtkillum_paraview.display`) is not available. Volume
    representation coloured directly by the RGBA array (Map Scalars off, Multi
    Components Mapping on) with a colour map and opacity function of its own
    (``UseSeparateColorMap``: two filters never share them) whose points are
    :func:`rgba_opacity_points`. Returns the representation.
    """
    from paraview import simple

    view = view or simple.GetActiveViewOrCreate("RenderView")
    if not int(source.GetPropertyValue("OutputRGBA")):
        source.SetPropertyWithName("OutputRGBA", 1)
    source.UpdatePipeline(float(view.ViewTime))  # the view's time: no extra time-step entry
    info = source.GetDataInformation().GetPointDataInformation().GetArrayInformation(array)
    if info is None:
        raise ValueError(f"{source.GetXMLLabel()} produced no point array {array!r}: it failed "
                         "to execute; see the Output Messages window")
    display = simple.Show(source, view)
    display.SetRepresentationType("Volume")
    display.UseSeparateColorMap = 1
    simple.ColorBy(display, ("POINTS", array))
    display.MapScalars = 0
    display.MultiComponentsMapping = 1
    top = 1.0 if info.GetDataType() in (10, 11) else 255.0  # VTK_FLOAT, VTK_DOUBLE
    opacity = simple.GetOpacityTransferFunction(array, display, separate=True)
    opacity.Points = rgba_opacity_points(unit_distance(source), top)
    display.ScalarOpacityFunction = opacity
    display.ScalarOpacityUnitDistance = 1.0
    simple.HideScalarBarIfNotNeeded(simple.GetColorTransferFunction(array, display,
                                                                    separate=True), view)
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
    """The opacity unit distance a filter proxy uses (0 resolves to ParaView's default, the
    approximate cell length of its input)."""
    u = float(source.GetPropertyValue("ScalarOpacityUnitDistance"))
    if u > 0:
        return u
    import math

    info = source.GetProperty("Input").GetProxy(0).GetDataInformation()
    bounds = info.GetBounds()
    diagonal = math.sqrt(sum((bounds[2 * a + 1] - bounds[2 * a]) ** 2 for a in range(3)))
    cells = info.GetNumberOfCells()
    return diagonal / cells ** (1.0 / 3.0) if cells > 0 and diagonal > 0 else 1.0


def SetLights(source, lights) -> None:
    """Fill a filter proxy's Lights table from core ``DirectionalLight``/``PointLight`` objects."""
    rows = []
    for light in lights:
        rows += light_row(light)
    source.Lights = rows


def CopyViewCamera(source, view=None, image_size: bool = False) -> None:
    """Copy a render view's camera into a vtkIllum Refraction Render's Camera properties.

    Position, focal point, view up, view angle, parallel projection and scale of
    ``view`` (default: the active render view); with ``image_size`` also its size
    in pixels (``ImageSize``). The filter renders again at its next update.
    """
    from paraview import simple

    view = view or simple.GetActiveViewOrCreate("RenderView")
    source.CameraPosition = list(view.CameraPosition)
    source.CameraFocalPoint = list(view.CameraFocalPoint)
    source.CameraViewUp = list(view.CameraViewUp)
    source.CameraViewAngle = float(view.CameraViewAngle)
    source.CameraParallelProjection = int(view.CameraParallelProjection)
    if float(view.CameraParallelScale) > 0:
        source.CameraParallelScale = float(view.CameraParallelScale)
    if image_size:
        source.ImageSize = [int(v) for v in view.ViewSize]


def ShowRendered(source, view=None):
    """Show a vtkIllum Refraction Render's image as the picture it is, seen head-on.

    In ``view``; default: the active render view, or, only where no render view is
    active, a new one placed in the layout (``GetActiveViewOrCreate``). An existing view
    is reused as it is: no new view, no layout change (``AssignViewToLayout`` after a
    ``SaveScreenshot`` once hung ParaView's GUI). The picture is a slice coloured
    directly by its RGB (Map Scalars off, no scalar bar); the view looks at it head-on
    (parallel projection, fitted, 2D interaction, no orientation axes); the filter's
    input is hidden in that view (it cuts through the picture's plane: Show it again to
    compare). Returns the representation.
    """
    from paraview import simple

    if view is None:
        active = simple.GetActiveView()
        view = active if active is not None and active.GetXMLName() == "RenderView" else \
            simple.GetActiveViewOrCreate("RenderView")
    source.UpdatePipeline(float(view.ViewTime))
    display = simple.Show(source, view)
    display.SetRepresentationType("Slice")
    simple.ColorBy(display, ("POINTS", REFRACTION_RGB))
    display.MapScalars = 0
    simple.HideScalarBarIfNotNeeded(simple.GetColorTransferFunction(REFRACTION_RGB), view)
    upstream = source.GetProperty("Input").GetProxy(0) if source.GetProperty("Input") else None
    if upstream is not None:
        from paraview import servermanager

        shown = servermanager.GetRepresentation(servermanager._getPyProxy(upstream), view)
        if shown is not None:
            shown.Visibility = 0
    view.InteractionMode = "2D"
    view.OrientationAxesVisibility = 0
    face_picture(source, view)
    return display


def face_picture(source, view) -> None:
    """Point ``view``'s camera at the picture of ``source`` head-on (parallel projection,
    picture up as view up) and fit it. The picture's axes come from its direction matrix
    (``PlaceFacingCamera``), read from the client-side output where there is one (a
    builtin session); elsewhere the picture is taken to lie in the xy plane."""
    import numpy as np
    from paraview import simple

    bounds = np.asarray(source.GetDataInformation().GetBounds(), dtype=np.float64)
    centre = bounds.reshape(3, 2).mean(axis=1)
    right, up, back = np.eye(3)
    try:
        image = source.GetClientSideObject().GetOutputDataObject(0)
        matrix = image.GetDirectionMatrix()
        axes = np.array([[matrix.GetElement(i, j) for j in range(3)] for i in range(3)])
        right, up, back = axes.T
    except AttributeError:  # no client-side object (a remote server): the xy plane
        pass
    size = max(float(np.linalg.norm(bounds[1::2] - bounds[0::2])), 1.0)
    view.CameraFocalPoint = [float(v) for v in centre]
    view.CameraPosition = [float(v) for v in centre + 2.0 * size * back]
    view.CameraViewUp = [float(v) for v in up]
    view.CameraParallelProjection = 1
    simple.ResetCamera(view)


def CacheStatistics(source) -> dict:
    """The time-step cache counters of a filter proxy: hits, misses, entries, megabytes."""
    source.UpdatePropertyInformation()
    values = list(source.GetProperty("CacheStatistics"))
    return dict(zip(("hits", "misses", "entries", "megabytes"), values))


# Link filters and displays in this session and hook its render views (links.py, display.py).
try:
    from vtkillum_paraview import links as _links
except ImportError:  # no server manager here (a pvserver): nothing to link
    _links = None
if _links is not None:
    _links.install()
# A table property (Lights, RefractiveIndex, MediumColor) set from Python to a list that is
# not a whole number of rows is refused with an error, not cut short (tables.py).
from vtkillum_paraview import tables as _tables  # noqa: E402

# Oriented NIfTI/NRRD/MetaImage/DICOM readers (readers.py); ParaView registers imported classes.
from vtkillum_paraview.readers import DICOMDirectoryReader, MedicalImageReader  # noqa: F401

_tables.install()


__all__ = [
    "AmbientExtinction",
    "CacheStatistics",
    "ConvectionDiffusionLight",
    "CopyViewCamera",
    "LightTransmittance",
    "ManyLights",
    "OpticalProperties",
    "PhotonDensity",
    "RefractionRender",
    "SetLights",
    "ShowIlluminated",
    "ShowRendered",
    "face_picture",
    "rgba_opacity_points",
    "unit_distance",
]
