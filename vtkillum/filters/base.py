"""The base class of every illumination filter: VTK pipeline glue, parameters and time cache.

A subclass implements one method, :meth:`IlluminationFilterBase.compute`, that
turns a :class:`~vtkillum.core.volume.Volume` and an
:class:`IlluminationParameters` into named numpy arrays on the output grid::

    class MyFilter(IlluminationFilterBase):
        def compute(self, volume, params):
            phi = my_core_kernel(volume, params.transfer_function, params.unit_distance,
                                 params.lights, shape=params.output_shape,
                                 device=params.device, progress=params.progress)
            return {"fluence": phi}        # (nx', ny', nz'[, c]) indexed [i, j, k]

Everything else -- input checks and conversion, transfer functions, lights,
output geometry at a chosen resolution, time steps, the per-time-step cache,
progress and error reporting -- lives here.

Pipeline passes
---------------
RequestInformation
    Checks that the input is image data, passes ``TIME_STEPS``/``TIME_RANGE``
    through and announces the output grid: the input's whole extent at full
    resolution, else ``0 .. n' - 1`` covering the same box (same first and last
    points, origin and direction; spacing ``(n - 1) s / (n' - 1)``).
RequestUpdateExtent
    Requests the whole input extent as one piece. Looks the request up in the cache
    (below).
RequestData
    Converts the input (:mod:`vtkillum.io.convert`), calls :meth:`compute` and
    assembles the output, or copies the cached output.

Ctrl-C
------
VTK cannot pass a Python exception through its (C++) pipeline: an exception raised in
``RequestData`` is printed and the request reported as failed, so a ``KeyboardInterrupt``
(Ctrl-C during a long kernel; the core launches in chunks so that it is seen) would end
up as an empty output and, in :meth:`IlluminationFilterBase.execute`, a ``RuntimeError``.
``RequestData`` therefore catches it, leaves the output empty, reports "interrupted"
the VTK way (``ErrorEvent`` observers or the output window) and remembers it; the
filter's own ``Update()``, ``UpdateTimeStep()``, ``UpdateWholeExtent()`` and
``execute()`` re-raise it once VTK has returned. When something else drives the
pipeline (a downstream algorithm's ``Update()``, a render window, ParaView), VTK offers
no way to raise through it: that update fails like any other (empty output, VTK's
failure message), and :meth:`IlluminationFilterBase.GetLastError` says it was
interrupted. (Re-delivering the signal from inside the pipeline does not work either:
Python handles a pending signal at the next call, still inside VTK's callback, where
VTK swallows it again.) The next update re-executes the filter.

Time cache
----------
Outputs are kept per requested time in a :class:`~vtkillum.filters.time_cache.TimeStepCache`
keyed by ``(time, upstream pipeline MTime, filter MTime)`` and bounded by
``CacheSizeMB`` (least recently used entries go first). The filter MTime covers
every property, the input-array selection and -- through observers -- edits of the
transfer functions. VTK's executive brings the input up to date *before* it
calls ``RequestData``, so a hit has to be decided earlier: in
``RequestUpdateExtent`` the filter asks its input for the time step the input
already holds (its ``DATA_TIME_STEP``), whose extent is also unchanged, so the
upstream executive finds nothing to do and does not execute; ``RequestData``
then copies the cached output and stamps it with the cached ``DATA_TIME_STEP``.
Once either MTime moves on, older entries can never be hit and are dropped.

Entries are keyed by the step *computed* (the input's ``DATA_TIME_STEP``), never by
the time requested: a request between two steps gets the step the input delivers
(VTK's readers take the one at or before it), the output says which, and a later
request for either finds it. A request for one of the input's own ``TIME_STEPS``
that the input answers with another step (a file of the series missing or
unreadable) is an error naming the time and the steps, and nothing is cached.

Threads
-------
VTK's pipeline is not thread-safe, and filters may share an upstream source. Every
update through a vtkillum filter (``execute``, ``Update``, ``UpdateTimeStep``,
``UpdateWholeExtent``) and every parameter edit holds :data:`PIPELINE_LOCK` (one
re-entrant lock for all vtkillum filters), so updates from several threads run one
after the other, each gets an output of its own (``execute`` returns a shallow copy),
and an edit made while an update runs applies to the next update, never to half of
one; an update during which a parameter changed is not cached. To edit a VTK
transfer function (several ``AddPoint`` calls) from another thread while updates run,
hold ``PIPELINE_LOCK`` around the edit. A downstream algorithm's own ``Update`` does
not take the lock: the time check above still refuses a step another thread's
request put in the input.

Pieces (ParaView's MPI engine)
------------------------------
Asked for piece *p* of *n* (each rank of ``mpirun -np n pvbatch`` asks for its own),
a filter runs in one of two modes, and one line per rank and layout says which:

*distributed* (filters that implement :meth:`IlluminationFilterBase.compute_piece`:
    light transmittance, ambient extinction without the radiance cache)
    ``RequestUpdateExtent`` asks the input for piece *p* of *n* (VTK's split) plus the
    ghost levels the method needs (:meth:`~IlluminationFilterBase.distributed_ghost_levels`);
    ``RequestData`` calls the distributed core (:mod:`vtkillum.core.parallel`, mpi4py on
    ``MPI_COMM_WORLD``, one warp device per rank), which exchanges planes or ghost layers
    with the other ranks and never gathers the volume. Needs mpi4py, as many MPI ranks as
    pieces, the output grid equal to the input grid (``OutputScale`` 1) and the
    ``Distributed`` property on (its default is the filter's
    :attr:`~IlluminationFilterBase.distributed_by_default`: on where the distributed
    result equals the one-rank result, see :meth:`SetDistributed`); otherwise mode 1,
    with the reason in the line.
*whole volume on every rank* (mode 1, every other filter)
    the filter requests the whole input as one piece, computes the whole volume's
    illumination (shadows and scattered light cross pieces) and outputs piece *p* of it.

Either way the output is piece *p* with the ghost levels asked for downstream, marked in
``vtkGhostType``, so every rank holds its piece of the one-process result and IceT's
compositing joins them without a seam. The time cache is not used in distributed mode.
"""

from __future__ import annotations

import dataclasses
import threading
import types
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkWeakReference
from vtkmodules.vtkCommonDataModel import (
    vtkDataObject,
    vtkDataSetAttributes,
    vtkImageData,
    vtkPiecewiseFunction,
)
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.units import WorldUnits
from vtkillum.filters.time_cache import CacheStatistics, TimeStepCache, default_cache_mb
from vtkillum.io.convert import (
    add_point_array,
    check_image_data,
    first_point,
    image_like,
    resampled_geometry,
    transfer_function_from_vtk,
    volume_from_image_data,
)
from vtkillum.io.illumination_arrays import add_lights_field

#: One lock for every vtkillum filter: VTK's pipeline is not thread-safe (an executive keeps
#: the request of the update in flight), and filters may share an upstream source.
PIPELINE_LOCK = threading.RLock()

#: Attributes that are not settings of the computation (left out of the results key).
_NOT_SETTINGS = frozenset({"_albedo", "_anisotropy", "_unit_distance", "_device",
                           "_nan_policy", "_input_component", "_last_error", "_interrupt",
                           "_pending", "_pass_input_arrays", "_tf_seen"})

#: Default memory budget of the per-time-step cache: a share of the memory available at
#: import (:func:`~vtkillum.filters.time_cache.default_cache_mb`).
DEFAULT_CACHE_MB = default_cache_mb()

DEVICES = ("auto", "cpu", "cuda")

#: Arrays computed by filters that reuse results (:attr:`IlluminationFilterBase.reuses_results`):
#: a transfer-function edit that does not change what a method depends on (a colour edit for
#: the transmittance), or the same settings again from a new filter (each pyvista accessor
#: call makes one), costs a lookup instead of a computation.
_RESULTS = TimeStepCache(int(DEFAULT_CACHE_MB * 2**20))


