"""``ManyLightsFilter``: virtual lights (Weber et al.) as an illumination volume plus the VLs."""

from __future__ import annotations

import numpy as np
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
from vtkmodules.vtkCommonCore import vtkPoints
from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkDataObject, vtkPolyData

from vtkillum.core.illumination import IlluminationVolume
from vtkillum.core.light_transmittance import light_transmittance
from vtkillum.core.many_lights.cache import ManyLightsState
from vtkillum.core.many_lights.gather import gather_params, scattered_fluence
from vtkillum.core.many_lights.render import parse_options
from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.illumination_arrays import illumination_arrays

#: Filter property -> (option name, validator description) of the core's many_lights options.
_CHOICES = {
    "VirtualLights": ("virtual_lights", ("clamped", "spherical", "point")),
    "Transmittance": ("transmittance", ("avsm", "ray-marching")),
    "AVSMLookup": ("avsm_lookup", ("trilinear", "point")),
    "DistanceSampling": ("distance_sampling", ("delta-tracking", "ray-marching")),
    "PhaseSampling": ("phase_sampling", ("hg", "isotropic")),
}
#: Edits that keep the walk: the VLs' powers are re-evaluated (eq. 6), nothing is traced.
_CONTRIBUTION_ONLY = ("color", "albedo", "light-color")