@dataclass
class IlluminationParameters:
    """What :meth:`IlluminationFilterBase.compute` gets besides the volume.

    Attributes
    ----------
    transfer_function : TransferFunction
        From the filter's colour and scalar-opacity functions (default: an opacity
        ramp 0 .. 0.5 over the data range, white).
    unit_distance : float
        Opacity unit distance ``u`` in world units (resolved: 0 means mean spacing).
    albedo, anisotropy : float
        Single-scattering albedo Λ and Henyey–Greenstein ``g``.
    lights : list of DirectionalLight / PointLight
        World-space lights.
    device : str
        Resolved warp device (``"cpu"``, ``"cuda:0"``).
    output_shape : (int, int, int)
        Points of the output grid, which covers the volume's box (see
        :func:`vtkillum.io.convert.image_like`).
    progress : callable
        ``progress(fraction)`` with fraction in [0, 1]; forwards to ``UpdateProgress``.
    units : vtkillum.core.units.WorldUnits
        :meth:`IlluminationFilterBase.compute` runs in canonical units (lengths of about
        a voxel, :mod:`vtkillum.core.units`), so that data in any length unit give the same
        light: its volume, ``unit_distance`` and ``lights`` are in them. A filter converts
        its own world lengths with ``units.to_length`` and returns quantities per length
        per world length (``units.per_world_length``); transmittance and fluence have no
        length in them.
    """

    transfer_function: TransferFunction
    unit_distance: float
    albedo: float
    anisotropy: float
    lights: list
    device: str
    output_shape: tuple
    progress: Callable[[float], None] = field(default=lambda fraction: None)
    units: WorldUnits = field(default_factory=WorldUnits)

    def scene(self, **fields) -> Scene:
        """A core :class:`~vtkillum.core.scene.Scene` with these optical parameters.

        ``fields`` set the remaining scene fields (camera, step_size, method options...).
        """
        return Scene(transfer_function=self.transfer_function,
                     opacity_unit_distance=self.unit_distance, albedo=self.albedo,
                     anisotropy=self.anisotropy, lights=list(self.lights), **fields)



def pass_arrays(source_image, output) -> None:
    """Add ``source_image``'s point and cell arrays to ``output`` (same points and cells)."""
    for source, target in ((source_image.GetPointData(), output.GetPointData()),
                           (source_image.GetCellData(), output.GetCellData())):
        for i in range(source.GetNumberOfArrays()):
            target.AddArray(source.GetAbstractArray(i))


class IlluminationFilterBase(VTKPythonAlgorithmBase):
    """Base of the illumination filters: one ``vtkImageData`` in, one ``vtkImageData`` out.

    Subclassing: call ``super().__init__()``, implement :meth:`compute`, and give
    each own property a ``SetX`` that validates and calls
    ``self.set_parameter("_x", value)`` (``Modified()`` only on change) plus a
    ``GetX``. Set the class attributes :attr:`requires_lights` and
    :attr:`uses_device` where they differ. See the module docstring for the
    pipeline passes and the time cache.

    Parameters
    ----------
    ColorTransferFunction : vtkColorTransferFunction
        Scattering colour (RGB in [0, 1]) as a function of the data value. Default white.
    ScalarOpacity : vtkPiecewiseFunction
        Opacity per ``ScalarOpacityUnitDistance``. Default: a ramp from 0 to 0.5 over
        the data range. Edits of either function re-execute the filter.
    ScalarOpacityUnitDistance : float
        Opacity unit distance ``u``; 0 (default) means the input's mean spacing.
    Albedo : float
        Single-scattering albedo Λ in [0, 1]; default 0.9.
    Anisotropy : float
        Henyey–Greenstein ``g`` in (-1, 1); default 0.
    Lights
        Set with ``AddDirectionalLight``, ``AddPointLight``, ``SetLight``, ``SetLights``,
        ``RemoveLight``, ``RemoveAllLights``. Default: one white directional light
        travelling along (1, -1, -1).
    Device : str
        ``"auto"`` (default: CUDA when present, else CPU; ``VTKILLUM_DEVICE``
        overrides), ``"cpu"``, ``"cuda"`` or ``"cuda:N"``.
    OutputScale : float
        Output resolution relative to the input, in (0, 1]; default 1.
        ``n' = max(2, round(n * OutputScale))`` per axis.
    OutputDimensions : (int, int, int)
        Explicit output dimensions (each >= 2); take precedence over ``OutputScale``.
        (0, 0, 0) (default) means "use OutputScale".
    InputComponent : int or None
        Component of a multi-component input array; -1 means the magnitude. Default
        ``None``: multi-component input is an error that says so.
    NaNPolicy : str
        ``"raise"`` (default) or ``"fill"`` (replace NaN/Inf by the smallest finite value).
    PassInputArrays : bool
        At full output resolution, also pass the input's point and cell arrays
        (shared, not copied). Default on.
    CacheSizeMB : float
        Memory budget of the per-time-step output cache; 0 disables it. Default 512.

    Notes
    -----
    Units: world units are the input image's (spacing, origin). Extinction is
    ``sigma_t = -ln(1 - alpha) / u`` in 1/world units; directional lights carry an
    irradiance, point lights an intensity (irradiance ``I / d**2``), both RGB.
    The input array is chosen with ``SetInputArrayToProcess(0, 0, 0, association,
    name)``; default the active point scalars. Cell arrays are averaged onto the
    points (``vtkCellDataToPointData``).
    """

    #: Whether :meth:`compute` needs at least one light (checked before it runs).
    requires_lights = True
    #: Whether :meth:`compute` runs warp kernels; if not, ``Device`` is not resolved (no warp
    #: import, no error for an absent GPU) and ``params.device`` is ``"cpu"``.
    uses_device = True
    #: What of the optical model, besides the opacity, its unit distance and the lights, the
    #: arrays of :meth:`compute` depend on: ``"color"`` (the colour transfer function),
    #: ``"albedo"``, ``"anisotropy"``. An edit of anything else does not recompute where
    #: results are reused (:attr:`reuses_results`, the ParaView plugin's memo).
    illumination_depends_on = frozenset({"color", "albedo", "anisotropy"})
    #: Whether the arrays computed for the same input data (object and MTime) and the same
    #: relevant settings may be reused, by any filter of the class in this process (a
    #: memo bounded like the time cache): for deterministic filters that keep no state of
    #: their own between executions.
    reuses_results = False

    def __init__(self) -> None:
        # vtkDataObject as input type so that any other input reaches RequestInformation
        # and gets an error that says how to resample, not VTK's generic type error.
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=1, inputType="vtkDataObject",
                                        nOutputPorts=1, outputType="vtkImageData")
        self._color_tf = None
        self._opacity_tf = None
        self._tf_links: dict = {}  # attribute -> (function, observer tag)
        self._tf_seen = (None, None)  # content of the transfer functions last executed with
        self._unit_distance = 0.0
        self._albedo = 0.9
        self._anisotropy = 0.0
        self._lights: list = [DirectionalLight((1.0, -1.0, -1.0))]
        self._device = "auto"
        self._output_scale = 1.0
        self._output_dimensions = (0, 0, 0)
        self._input_component = None
        self._nan_policy = "raise"
        self._pass_input_arrays = True
        self._cache = TimeStepCache(int(DEFAULT_CACHE_MB * 2**20))
        self._pending = None  # (key, cached output or None), from RequestUpdateExtent
        self._steps_seen: dict = {}  # (requested time, upstream MTime) -> step computed
        self._notes_given: set = set()  # notes already given (_deliver, _check_series_fits)
        self._distributed = bool(self.distributed_by_default)  # SetDistributed
        self._last_error: Exception | None = None
        self._interrupt: KeyboardInterrupt | None = None  # caught in RequestData, see module doc
        self.SetInputArrayToProcess(0, 0, 0, vtkDataObject.FIELD_ASSOCIATION_POINTS,
                                    vtkDataSetAttributes.SCALARS)

    # === what a subclass implements ===========================================================
    def compute(self, volume, params: IlluminationParameters) -> dict:
        """Compute the output arrays.

        Parameters
        ----------
        volume : vtkillum.core.volume.Volume
            The input at its own resolution, in world units.
        params : IlluminationParameters
            Optical parameters, lights, device, ``output_shape`` and ``progress``.

        Returns
        -------
        dict of str -> ndarray
            Arrays of shape ``output_shape`` or ``output_shape + (components,)``,
            indexed ``[i, j, k]``. The first becomes the active scalars.
        """
        raise NotImplementedError(f"{type(self).__name__} must implement compute(volume, params)")

    # === properties ===========================================================================
    def set_parameter(self, attribute: str, value) -> bool:
        """Set ``self.<attribute>`` and call ``Modified()`` only if the value changed.

        Subclasses use it for their own properties. Returns whether it changed. Waits for an
        update in flight in another thread (:data:`PIPELINE_LOCK`): that update computes
        with the old value, the next with the new one, never a mix.
        """
        with PIPELINE_LOCK:
            old = getattr(self, attribute)
            same = (np.array_equal(np.asarray(old), np.asarray(value))
                    if isinstance(value, (tuple, list, np.ndarray)) else old == value)
            if same and type(old) is type(value):
                return False
            setattr(self, attribute, value)
            self.Modified()
            return True

    def SetColorTransferFunction(self, function) -> None:
        if function is not None and not isinstance(function, vtkColorTransferFunction):
            raise TypeError("SetColorTransferFunction expects a vtkColorTransferFunction or None")
        self._observe("_color_tf", function)

    def GetColorTransferFunction(self):
        return self._color_tf

    def SetScalarOpacity(self, function) -> None:
        if function is not None and not isinstance(function, vtkPiecewiseFunction):
            raise TypeError("SetScalarOpacity expects a vtkPiecewiseFunction or None")
        self._observe("_opacity_tf", function)

    def GetScalarOpacity(self):
        return self._opacity_tf

    def SetTransferFunction(self, tf: TransferFunction) -> None:
        """Convenience: set both VTK functions from a core :class:`TransferFunction`."""
        from vtkillum.io.convert import transfer_function_to_vtk

        color_tf, opacity_tf = transfer_function_to_vtk(tf)
        with PIPELINE_LOCK:  # both or neither, for an update in another thread
            self.SetColorTransferFunction(color_tf)
            self.SetScalarOpacity(opacity_tf)

    def SetScalarOpacityUnitDistance(self, u: float) -> None:
        u = float(u)
        if not (np.isfinite(u) and u >= 0):
            raise ValueError(f"ScalarOpacityUnitDistance must be >= 0 (0: mean spacing), got {u}")
        self.set_parameter("_unit_distance", u)

    def GetScalarOpacityUnitDistance(self) -> float:
        return self._unit_distance

    def SetAlbedo(self, albedo: float) -> None:
        albedo = float(albedo)
        if not 0.0 <= albedo <= 1.0:
            raise ValueError(f"Albedo must lie in [0, 1], got {albedo}")
        self.set_parameter("_albedo", albedo)

    def GetAlbedo(self) -> float:
        return self._albedo

    def SetAnisotropy(self, g: float) -> None:
        g = float(g)
        if not -1.0 < g < 1.0:
            raise ValueError(f"Anisotropy (Henyey-Greenstein g) must lie in (-1, 1), got {g}")
        self.set_parameter("_anisotropy", g)

    def GetAnisotropy(self) -> float:
        return self._anisotropy

    def SetDevice(self, device: str) -> None:
        d = str(device).lower()
        if d not in DEVICES and not (d.startswith("cuda:") and d[5:].isdigit()):
            raise ValueError(f"Device must be one of {DEVICES} or 'cuda:N', got {device!r}")
        self.set_parameter("_device", d)

    def GetDevice(self) -> str:
        return self._device

    def SetOutputScale(self, scale: float) -> None:
        scale = float(scale)
        if not 0.0 < scale <= 1.0:
            raise ValueError(f"OutputScale must lie in (0, 1], got {scale}")
        self.set_parameter("_output_scale", scale)

    def GetOutputScale(self) -> float:
        return self._output_scale

    def SetOutputDimensions(self, nx, ny=None, nz=None) -> None:
        dims = tuple(int(n) for n in (nx if ny is None else (nx, ny, nz)))
        if len(dims) != 3 or not (dims == (0, 0, 0) or min(dims) >= 2):
            raise ValueError(f"OutputDimensions must be three integers >= 2, or (0, 0, 0) to "
                             f"use OutputScale; got {dims}")
        self.set_parameter("_output_dimensions", dims)

    def GetOutputDimensions(self) -> tuple:
        return self._output_dimensions

    def SetInputComponent(self, component) -> None:
        if component is not None:
            component = int(component)
            if component < -1:
                raise ValueError("InputComponent must be an index >= 0, -1 (magnitude) or None")
        self.set_parameter("_input_component", component)

    def GetInputComponent(self):
        return self._input_component

    def SetNaNPolicy(self, policy: str) -> None:
        if policy not in ("raise", "fill"):
            raise ValueError(f"NaNPolicy must be 'raise' or 'fill', got {policy!r}")
        self.set_parameter("_nan_policy", policy)

    def GetNaNPolicy(self) -> str:
        return self._nan_policy

    def SetPassInputArrays(self, on: bool) -> None:
        self.set_parameter("_pass_input_arrays", bool(on))

    def GetPassInputArrays(self) -> bool:
        return self._pass_input_arrays

    def SetCacheSizeMB(self, megabytes: float) -> None:
        """Memory budget of the time cache; shrinking evicts at once. Does not re-execute."""
        megabytes = float(megabytes)
        if not (np.isfinite(megabytes) and megabytes >= 0):
            raise ValueError(f"CacheSizeMB must be >= 0, got {megabytes}")
        self._cache.max_bytes = int(megabytes * 2**20)

    def GetCacheSizeMB(self) -> float:
        return self._cache.max_bytes / 2**20

    def GetCacheStatistics(self) -> CacheStatistics:
        """Hits, misses, evictions, invalidations, entries and bytes of the time cache."""
        return self._cache.statistics()

    def ClearCache(self) -> None:
        self._cache.clear()

    # --- lights ---------------------------------------------------------------------------------
    def AddDirectionalLight(self, direction, irradiance=(1.0, 1.0, 1.0)) -> int:
        """Add a light travelling along ``direction`` (world space); returns its index."""
        return self._add_light(DirectionalLight(direction, irradiance))

    def AddPointLight(self, position, intensity=(1.0, 1.0, 1.0)) -> int:
        """Add a point light at ``position`` (world space); returns its index."""
        return self._add_light(PointLight(position, intensity))

    def SetLight(self, index: int, kind: str, vector, rgb=(1.0, 1.0, 1.0)) -> None:
        """Replace light ``index``: ``kind`` "directional" (vector = travel direction,
        rgb = irradiance) or "point" (vector = position, rgb = intensity)."""
        self._check_light_index(index)
        light = _make_light(kind, vector, rgb)
        if light.to_dict() != self._lights[index].to_dict():
            self._lights[index] = light
            self.Modified()

    def SetLights(self, lights) -> None:
        """Replace all lights by core ``DirectionalLight``/``PointLight`` objects."""
        lights = list(lights)
        for light in lights:
            if not isinstance(light, (DirectionalLight, PointLight)):
                raise TypeError("expected DirectionalLight or PointLight, got "
                                f"{type(light).__name__}")
        if [x.to_dict() for x in lights] != [x.to_dict() for x in self._lights]:
            self._lights = lights
            self.Modified()

    def GetLight(self, index: int):
        self._check_light_index(index)
        return self._lights[index]

    def GetLights(self) -> list:
        return list(self._lights)

    def GetNumberOfLights(self) -> int:
        return len(self._lights)

    def RemoveLight(self, index: int) -> None:
        self._check_light_index(index)
        del self._lights[index]
        self.Modified()

    def RemoveAllLights(self) -> None:
        if self._lights:
            self._lights = []
            self.Modified()

    def _add_light(self, light) -> int:
        self._lights.append(light)
        self.Modified()
        return len(self._lights) - 1

    def _check_light_index(self, index: int) -> None:
        if not 0 <= int(index) < len(self._lights):
            raise IndexError(f"light index {index} out of range; the filter has "
                             f"{len(self._lights)} light(s)")

    # === Python convenience ======================================================================
    def SetInputData(self, data) -> None:
        """Use ``data`` (a vtkImageData or pyvista.ImageData) as input, like vtkImageAlgorithm."""
        self.SetInputDataObject(0, data)

    def execute(self, data=None, time: float | None = None):
        """Update (at ``time``) and return the output; raise the error if the update failed.

        Parameters
        ----------
        data : vtkDataObject, optional
            Set as input data first (``SetInputDataObject``).
        time : float, optional
            Time to request (``UpdateTimeStep``).
        """
        with PIPELINE_LOCK:  # the update and the output it returns belong together
            if data is not None:
                self.SetInputData(data)
            if self.GetNumberOfInputConnections(0) == 0:
                raise ValueError(f"{type(self).__name__} has no input; pass data or connect "
                                 "one")
            self._last_error = None
            # Update()'s return value differs between VTK versions (void in 9.2): check the
            # output. Both re-raise a KeyboardInterrupt caught in RequestData.
            if time is None:
                self.Update()
            else:
                self.UpdateTimeStep(float(time))
            if self._last_error is not None:
                raise self._last_error
            output = self.GetOutputDataObject(0)
            if output is None or output.GetNumberOfPoints() == 0:
                raise RuntimeError(f"{type(self).__name__}: the pipeline update failed "
                                   "(see VTK errors)")
            result = type(output)()  # a copy of its own: a later update does not change it
            result.ShallowCopy(output)
            result.GetInformation().Copy(output.GetInformation())
            return result

    # === Ctrl-C through the pipeline (see the module docstring) ==================================
    def Update(self, *args):
        """``vtkAlgorithm.Update``; re-raises a ``KeyboardInterrupt`` caught in ``RequestData``."""
        with PIPELINE_LOCK:
            self._interrupt = None
            result = super().Update(*args)
            self._reraise_interrupt()
            return result

    def UpdateTimeStep(self, *args):
        """``vtkAlgorithm.UpdateTimeStep``; re-raises a caught ``KeyboardInterrupt``."""
        with PIPELINE_LOCK:
            self._interrupt = None
            result = super().UpdateTimeStep(*args)
            self._reraise_interrupt()
            return result

    def UpdateWholeExtent(self, *args):
        """``vtkAlgorithm.UpdateWholeExtent``; re-raises a caught ``KeyboardInterrupt``."""
        with PIPELINE_LOCK:
            self._interrupt = None
            result = super().UpdateWholeExtent(*args)
            self._reraise_interrupt()
            return result

    def _reraise_interrupt(self) -> None:
        interrupt, self._interrupt = self._interrupt, None
        if interrupt is not None:
            raise interrupt

    def GetLastError(self) -> str | None:
        """Message of the error of the last failed execution, or ``None``."""
        return None if self._last_error is None else str(self._last_error)

    # === pipeline =============================================================================
    def RequestInformation(self, request, inInfo, outInfo):
        in_info = inInfo[0].GetInformationObject(0)
        out_info = outInfo.GetInformationObject(0)
        try:
            self._last_error = None
            check_image_data(in_info.Get(vtkDataObject.DATA_OBJECT()))
            whole = in_info.Get(SDDP.WHOLE_EXTENT())
            spacing = in_info.Get(vtkDataObject.SPACING()) or (1.0, 1.0, 1.0)
            origin = in_info.Get(vtkDataObject.ORIGIN()) or (0.0, 0.0, 0.0)
            direction = (in_info.Get(vtkDataObject.DIRECTION())
                         if in_info.Has(vtkDataObject.DIRECTION()) else np.eye(3).reshape(-1))
            extent, origin, spacing = self._output_grid(whole, origin, spacing, direction)
            out_info.Set(SDDP.WHOLE_EXTENT(), extent, 6)
            out_info.Set(vtkDataObject.ORIGIN(), origin, 3)
            out_info.Set(vtkDataObject.SPACING(), spacing, 3)
            out_info.Set(vtkDataObject.DIRECTION(), tuple(float(v) for v in direction), 9)
            for key in (SDDP.TIME_STEPS(), SDDP.TIME_RANGE()):
                if in_info.Has(key):
                    out_info.CopyEntry(in_info, key)
                else:
                    out_info.Remove(key)
            # The output's arrays are not the input's: drop the copied scalar metadata.
            out_info.Remove(vtkDataObject.POINT_DATA_VECTOR())
            return 1
        except Exception as err:  # reported through VTK, see _report
            self._report(err)
            return 0

    def RequestUpdateExtent(self, request, inInfo, outInfo):
        in_info = inInfo[0].GetInformationObject(0)
        out_info = outInfo.GetInformationObject(0)
        self._piece_mode = self._choose_piece_mode(in_info, out_info)
        if self._piece_mode[0] == "distributed":
            _, piece, pieces, _reason = self._piece_mode
            from vtkillum.core.parallel.decomposition import split_extent

            ghosts = int(self.distributed_ghost_levels(in_info))
            whole = in_info.Get(SDDP.WHOLE_EXTENT())
            # The piece plus its ghost levels, asked for as an extent (VTK's structured
            # request: with a piece number as well, a source splits the extent again).
            in_info.Set(SDDP.UPDATE_EXTENT(), split_extent(whole, piece, pieces, ghosts), 6)
            in_info.Set(SDDP.UPDATE_PIECE_NUMBER(), 0)
            in_info.Set(SDDP.UPDATE_NUMBER_OF_PIECES(), 1)
            in_info.Set(SDDP.UPDATE_NUMBER_OF_GHOST_LEVELS(), 0)
            self._pending = None  # pieces are not cached (see the module docstring)
            return 1
        if in_info.Has(SDDP.WHOLE_EXTENT()):
            in_info.Set(SDDP.UPDATE_EXTENT(), in_info.Get(SDDP.WHOLE_EXTENT()), 6)
        # Light crosses pieces: the whole volume as one piece, whatever piece the output is
        # (in parallel every rank computes it and keeps its own piece, see _deliver).
        in_info.Set(SDDP.UPDATE_PIECE_NUMBER(), 0)
        in_info.Set(SDDP.UPDATE_NUMBER_OF_PIECES(), 1)
        in_info.Set(SDDP.UPDATE_NUMBER_OF_GHOST_LEVELS(), 0)
        self._pending = None
        if self._cache.max_bytes == 0:
            return 1
        key = self._cache_key(out_info)
        self._cache.keep_only(lambda k: k[1:] == key[1:])
        cached = self._cache.lookup(key)
        self._pending = (key, cached)
        if cached is not None:
            self._request_current_input(in_info)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        out_info = outInfo.GetInformationObject(0)
        output = vtkImageData.GetData(out_info)
        key, cached = self._pending if self._pending is not None else (None, None)
        self._pending = None
        try:
            self._last_error = None
            mode = getattr(self, "_piece_mode", ("whole",))
            if mode[0] == "distributed" and cached is None:
                in_info = inInfo[0].GetInformationObject(0)
                image = in_info.Get(vtkDataObject.DATA_OBJECT())
                self._checked_time(image, in_info, out_info)
                piece_output = self._execute_piece(image, in_info, out_info, mode[1], mode[2])
                self._deliver_piece(output, piece_output, out_info, mode[1], mode[2])
                self.UpdateProgress(1.0)
                return 1
            if cached is None:
                in_info = inInfo[0].GetInformationObject(0)
                image = in_info.Get(vtkDataObject.DATA_OBJECT())
                requested = self._checked_time(image, in_info, out_info)
                cached = self._execute(image, out_info)
                if key is not None:
                    self._store(key, requested, cached, in_info)
            self._deliver(output, cached, out_info)
            info = cached.GetInformation()
            if info.Has(vtkDataObject.DATA_TIME_STEP()):
                output.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(),
                                            info.Get(vtkDataObject.DATA_TIME_STEP()))
            self.UpdateProgress(1.0)
            return 1
        except KeyboardInterrupt as interrupt:  # VTK would swallow it: see the module docstring
            output.Initialize()
            self._interrupt = interrupt
            self._last_error = RuntimeError("interrupted (KeyboardInterrupt); the output is "
                                            "empty until the next update")
            self._show_error(str(self._last_error))
            return 0  # a failed request: the next update executes again
        except Exception as err:  # reported through VTK, see _report
            output.Initialize()
            self._report(err)
            # The error is reported (ErrorEvent / output window, GetLastError, execute()
            # raises it) and the output is empty; the request itself succeeds. A failed
            # request (0) left ParaView's representation stuck on its last data: after a bad
            # property value was corrected the view never showed new illumination again
            # (tests/plugin/test_pvbatch.py::test_view_recovers_after_a_bad_value).
            return 1

    # === internals ==============================================================================
    def _deliver(self, output, whole, out_info) -> None:
        """Copy ``whole`` (the output for the whole volume) into ``output``, cut to the piece
        the pipeline asked for.

        In a parallel pipeline (ParaView under MPI: ``UPDATE_NUMBER_OF_PIECES`` > 1) each
        rank asks for its own piece; the filter computed the whole volume (shadows and
        scattered light cross pieces), so every rank holds the same result as one process
        and keeps its piece of it (ghost levels, if asked for, marked in ``vtkGhostType``),
        and the pieces composite without a seam. Memory and compute are those of the whole
        volume on every rank: the simplest correct parallel mode.
        """
        pieces = out_info.Get(SDDP.UPDATE_NUMBER_OF_PIECES()) \
            if out_info.Has(SDDP.UPDATE_NUMBER_OF_PIECES()) else 1
        if pieces <= 1:
            output.ShallowCopy(whole)
            return
        piece = out_info.Get(SDDP.UPDATE_PIECE_NUMBER())
        ghosts = out_info.Get(SDDP.UPDATE_NUMBER_OF_GHOST_LEVELS()) \
            if out_info.Has(SDDP.UPDATE_NUMBER_OF_GHOST_LEVELS()) else 0
        extent, owned = piece_extents(whole.GetExtent(), piece, pieces, ghosts)
        output.ShallowCopy(whole)
        output.Crop(extent)
        if ghosts and extent != owned:
            output.GenerateGhostArray(list(owned))
        mode = getattr(self, "_piece_mode", ("whole", piece, pieces, None))
        reason = mode[3] if len(mode) > 3 else None
        message = (f"{self._label()}: piece {piece + 1} of {pieces}: illumination computed on "
                   "the whole volume on this rank and cut to its piece (mode: whole volume on "
                   "every rank" + (f"; not distributed: {reason}" if reason else "") + ")")
        if message not in self._notes_given:  # once per piece layout, not per update
            self._notes_given.add(message)
            vtkOutputWindow.GetInstance().DisplayText(message + "\n")

    # --- distributed mode (issue 36) -----------------------------------------------------------
    def compute_piece(self, volume, params, piece):
        """This rank's piece of the illumination, computed across MPI ranks.

        Implemented by filters with a distributed core; the base class has none (mode 1).
        ``volume`` holds the input points ``piece.data_extent`` (the piece plus the ghost
        levels the input delivered), in canonical units like :meth:`compute`'s; ``piece``
        is a :class:`PieceRequest`. Returns the output arrays on ``piece.extent``'s points.
        """
        raise NotImplementedError(f"{type(self).__name__} has no distributed core: its "
                                  "distributed_unsupported() must name why (mode 1)")

    def distributed_ghost_levels(self, in_info=None) -> int:
        """Ghost levels of the input the distributed method needs around its piece."""
        return 0

    def distributed_unsupported(self) -> str | None:
        """Why this filter runs mode 1 under MPI (None: it can run distributed).

        The default: filters without :meth:`compute_piece` say what a distributed version
        would need (:attr:`distributed_needs`).
        """
        for cls in type(self).__mro__:  # the method's own compute_piece, past wrappers
            method = cls.__dict__.get("compute_piece")
            if method is not None and not getattr(method, "wraps_compute_piece", False):
                return self.distributed_needs if cls is IlluminationFilterBase else None
        return self.distributed_needs

    #: What a distributed version of the method would need (said in mode 1's log line).
    distributed_needs = "this method has no distributed version"

    #: The ``Distributed`` property's default: on for filters whose distributed core gives
    #: the one-rank result (light transmittance: bit-identical; ambient extinction without
    #: the radiance cache: within float rounding), off elsewhere.
    distributed_by_default = False
    #: True for a filter whose distributed core computes the pieces of its own output grid
    #: (convection–diffusion's light grid), so an output grid other than the data's is fine.
    distributed_on_output_grid = False

    def SetDistributed(self, on: bool) -> None:
        """Use the distributed core under MPI when the filter has one.

        The default is :attr:`distributed_by_default` (on for light transmittance, whose
        distributed march is the one-rank march, ``docs/parallel.md``). Off: mode 1 (the
        whole volume on every rank), which gives the one-rank result too, at the whole
        volume's memory and time on every rank.
        """
        self.set_parameter("_distributed", bool(on))

    def GetDistributed(self) -> bool:
        return self._distributed

    def _choose_piece_mode(self, in_info, out_info) -> tuple:
        """``(mode, piece, pieces, reason)``: ``"distributed"`` or ``"whole"`` (mode 1)."""
        pieces = out_info.Get(SDDP.UPDATE_NUMBER_OF_PIECES()) \
            if out_info.Has(SDDP.UPDATE_NUMBER_OF_PIECES()) else 1
        piece = out_info.Get(SDDP.UPDATE_PIECE_NUMBER()) \
            if out_info.Has(SDDP.UPDATE_PIECE_NUMBER()) else 0
        if pieces <= 1:
            return ("whole", piece, pieces, None)
        reason = self.distributed_unsupported()
        if reason is None and not self.GetDistributed():
            reason = "the Distributed property is off"
        if reason is None and not self.distributed_on_output_grid and \
                in_info.Has(SDDP.WHOLE_EXTENT()):
            whole = in_info.Get(SDDP.WHOLE_EXTENT())
            dims = tuple(int(whole[2 * a + 1] - whole[2 * a] + 1) for a in range(3))
            if tuple(self.output_shape(dims)) != dims:
                reason = ("the output grid differs from the input grid (OutputScale / "
                          "OutputDimensions); the distributed methods compute on the data grid")
        if reason is None:
            from vtkillum.core.parallel.comm import mpi

            MPI = mpi()
            if MPI is None:
                reason = "mpi4py is not installed (pip install 'vtkillum[mpi]')"
            elif MPI.COMM_WORLD.Get_size() != pieces:
                reason = (f"{pieces} pieces on {MPI.COMM_WORLD.Get_size()} MPI ranks; the "
                          "distributed core needs one piece per rank")
        return ("whole" if reason else "distributed", piece, pieces, reason)

    def _execute_piece(self, image, in_info, out_info, piece: int, pieces: int):
        """Compute this rank's piece with the distributed core (a new vtkImageData on the
        piece's extent, without ghosts)."""
        from vtkillum.core.parallel.comm import rank_device, world
        from vtkillum.core.parallel.decomposition import split_extent

        check_image_data(image)
        self.UpdateProgress(0.0)
        whole = tuple(in_info.Get(SDDP.WHOLE_EXTENT()))
        extent = split_extent(whole, piece, pieces)
        data_extent = tuple(image.GetExtent())
        if any(data_extent[2 * a] > extent[2 * a] or data_extent[2 * a + 1] < extent[2 * a + 1]
               for a in range(3)):
            raise ValueError(f"piece {piece + 1} of {pieces}: the input delivered extent "
                             f"{data_extent}, which does not hold the piece {extent}")
        ghosted = split_extent(whole, piece, pieces, self.distributed_ghost_levels(in_info))
        keep = tuple(max(data_extent[i], ghosted[i]) if i % 2 == 0
                     else min(data_extent[i], ghosted[i]) for i in range(6))
        if keep != data_extent:
            cropped = vtkImageData()
            cropped.DeepCopy(image)
            cropped.Crop(keep)
            image = cropped
        name, association = self._selected_array(image)
        component = "magnitude" if self._input_component == -1 else self._input_component
        volume = volume_from_image_data(image, name, component, self._nan_policy, association)
        if self.requires_lights and not self._lights:
            raise ValueError(f"{type(self).__name__} has no lights; add one with "
                             "AddDirectionalLight(direction, irradiance) or AddPointLight(...)")
        dims = tuple(int(extent[2 * a + 1] - extent[2 * a] + 1) for a in range(3))
        device = rank_device(None, self._device if self.uses_device else "cpu")
        # What one rank derives from the whole volume, derived the same way here: its first
        # point (canonical units, point lights), its data range (the default opacity ramp).
        from vtkillum.io.convert import first_point

        first = first_point(image.GetOrigin(), whole, volume.spacing, volume.direction)
        ranges = world().allgather(tuple(float(v) for v in volume.value_range))
        whole_like = types.SimpleNamespace(
            spacing=volume.spacing, origin=first,
            value_range=(min(r[0] for r in ranges), max(r[1] for r in ranges)))
        params = IlluminationParameters(
            transfer_function=self._transfer_function(whole_like),
            unit_distance=self._unit_distance or volume.mean_spacing(),
            albedo=self._albedo, anisotropy=self._anisotropy, lights=list(self._lights),
            device=device, output_shape=dims,
            progress=lambda fraction: self.UpdateProgress(float(np.clip(fraction, 0.0, 1.0))),
        )
        units = WorldUnits.for_volume(whole_like)
        request = PieceRequest(piece, pieces, extent, whole, keep, units.to_point(first))
        inside = dataclasses.replace(params, unit_distance=units.to_length(params.unit_distance),
                                     lights=units.lights(params.lights, volume), units=units)
        with units.explained():
            arrays = self.compute_piece(units.volume(volume), inside, request)
        piece_image = vtkImageData()
        piece_image.ShallowCopy(image)
        if keep != extent:
            piece_image.Crop(extent)
        output = image_like(piece_image)
        if self._pass_input_arrays:
            pass_arrays(piece_image, output)
        return self._finish_arrays(output, arrays, dims, "compute_piece", params.lights,
                                   image, out_info)

    def _finish_arrays(self, output, arrays: dict, shape, where: str, lights, image, out_info):
        """``output`` with ``arrays`` (float32, the first active), the lights and the time."""
        for index, (array_name, values) in enumerate(arrays.items()):
            values = np.asarray(values)
            if values.dtype.kind == "f":
                values = values.astype(np.float32, copy=False)
            if values.shape[:3] != tuple(shape):
                raise ValueError(f"{type(self).__name__}.{where} returned {array_name!r} with "
                                 f"shape {values.shape}; expected {tuple(shape)} (+ components)")
            add_point_array(output, array_name, values, set_active=index == 0)
        if self.requires_lights:
            add_lights_field(output, lights)
        time = self._input_time(image, out_info)
        if time is not None:
            output.GetInformation().Set(vtkDataObject.DATA_TIME_STEP(), time)
        return output

    def _deliver_piece(self, output, piece_output, out_info, piece: int, pieces: int) -> None:
        """Output the piece computed by :meth:`_execute_piece`, widened by the ghost levels
        asked for downstream (filled from the neighbouring ranks, marked as ghosts)."""
        from vtkillum.core.parallel.decomposition import Decomposition
        from vtkillum.core.parallel.halo import halo_exchange
        from vtkillum.io.convert import point_array

        ghosts = out_info.Get(SDDP.UPDATE_NUMBER_OF_GHOST_LEVELS()) \
            if out_info.Has(SDDP.UPDATE_NUMBER_OF_GHOST_LEVELS()) else 0
        whole = tuple(out_info.Get(SDDP.WHOLE_EXTENT()))
        decomposition = Decomposition.of(whole, pieces)
        owned = decomposition.extents[piece]
        extent = decomposition.ghosted(piece, ghosts) if ghosts else owned
        if extent == owned:
            output.ShallowCopy(piece_output)
        else:
            wide = image_like(piece_output)
            wide.SetExtent(*extent)
            pd = piece_output.GetPointData()
            active = pd.GetScalars().GetName() if pd.GetScalars() is not None else None
            for i in range(pd.GetNumberOfArrays()):
                name = pd.GetArrayName(i)
                values = halo_exchange(point_array(piece_output, name), decomposition,
                                       piece, ghosts)
                add_point_array(wide, name, values, set_active=name == active)
            wide.GetFieldData().ShallowCopy(piece_output.GetFieldData())
            wide.GetInformation().Copy(piece_output.GetInformation())
            output.ShallowCopy(wide)
            output.GenerateGhostArray(list(owned))
        message = (f"{self._label()}: piece {piece + 1} of {pieces}: illumination computed "
                   "distributed across the MPI ranks on this rank's piece (mode: distributed)")
        if message not in self._notes_given:
            self._notes_given.add(message)
            vtkOutputWindow.GetInstance().DisplayText(message + "\n")

    def _checked_time(self, image, in_info, out_info):
        """The time requested of this update (None: not a time series); raises when the input
        delivered another of its own time steps than the one requested.

        A request between two steps gets the step the input delivers (a reader's own rule;
        VTK's readers take the step at or before it), and the output's ``DATA_TIME_STEP``
        says which. A request for one of the input's steps must get exactly that step:
        anything else means the step is missing or unreadable, or another thread updated
        the same input, and the illumination of another step must not be passed off (or
        cached) as this one's.
        """
        if not (out_info.Has(SDDP.UPDATE_TIME_STEP()) and out_info.Has(SDDP.TIME_RANGE())):
            return None
        requested = out_info.Get(SDDP.UPDATE_TIME_STEP())
        info = image.GetInformation() if image is not None else None
        if info is None or not info.Has(vtkDataObject.DATA_TIME_STEP()):
            return requested
        delivered = info.Get(vtkDataObject.DATA_TIME_STEP())
        steps = in_info.Get(SDDP.TIME_STEPS()) if in_info.Has(SDDP.TIME_STEPS()) else ()
        scale = max([abs(v) for v in steps] + [abs(requested), 1.0])
        tolerance = 1e-12 * scale
        if abs(delivered - requested) > tolerance and \
                any(abs(step - requested) <= tolerance for step in steps):
            shown = ", ".join(f"{step:g}" for step in steps[:12]) + \
                (f", ... ({len(steps)} steps)" if len(steps) > 12 else "")
            raise ValueError(
                f"time {requested:g} was requested, one of the input's time steps ({shown}), "
                f"but the input delivered time {delivered:g}: that step is missing or could "
                "not be read (or another thread updated the same input; update vtkillum "
                "filters from one thread at a time, or through execute()/Update(), which "
                "hold vtkillum.filters.base.PIPELINE_LOCK)")
        return requested

    def _store(self, key, requested, output, in_info) -> None:
        """Cache ``output`` under the time it was computed for (its ``DATA_TIME_STEP``), never
        the time requested, and only if no parameter changed while it was computed."""
        if self.GetMTime() != key[2]:  # edited meanwhile (another thread): not this key's
            return
        info = output.GetInformation()
        computed = info.Get(vtkDataObject.DATA_TIME_STEP()) \
            if key[0] is not None and info.Has(vtkDataObject.DATA_TIME_STEP()) else key[0]
        if requested is not None and computed != requested:
            self._steps_seen = {k: v for k, v in self._steps_seen.items() if k[1] == key[1]}
            self._steps_seen[(requested, key[1])] = computed
        nbytes = output.GetActualMemorySize() * 1024
        self._cache.store((computed, key[1], key[2]), output, nbytes)
        self._check_series_fits(in_info, nbytes)

    def _check_series_fits(self, in_info, nbytes: int) -> None:
        """Say once (per series length, output size and budget) when the time cache cannot
        hold every step of the input's time series, and what CacheSizeMB would."""
        steps = in_info.Get(SDDP.TIME_STEPS()) if in_info.Has(SDDP.TIME_STEPS()) else None
        n = len(steps) if steps is not None else 0
        budget = self._cache.max_bytes
        if n < 2 or nbytes <= 0 or n * nbytes <= budget:
            return
        mb = nbytes / 2**20
        message = (f"{self._label()}: CacheSizeMB {budget / 2**20:.0f} keeps {budget // nbytes} "
                   f"of the {n} time steps ({mb:.0f} MB each): stepping back to a step it "
                   f"dropped computes it again. CacheSizeMB {np.ceil(n * mb):.0f} keeps them "
                   "all.")
        if message not in self._notes_given:
            self._notes_given.add(message)
            vtkOutputWindow.GetInstance().DisplayText(message + "\n")

    def _label(self) -> str:
        return getattr(self, "paraview_label", type(self).__name__)

    def _execute(self, image, out_info) -> vtkImageData:
        """Convert, compute and assemble one output (a new vtkImageData)."""
        check_image_data(image)
        self.UpdateProgress(0.0)
        name, association = self._selected_array(image)
        component = self._input_component
        if component == -1:
            component = "magnitude"
        volume = volume_from_image_data(image, name, component, self._nan_policy, association)
        if self.requires_lights and not self._lights:
            raise ValueError(f"{type(self).__name__} has no lights; add one with "
                             "AddDirectionalLight(direction, irradiance) or AddPointLight(...)")
        shape = self.output_shape(volume.dims)
        params = IlluminationParameters(
            transfer_function=self._transfer_function(volume),
            unit_distance=self._unit_distance or volume.mean_spacing(),
            albedo=self._albedo, anisotropy=self._anisotropy, lights=list(self._lights),
            device=self._resolved_device(), output_shape=shape,
            progress=lambda fraction: self.UpdateProgress(float(np.clip(fraction, 0.0, 1.0))),
        )
        memo_key = self._results_key(image, name, association, component, params) \
            if self.reuses_results else None
        arrays = _RESULTS.lookup(memo_key) if memo_key is not None else None
        if arrays is None:
            arrays = self._compute_canonical(volume, params)
            if memo_key is not None and isinstance(arrays, dict):
                _RESULTS.store(memo_key, dict(arrays),
                               sum(np.asarray(v).nbytes for v in arrays.values()))
        if not isinstance(arrays, dict) or not arrays:
            raise TypeError(f"{type(self).__name__}.compute must return a non-empty dict of arrays")

        same = shape == volume.dims
        output = image_like(image) if same else image_like(volume, shape)
        if same and self._pass_input_arrays:
            pass_arrays(image, output)
        return self._finish_arrays(output, arrays, shape, "compute", params.lights, image,
                                   out_info)

    def relevant_model(self, params) -> tuple:
        """What of ``params`` the illumination depends on (:attr:`illumination_depends_on`):
        the opacity always, the colours, albedo and anisotropy only where they matter."""
        tf = params.transfer_function
        needs = self.illumination_depends_on
        if "color" in needs:
            shape = (np.asarray(tf.scalars).tobytes(), np.asarray(tf.opacity).tobytes(),
                     np.asarray(tf.colors).tobytes())
        else:  # the opacity curve alone (colour control points add points on its lines)
            shape = _curve(tf.scalars, tf.opacity)
        return (shape,
                float(params.unit_distance),
                float(params.albedo) if "albedo" in needs else None,
                float(params.anisotropy) if "anisotropy" in needs else None,
                tuple(str(light.to_dict()) for light in params.lights), params.device,
                tuple(params.output_shape))

    def _results_key(self, image, name, association, component, params) -> tuple:
        """The memo key of an execution: the class, the input (object, data MTime, the array
        and how it is read), the relevant model and every plain setting of the filter."""
        own = tuple(sorted((k, v) for k, v in vars(self).items()
                           if k.startswith("_") and k not in _NOT_SETTINGS
                           and isinstance(v, (bool, int, float, str, tuple))))
        return (type(self), image.GetAddressAsString("vtkObject"), image.GetMTime(), name,
                association, component, self._nan_policy, self.relevant_model(params), own)

    def _compute_canonical(self, volume, params) -> dict:
        """:meth:`compute` in canonical units (see :class:`IlluminationParameters`)."""
        units = WorldUnits.for_volume(volume)
        inside = dataclasses.replace(params, unit_distance=units.to_length(params.unit_distance),
                                     lights=units.lights(params.lights, volume), units=units)
        with units.explained():
            return self.compute(units.volume(volume), inside)

    def _resolved_device(self) -> str:
        if not self.uses_device:
            return "cpu"
        from vtkillum.core.device import resolve_device  # imports warp: only when needed

        return resolve_device(self._device)

    def _transfer_function(self, volume) -> TransferFunction:
        if self._opacity_tf is not None and self._opacity_tf.GetSize() > 0:
            return transfer_function_from_vtk(self._color_tf, self._opacity_tf)
        lo, hi = volume.value_range
        ramp = TransferFunction.ramp(lo, hi if hi > lo else lo + 1.0, 0.5)
        if self._color_tf is None or self._color_tf.GetSize() == 0:
            return ramp
        from vtkillum.io.convert import transfer_function_to_vtk

        return transfer_function_from_vtk(self._color_tf, transfer_function_to_vtk(ramp)[1])

    def _selected_array(self, image):
        """(name or None for the default choice, association) of the input array to process."""
        info = self.GetInputArrayInformation(0)
        association = {vtkDataObject.FIELD_ASSOCIATION_POINTS: "points",
                       vtkDataObject.FIELD_ASSOCIATION_CELLS: "cells"}.get(
            info.Get(vtkDataObject.FIELD_ASSOCIATION()), None)
        if info.Has(vtkDataObject.FIELD_NAME()):
            return info.Get(vtkDataObject.FIELD_NAME()), association
        # An attribute (e.g. SCALARS): the active array of that association, if any.
        data = image.GetCellData() if association == "cells" else image.GetPointData()
        active = data.GetAttribute(info.Get(vtkDataObject.FIELD_ATTRIBUTE_TYPE()))
        if active is not None and association == "cells":
            return active.GetName(), association
        return None, None  # active point scalars, else the documented fallbacks

    def output_shape(self, dims) -> tuple:
        """Points of the output grid for input dimensions ``dims`` (subclasses may override)."""
        if self._output_dimensions != (0, 0, 0):
            return tuple(self._output_dimensions)
        if self._output_scale == 1.0:
            return tuple(int(n) for n in dims)
        return tuple(max(2, int(round(n * self._output_scale))) for n in dims)

    def _output_grid(self, whole, origin, spacing, direction):
        """Output (whole extent, origin, spacing) for an input grid, as the data will have."""
        dims = np.array(whole[1::2]) - np.array(whole[0::2]) + 1
        if np.any(dims < 1):
            raise ValueError(f"the input image is empty (whole extent {tuple(whole)}); update "
                             "the algorithm that produces it or check the reader's file name")
        shape = self.output_shape(dims)
        if shape == tuple(int(n) for n in dims):
            return tuple(whole), tuple(origin), tuple(spacing)
        if np.any(dims < 2):
            raise ValueError(f"input dimensions {tuple(dims)}: at least 2 points per axis are "
                             "needed for a volume")
        d = np.asarray(direction, dtype=np.float64).reshape(3, 3)
        start = first_point(origin, whole, spacing, d)
        new_spacing = resampled_geometry(dims, spacing, shape)
        extent = (0, shape[0] - 1, 0, shape[1] - 1, 0, shape[2] - 1)
        return extent, tuple(float(v) for v in start), tuple(float(v) for v in new_spacing)

    def _cache_key(self, out_info) -> tuple:
        # Without TIME_RANGE the input is static: every requested time gives the same output.
        temporal = out_info.Has(SDDP.UPDATE_TIME_STEP()) and out_info.Has(SDDP.TIME_RANGE())
        time = out_info.Get(SDDP.UPDATE_TIME_STEP()) if temporal else None
        upstream = self.GetInputAlgorithm(0, 0).GetExecutive().GetPipelineMTime() \
            if self.GetNumberOfInputConnections(0) else 0
        # Entries are keyed by the step computed: a request between steps looks up the step
        # the input delivered for it before (_store), else it misses.
        time = self._steps_seen.get((time, upstream), time)
        return (time, upstream, self.GetMTime())

    @staticmethod
    def _request_current_input(in_info) -> None:
        """Ask the input for the time step it already holds, so that it does not execute."""
        if not in_info.Has(SDDP.UPDATE_TIME_STEP()):
            return
        data = in_info.Get(vtkDataObject.DATA_OBJECT())
        if data is not None and data.GetInformation().Has(vtkDataObject.DATA_TIME_STEP()):
            in_info.Set(SDDP.UPDATE_TIME_STEP(),
                        data.GetInformation().Get(vtkDataObject.DATA_TIME_STEP()))
        else:
            in_info.Remove(SDDP.UPDATE_TIME_STEP())

    @staticmethod
    def _input_time(image, out_info):
        info = image.GetInformation()
        if info.Has(vtkDataObject.DATA_TIME_STEP()):
            return info.Get(vtkDataObject.DATA_TIME_STEP())
        if out_info.Has(SDDP.UPDATE_TIME_STEP()):
            return out_info.Get(SDDP.UPDATE_TIME_STEP())
        return None

    def _observe(self, attribute: str, function) -> None:
        """Hold a transfer function and re-execute (Modified) whenever it is edited.

        The observer holds only a vtkWeakReference to the filter, so the function does
        not keep the filter alive (no reference cycle through the observer). It is
        removed when the function is replaced, or at the function's first edit after
        the filter is gone.
        """
        with PIPELINE_LOCK:
            self._observe_locked(attribute, function)

    def _observe_locked(self, attribute: str, function) -> None:
        old = getattr(self, attribute)
        if old is function:
            return
        link = self._tf_links.pop(attribute, None)
        if link is not None:
            link[0].RemoveObserver(link[1])
        setattr(self, attribute, function)
        if function is not None:
            ref = vtkWeakReference()
            ref.Set(self)
            tag = []

            def modified(caller, event, ref=ref, tag=tag):
                target = ref.Get()
                if target is not None:
                    target._transfer_function_edited()
                elif tag:
                    caller.RemoveObserver(tag.pop())

            tag.append(function.AddObserver("ModifiedEvent", modified))
            self._tf_links[attribute] = (function, tag[0])
        self._transfer_function_edited()

    def _transfer_function_edited(self) -> None:
        """Re-execute when the content of a transfer function changed, not on every Modified
        (VTK fires it also for edits that set what is already there)."""
        seen = (_signature(self._color_tf), _signature(self._opacity_tf))
        if seen != self._tf_seen:
            self._tf_seen = seen
            self.Modified()

    def _report(self, err: Exception) -> None:
        """Record ``err`` and show it the VTK way (ErrorEvent observers or the output window)."""
        self._last_error = err
        self._show_error(str(err))

    def _show_error(self, text: str) -> None:
        message = f"{type(self).__name__}: {text}"
        if self.HasObserver("ErrorEvent"):
            self.InvokeEvent("ErrorEvent", message)
        else:
            vtkOutputWindow.GetInstance().DisplayErrorText(message + "\n")