class ManyLightsFilter(IlluminationFilterBase):
    """Virtual lights and the light they scatter, on a light grid; the VLs on port 1.

    Runs the random walks of :mod:`vtkillum.core.many_lights` (one VL set of ``Count``
    VLs, transmittance cached in one AVSM per VL unless ``Transmittance`` is
    ``"ray-marching"``) and evaluates on the output grid (the input's resolution or the
    one chosen with ``OutputScale`` / ``OutputDimensions``, covering the same box):

    Output port 0, ``vtkImageData``:

    ``fluence`` (RGB, active scalars)
        ``sum_l T_l E_l + phi_s``, for display.
    ``transmittance`` (one component per light)
        ``T_l`` towards each real light: the direct light the mappers shade with the
        phase function (:mod:`vtkillum.core.illumination`); the grid of
        :func:`~vtkillum.core.light_transmittance.light_transmittance`'s default (chained
        segments for directional lights, exact rays for point lights).
    ``scattered_fluence`` (RGB)
        ``phi_s``: the fluence of the VLs' light, ``sum_j I_j(w) T(x_j, x) K_j(x)``
        (the light that scattered at least once, taken as isotropic by the mappers).

    and the lights as field data ``vtkillum_lights``. The ``illumination`` method of the
    ray caster renders it; the render method ``many-lights`` gathers the same VLs per
    view-ray sample instead (phase function at the receiver, no grid).

    Output port 1, ``vtkPolyData``: one vertex per VL at its world position, with point
    arrays ``position`` (world), ``radiance`` (RGB ``beta sigma_s / P``: the VL's
    intensity per unit phase function, see :mod:`vtkillum.core.many_lights.contribution`),
    ``radius`` (VSL radius, world units; 0 for point VLs), ``incident_direction``
    (world), ``path``, ``vertex`` (index in its light path) and ``creation`` (creation
    batch). Show them in ParaView or pyvista as points or glyphs.

    Parameters
    ----------
    Count : int
        Virtual lights (at least 1); default 1024 (256 before issue 34). Whole light paths
        are kept, so there may be a few more.
    Seed : int
        Seed of the light paths; default 0.
    VirtualLights : str
        ``"clamped"`` (default: bounded contributions, the clamped light spread over the
        VL's sphere, :mod:`vtkillum.core.many_lights.clamp`), ``"spherical"`` (VSLs, the
        default before issue 34) or ``"point"``.
    VSLRadius : float
        Clamping or VSL radius in voxels (x mean spacing); 0 (default): automatic (clamped:
        from the VLs' density; spherical: 2, the old default).
    VSLRadiusMFP : float
        ... and at most this many mean free paths at the VL (0: no such bound, the
        default; 0.5 before issue 34).
    Transmittance : str
        ``"avsm"`` (default) or ``"ray-marching"`` (exact).
    AVSMResolution : int
        Texels per cube-map face edge; default 16 (48 before issue 34).
    AVSMNodes : int
        (depth, transmittance) nodes per texel, 2 .. 16; default 8.
    AVSMLookup : str
        ``"trilinear"`` (default) or ``"point"``.
    DistanceSampling : str
        ``"delta-tracking"`` (default) or ``"ray-marching"`` (Algorithm 1).
    PhaseSampling : str
        ``"hg"`` (default) or ``"isotropic"``.
    DensityScale : float
        Global density scale ``S`` (eq. 7); default 1.
    StepSize : float
        Marching step in world units (segments, shadow rays); 0 (default): half the
        smallest spacing.
    ColorTransferFunction, ScalarOpacity, ScalarOpacityUnitDistance, Albedo, Anisotropy,
    Lights, Device, OutputScale, OutputDimensions, InputComponent, NaNPolicy,
    PassInputArrays, CacheSizeMB
        As in the base class.

    Notes
    -----
    Units: fluences in the lights' irradiance units (point lights: intensity / world
    unit²); ``radiance`` of a VL in those units times world units². Cost: the walks,
    ``Count`` x 6 x ``AVSMResolution``² texel rays, and ``Count`` lookups per output
    point. The VLs of the last execution are kept in :attr:`state` (a
    :class:`~vtkillum.core.many_lights.cache.ManyLightsState`). The next execution walks
    anew only when the walk depends on what changed: after an edit of the colours, the
    albedo or a light's colour (``Anisotropy`` too with isotropic ``PhaseSampling``) the
    VLs' powers are re-evaluated along the stored paths (eq. 6) and gathered again, the
    transmittance is kept; with nothing changed nothing is launched
    (``docs/many_lights.md``). :meth:`ClearCache` forgets the VLs.
    """

    #: Why this filter runs on the whole volume on every rank under MPI (mode 1).
    distributed_needs = ("a distributed version needs the random walks handed between ranks like photons, every virtual light's shadow map over the whole volume (a sweep per light or an all-gather of the coarse transmittance), and the gather of all lights on every rank; not built yet")

    def __init__(self) -> None:
        super().__init__()
        self.SetNumberOfOutputPorts(2)
        self._count = 1024
        self._seed = 0
        self._vsl_radius = 0.0
        self._vsl_radius_mfp = 0.0
        self._density_scale = 1.0
        self._step_size = 0.0
        self._avsm_resolution = 16
        self._avsm_nodes = 8
        self._choice = {"virtual_lights": "clamped", "transmittance": "avsm",
                        "avsm_lookup": "trilinear", "distance_sampling": "delta-tracking",
                        "phase_sampling": "hg"}
        self.state = None
        self._light_outputs: dict = {}
        self._latest_lights = None
        self._grids = None  # the last scattered fluence and transmittance, see compute

    # --- VTK plumbing ---------------------------------------------------------------------
    def FillOutputPortInformation(self, port, info):
        info.Set(vtkDataObject.DATA_TYPE_NAME(), "vtkPolyData" if port == 1 else "vtkImageData")
        return 1

    def RequestData(self, request, inInfo, outInfo):
        key = self._pending[0] if self._pending is not None else None
        self._latest_lights = None
        status = super().RequestData(request, inInfo, outInfo)
        lights = vtkPolyData.GetData(outInfo.GetInformationObject(1))
        if status != 1:
            lights.Initialize()
            return status
        if self._latest_lights is not None:  # computed now
            if key is not None:
                self._light_outputs = {k: v for k, v in self._light_outputs.items()
                                       if k in self._cache}
                self._light_outputs[key] = self._latest_lights
            lights.ShallowCopy(self._latest_lights)
        elif key in self._light_outputs:     # the image came from the time cache
            lights.ShallowCopy(self._light_outputs[key])
        else:
            lights.Initialize()
        return 1

    def GetVirtualLightsOutput(self) -> vtkPolyData:
        """Port 1 (update the filter first)."""
        return self.GetOutputDataObject(1)

    # --- properties -----------------------------------------------------------------------
    def SetCount(self, count: int) -> None:
        self.set_parameter("_count", _positive_int(count, "Count"))

    def GetCount(self) -> int:
        return self._count

    def SetSeed(self, seed: int) -> None:
        seed = int(seed)
        if not 0 <= seed < 2**31:
            raise ValueError(f"Seed must lie in [0, 2**31), got {seed}")
        self.set_parameter("_seed", seed)

    def GetSeed(self) -> int:
        return self._seed

    def SetVSLRadius(self, radius: float) -> None:
        radius = float(radius)
        if not (np.isfinite(radius) and radius >= 0):
            raise ValueError(f"VSLRadius must be >= 0 voxels (0: automatic), got {radius}")
        self.set_parameter("_vsl_radius", radius)

    def GetVSLRadius(self) -> float:
        return self._vsl_radius

    def SetVSLRadiusMFP(self, radius: float) -> None:
        radius = float(radius)
        if not (np.isfinite(radius) and radius >= 0):
            raise ValueError(f"VSLRadiusMFP must be >= 0 (0: no bound), got {radius}")
        self.set_parameter("_vsl_radius_mfp", radius)

    def GetVSLRadiusMFP(self) -> float:
        return self._vsl_radius_mfp

    def SetDensityScale(self, scale: float) -> None:
        self.set_parameter("_density_scale", _positive(scale, "DensityScale"))

    def GetDensityScale(self) -> float:
        return self._density_scale

    def SetStepSize(self, step: float) -> None:
        step = float(step)
        if not (np.isfinite(step) and step >= 0):
            raise ValueError(f"StepSize must be >= 0 (0: half the smallest spacing), got {step}")
        self.set_parameter("_step_size", step)

    def GetStepSize(self) -> float:
        return self._step_size

    def SetAVSMResolution(self, resolution: int) -> None:
        resolution = _positive_int(resolution, "AVSMResolution")
        if resolution < 2:
            raise ValueError(f"AVSMResolution must be at least 2 texels, got {resolution}")
        self.set_parameter("_avsm_resolution", resolution)

    def GetAVSMResolution(self) -> int:
        return self._avsm_resolution

    def SetAVSMNodes(self, nodes: int) -> None:
        nodes = _positive_int(nodes, "AVSMNodes")
        if not 2 <= nodes <= 16:
            raise ValueError(f"AVSMNodes (depth samples per texel) must lie in [2, 16], got "
                             f"{nodes}")
        self.set_parameter("_avsm_nodes", nodes)

    def GetAVSMNodes(self) -> int:
        return self._avsm_nodes

    def _set_choice(self, prop: str, value: str) -> None:
        option, choices = _CHOICES[prop]
        if value not in choices:
            raise ValueError(f"{prop} must be one of {list(choices)}, got {value!r}")
        if self._choice[option] != value:
            self._choice[option] = value
            self.Modified()

    def SetVirtualLights(self, kind: str) -> None:
        self._set_choice("VirtualLights", kind)

    def GetVirtualLights(self) -> str:
        return self._choice["virtual_lights"]

    def SetTransmittance(self, mode: str) -> None:
        self._set_choice("Transmittance", mode)

    def GetTransmittance(self) -> str:
        return self._choice["transmittance"]

    def SetAVSMLookup(self, lookup: str) -> None:
        self._set_choice("AVSMLookup", lookup)

    def GetAVSMLookup(self) -> str:
        return self._choice["avsm_lookup"]

    def SetDistanceSampling(self, sampling: str) -> None:
        self._set_choice("DistanceSampling", sampling)

    def GetDistanceSampling(self) -> str:
        return self._choice["distance_sampling"]

    def SetPhaseSampling(self, sampling: str) -> None:
        self._set_choice("PhaseSampling", sampling)

    def GetPhaseSampling(self) -> str:
        return self._choice["phase_sampling"]

    # --- compute --------------------------------------------------------------------------
    def ClearCache(self) -> None:
        """Forget the cached outputs and the virtual lights: the next execution walks anew."""
        super().ClearCache()
        self.state = None
        self._grids = None

    def compute(self, volume, params):
        step = params.units.to_length(self._step_size) or None  # canonical units
        scene = params.scene(step_size=step)
        options = dict(self._choice, count=self._count, seed=self._seed,
                       vsl_radius=self._vsl_radius, vsl_radius_mfp=self._vsl_radius_mfp,
                       density_scale=self._density_scale, avsm_resolution=self._avsm_resolution,
                       avsm_nodes=self._avsm_nodes)
        opts = parse_options(options, volume, scene)
        params.progress(0.05)
        shape = tuple(params.output_shape)
        state = self._reusable_state(volume, scene, opts, params.device)
        if state is None:
            self._grids = None
            state = ManyLightsState(volume, scene, opts, params.device)
        elif state.update(scene)["edits"]:  # eq. 6: the VLs' powers along the stored paths
            self._grids = self._grids and dict(self._grids, scattered=None)
        params.progress(0.5)
        grids = self._grids if self._grids is not None and self._grids["shape"] == shape \
            else {"shape": shape, "scattered": None, "transmittance": None}
        if grids["scattered"] is None:
            vls = state.virtual_lights()
            gp = gather_params(opts["step_size"], False, opts["seed"],
                               opts["early_termination"], 1, opts["transmittance"],
                               opts["vl_step"], state.scale)
            grids["scattered"] = np.maximum(scattered_fluence(
                state.medium, vls, state.maps(), gp, shape, volume.extent, params.device), 0.0)
        params.progress(0.8)
        if grids["transmittance"] is None:  # depends on sigma_t and the lights' geometry only
            grids["transmittance"], _ = light_transmittance(
                volume, params.transfer_function, params.unit_distance / state.scale,
                params.lights, shape=shape, step_size=step, device=params.device)
        self.state = state
        self._grids = grids
        self._latest_lights = virtual_lights_polydata(state, volume, params.units)
        illumination = IlluminationVolume.for_volume(volume, grids["scattered"],
                                                     grids["transmittance"])
        return illumination_arrays(illumination, volume, params.lights, shape)

    def _reusable_state(self, volume, scene, opts, device):
        """:attr:`state` when the edit since it was made needs no new walk, else ``None``.

        The walk depends on the data, the options, ``sigma_t`` and the lights' geometry;
        colour, albedo and light colour enter only the VLs' powers, which eq. 6
        re-evaluates along the stored paths (importance-weighted by the densities the
        paths were drawn with: unbiased, and identical to a new walk wherever the
        Russian roulette's survival, ``albedo * max colour``, is unchanged). ``g`` also
        when the directions are sampled isotropically (section 5.2); with HG sampling a
        new ``g`` walks anew.
        """
        state = self.state
        if state is None or state.device != device or state.opts != opts:
            return None
        old = state.volume
        if old is not volume and not (
                old.dims == volume.dims and old.content_key == volume.content_key
                and np.array_equal(old.spacing, volume.spacing)
                and np.array_equal(old.origin, volume.origin)
                and np.array_equal(old.direction, volume.direction)):
            return None
        keep = set(_CONTRIBUTION_ONLY)
        if opts["phase_sampling"] == "isotropic":
            keep.add("anisotropy")
        return state if set(state.edits(scene)) <= keep else None