def _curve(x, y) -> tuple:
    """A piecewise-linear curve through ``(x, y)`` without the points that lie on the line
    between their neighbours (so the same curve has one key however it is sampled)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    keep = [0]
    for i in range(1, len(x) - 1):
        a = keep[-1]
        t = (x[i] - x[a]) / (x[i + 1] - x[a]) if x[i + 1] != x[a] else 0.0
        if abs(y[a] + t * (y[i + 1] - y[a]) - y[i]) > 1e-12 * (1.0 + abs(y[i])):
            keep.append(i)
    if len(x) > 1:
        keep.append(len(x) - 1)
    return (x[keep].tobytes(), y[keep].tobytes())


def _signature(function) -> tuple | None:
    """The content of a VTK colour or opacity transfer function (None for none)."""
    if function is None:
        return None
    width = 6 if isinstance(function, vtkColorTransferFunction) else 4
    nodes = []
    for i in range(function.GetSize()):
        node = [0.0] * width
        function.GetNodeValue(i, node)
        nodes.append(tuple(node))
    extra = ()
    if width == 6:
        extra = (function.GetColorSpace(), function.GetScale(), function.GetClamping())
    return (tuple(nodes), extra, function.GetClamping() if width == 4 else None)


@dataclass(frozen=True)
class PieceRequest:
    """What a distributed :meth:`IlluminationFilterBase.compute_piece` is asked for.

    ``piece`` of ``pieces`` (this rank's, one per MPI rank), its ``extent`` (VTK's split,
    no ghosts; the arrays returned cover it), the input's ``whole`` extent, the
    ``data_extent`` the volume holds (the piece plus the ghost levels delivered) and the
    whole volume's first point ``origin`` in the canonical units the volume is in (the
    one-rank volume's origin, bit for bit; None when not known).
    """

    piece: int
    pieces: int
    extent: tuple
    whole: tuple
    data_extent: tuple
    origin: object = None


def piece_extents(whole, piece: int, pieces: int, ghost_levels: int = 0) -> tuple:
    """(extent with ghost levels, extent owned) of ``piece`` of ``pieces`` of ``whole``.

    Split as VTK's default extent translator splits structured data (blocks along the
    longest axes), so the pieces tile the whole extent sharing their boundary points.
    """
    from vtkmodules.vtkCommonExecutionModel import vtkExtentTranslator

    translator = vtkExtentTranslator()
    result = []
    for ghosts in (ghost_levels, 0):
        translator.SetWholeExtent(*whole)
        translator.SetPiece(int(piece))
        translator.SetNumberOfPieces(int(pieces))
        translator.SetGhostLevel(int(ghosts))
        translator.PieceToExtent()
        result.append(tuple(translator.GetExtent()))
    return result[0], result[1]


def _make_light(kind: str, vector, rgb):
    if kind == "directional":
        return DirectionalLight(vector, rgb)
    if kind == "point":
        return PointLight(vector, rgb)
    raise ValueError(f"light kind must be 'directional' or 'point', got {kind!r}")