def virtual_lights_polydata(state, volume, units=None) -> vtkPolyData:
    """The VLs of a :class:`~vtkillum.core.many_lights.cache.ManyLightsState` as points.

    ``volume`` is the state's; ``units`` (:class:`~vtkillum.core.units.WorldUnits`) the
    canonical units it was computed in: the points and arrays come back in world units.
    """
    vls = state.vls
    n = vls.n_vls
    length = 1.0 if units is None else units.length
    origin = np.zeros(3) if units is None else np.asarray(units.origin)
    rotation = np.asarray(volume.direction, np.float64)
    world = ((vls.position.astype(np.float64) @ rotation.T + volume.origin) * length + origin) \
        if n else np.zeros((0, 3))
    poly = vtkPolyData()
    points = vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(world), deep=True))
    poly.SetPoints(points)
    cells = vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(np.arange(n + 1, dtype=np.int64), deep=True),
                  numpy_to_vtkIdTypeArray(np.arange(n, dtype=np.int64), deep=True))
    poly.SetVerts(cells)
    arrays = {
        "position": world,
        "radiance": vls.power().astype(np.float64) * length**2 if n else np.zeros((0, 3)),
        "radius": state.radii().astype(np.float64) * length,
        "incident_direction": (vls.direction().astype(np.float64) @ rotation.T) if n else
        np.zeros((0, 3)),
        "path": vls.vl_path.astype(np.int32),
        "vertex": vls.vl_vertex.astype(np.int32),
        "creation": vls.path_created[vls.vl_path].astype(np.int32),
    }
    for name, values in arrays.items():
        array = numpy_to_vtk(np.ascontiguousarray(values), deep=True)
        array.SetName(name)
        poly.GetPointData().AddArray(array)
    poly.GetPointData().SetActiveScalars("radiance")
    return poly


def _positive(value, name: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value}")
    return value


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not float(value).is_integer() or int(value) < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)
