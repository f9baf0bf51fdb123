"""Illumination rendered per sample in ParaView's render view.

ParaView 5.11's volume representation draws a ``vtkPVLODVolume`` whose inner
``vtkVolume`` (inside a ``vtkLODProp3D``) and ``vtkMultiBlockVolumeMapper`` a
Python plugin cannot reach: neither shader replacements nor textures can be
given to them (tried: the shader property of the outer volume is ignored, the
mapper fires no ``UpdateShaderEvent``). What does work is to let ParaView keep
its representation (colour map, opacity function, unit distance, shading,
visibility, transform, time, state files, the Color Map Editor) and to draw, in
its place in the same renderer, a ``vtkVolume`` of our own that

* shares the representation's ``vtkVolumeProperty`` (so every edit of the colour
  map, opacity, unit distance or shading is live),
* renders the very data ParaView delivered to the representation (its mapper's
  input, each time step), the array the display colours by,
* runs VTK's GPU ray caster with the composite step replaced
  (:mod:`.shaders`): per sample it applies the per-light transmittance and the
  scattered fluence of the filter output (3D textures on the data's grid,
  trilinear), the Henyey-Greenstein phase function towards the camera, the
  lights (``vtkillum_lights``) and, when *Shade* is on, the Phong factor.

:class:`ViewHook` does this for one render view, at the start of each of its
renders (after ParaView has prepared its representations): every visible volume
representation whose data carry illumination (a vtkIllum filter's output, or a
file written from one) and that colours by the illuminated array is swapped for
an :class:`IlluminatedVolume`; when that stops being so (another array, another
representation, the filter deleted), ParaView's own volume is put back.

Limits: builtin sessions only (the GUI without a server, pvpython, pvbatch); with
a remote server the client has no data and ParaView's plain volume is drawn (use
the filters' ``OutputRGBA``). Composite blending, point data, at most
:data:`~.shaders.MAX_LIGHTS` lights; ParaView's interactive LOD (outline while
rotating very large data) does not apply to the swapped volume.
"""

from __future__ import annotations

import numpy as np
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonCore import VTK_FLOAT, vtkFloatArray, vtkWeakReference
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkRenderingCore import vtkVolume
from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject
from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkOpenGLGPUVolumeRayCastMapper

from vtkillum_paraview.glue import (
    FLUENCE,
    LIGHTS_FIELD,
    RENDER_FIELD,
    SCALARS_FIELD,
    SCATTERED,
    TRANSMITTANCE,
)
from vtkillum_paraview.shaders import (
    LATE_DEC,
    LIGHT_STRIDE,
    MAX_LIGHTS,
    SHADING_DEC,
    SHADING_IMPL,
    UNIFORMS_DEC,
)

_views: dict = {}  # view global id -> ViewHook

#: Light-grid cells marched exactly towards each light before the transmittance grid is
#: read (``vtkillum.core.raycast``'s ``near_cells``).
NEAR_CELLS = 2.0

#: Jitter the rays' start per pixel (VTK's ``UseJittering``): thin, dense layers (a skull
#: under a narrow opacity peak) then show fine noise instead of the concentric "wood-grain"
#: rings that ParaView's own volume rendering shows there. False: sampled exactly as
#: ParaView's volume mapper (the tests compare pictures that way).
JITTER = True


#: Outcome of the one-time check of whether the render-view illumination works here:
#: None until it ran, "" when it works, else the reason it does not (:func:`enabled`).
_verdict: list = []


def enabled() -> bool:
    """Whether illumination is drawn in render views here.

    Decided once per process, at run time: the illuminated volume must compile and
    draw correctly in this ParaView's VTK (:func:`.probe.self_test`), and the render
    view must be ParaView's only process (with several MPI ranks each rank renders its
    own piece, and only this one could be swapped: half the picture would be lit).
    Otherwise ParaView's own volume is drawn and one message says why and what to do.
    ``VTKILLUM_PARAVIEW_DISPLAY=0`` switches it off (ParaView's own volume, e.g. to
    compare), ``=1`` on without the self-test.
    """
    import os

    choice = os.environ.get("VTKILLUM_PARAVIEW_DISPLAY", "").strip()
    if choice in ("0", "1"):
        return choice == "1"
    if not _verdict:
        reason = _parallel_reason()
        if reason is None:
            from vtkillum_paraview.probe import self_test

            reason = self_test()
        _verdict.append(reason or "")
        if reason:
            _warn(f"vtkIllum: the render view shows ParaView's own (unlit) volume: {reason}. "
                  "For a lit picture switch the filter's OutputRGBA on and use "
                  "vtkillum_plugin.ShowIlluminated(filter); VTKILLUM_PARAVIEW_DISPLAY=1 "
                  "forces the per-sample illumination on.")
    return not _verdict[0]


def _parallel_reason() -> str | None:
    """Why the per-sample illumination cannot run in this process's render views, if so."""
    try:
        from paraview.modules.vtkRemotingCore import vtkProcessModule
    except ImportError:
        return None
    module = vtkProcessModule.GetProcessModule()
    ranks = module.GetNumberOfLocalPartitions() if module is not None else 1
    if ranks > 1:
        return (f"ParaView runs on {ranks} MPI ranks, and the per-sample illumination draws "
                "only in a single process")
    return None


def hook_views(view_proxies) -> None:
    """Give every render view among ``view_proxies`` a :class:`ViewHook` (once)."""
    if not any(_is_render_view(view) for view in view_proxies) or not enabled():
        return
    for gid in [gid for gid, hook in _views.items() if hook.view is None]:
        _views.pop(gid).detach()
    for view in view_proxies:
        gid = view.GetGlobalID()
        if gid in _views or not _is_render_view(view):
            continue
        _views[gid] = ViewHook(view, view.GetClientSideObject().GetRenderer())


def _is_render_view(view) -> bool:
    cso = view.GetClientSideObject()
    return cso is not None and cso.IsA("vtkPVRenderView")


def illumination_of(data) -> dict | None:
    """What a dataset carries for the render view, or None if it carries no illumination."""
    if data is None or not data.IsA("vtkImageData") or data.GetNumberOfPoints() == 0:
        return None
    fd, pd = data.GetFieldData(), data.GetPointData()
    render = fd.GetArray(RENDER_FIELD)
    if render is None:
        return None
    lights = fd.GetArray(LIGHTS_FIELD)
    transmittance, scattered, fluence = (pd.GetArray(n) for n in (TRANSMITTANCE, SCATTERED,
                                                                   FLUENCE))
    if transmittance is None and fluence is None:
        return None
    scalars = fd.GetAbstractArray(SCALARS_FIELD)
    name = scalars.GetValue(0) if scalars is not None and scalars.GetNumberOfValues() else ""
    if not name and pd.GetScalars() is not None:
        name = pd.GetScalars().GetName()
    rows = np.zeros((0, 8))
    if lights is not None and lights.GetNumberOfTuples():
        width = lights.GetNumberOfComponents()  # 8: with the source radius; 7: without
        raw = vtk_to_numpy(lights).reshape(-1, width)
        rows = np.zeros((len(raw), 8))
        rows[:, : min(width, 8)] = raw[:, :8]
    albedo, anisotropy, unit, exposure = (render.GetValue(i) for i in range(4))
    light_spacing = render.GetValue(4) if render.GetNumberOfTuples() > 4 else 0.0
    return {"scalars": name, "lights": rows, "albedo": albedo, "anisotropy": anisotropy,
            "unit_distance": unit, "exposure": exposure, "light_spacing": light_spacing,
            "transmittance": transmittance,
            "scattered": scattered, "fluence": fluence}


class ViewHook:
    """Swaps ParaView's volumes for illuminated ones in one render view (see module doc)."""

    def __init__(self, view, renderer) -> None:
        self._view = vtkWeakReference()
        self._view.Set(view)
        self._renderer = vtkWeakReference()
        self._renderer.Set(renderer)
        self.volumes: dict = {}  # ParaView volume address -> IlluminatedVolume
        self._tags = [renderer.AddObserver("StartEvent", lambda *a: self.before_render()),
                      renderer.AddObserver("EndEvent", lambda *a: self.after_render())]

    @property
    def view(self):
        return self._view.Get()

    def detach(self) -> None:
        renderer = self._renderer.Get()
        if renderer is not None:
            for tag in self._tags:
                renderer.RemoveObserver(tag)
            for ours in self.volumes.values():
                ours.restore(renderer)
        self.volumes.clear()

    def _volume_representations(self) -> list:
        """(ParaView volume actor, representation proxy) for each volume representation."""
        from paraview.modules.vtkRemotingServerManager import vtkSMPropertyHelper

        view = self.view
        found = []
        if view is None or view.GetProperty("Representations") is None:
            return found
        helper = vtkSMPropertyHelper(view, "Representations")
        for i in range(helper.GetNumberOfElements()):
            rep = helper.GetAsProxy(i)
            cso = rep.GetClientSideObject() if rep is not None else None
            if cso is None or not hasattr(cso, "GetActiveRepresentation"):
                continue
            active = cso.GetActiveRepresentation()
            if active is not None and active.IsA("vtkImageVolumeRepresentation"):
                found.append((active.GetActor(), rep))
        return found

    def before_render(self) -> None:
        renderer = self._renderer.Get()
        if renderer is None:
            return
        try:
            self._update(renderer)
        except Exception as err:  # noqa: BLE001 - never break ParaView's render
            _warn(f"vtkIllum: illuminated rendering failed, showing ParaView's volume: {err}")
            for ours in self.volumes.values():
                ours.restore(renderer)
            self.volumes.clear()

    def _update(self, renderer) -> None:
        seen = set()
        for pvvol, _rep in self._volume_representations():
            key = pvvol.GetAddressAsString("vtkPVLODVolume")
            seen.add(key)
            ours = self.volumes.get(key)
            reason = IlluminatedVolume.why_not(pvvol)
            if reason is None:
                if ours is None:
                    ours = self.volumes[key] = IlluminatedVolume(pvvol)
                ours.take_place_of(renderer)
                ours.sync(renderer)
            elif ours is not None:
                ours.restore(renderer)
                del self.volumes[key]
        for key in [k for k in self.volumes if k not in seen]:
            self.volumes.pop(key).remove(renderer)

    def after_render(self) -> None:
        for ours in self.volumes.values():
            ours.release_textures()


class _Texture:
    """A float 3D texture uploaded from a numpy array (VTK point order)."""

    def __init__(self) -> None:
        self.texture = vtkTextureObject()
        self.key = None

    def upload(self, window, key, values: np.ndarray, dims) -> None:
        if key == self.key and self.texture.GetHandle():
            return
        values = np.ascontiguousarray(values, dtype=np.float32)
        components = values.shape[-1] if values.ndim > 1 else 1
        self.texture.SetContext(window)
        if not self.texture.Create3DFromRaw(int(dims[0]), int(dims[1]), int(dims[2]),
                                            components, VTK_FLOAT, values):
            raise RuntimeError("could not create an illumination texture "
                               f"({dims[0]}x{dims[1]}x{dims[2]}x{components})")
        self.texture.SetMinificationFilter(vtkTextureObject.Linear)
        self.texture.SetMagnificationFilter(vtkTextureObject.Linear)
        for set_wrap in (self.texture.SetWrapS, self.texture.SetWrapT, self.texture.SetWrapR):
            set_wrap(vtkTextureObject.ClampToEdge)
        self._data = values  # keep the host copy alive while the driver may read it
        self.key = key


class IlluminatedVolume:
    """Our ``vtkVolume`` in the place of one ParaView volume actor (see module doc)."""

    @staticmethod
    def why_not(pvvol) -> str | None:
        """Why this ParaView volume is drawn as is (None: it gets illuminated)."""
        mapper = pvvol.GetMapper()
        if mapper is None or not pvvol.GetVisibility():
            return "hidden"
        data = mapper.GetInputDataObject(0, 0)
        if data is not None and data.IsA("vtkMultiBlockDataSet") and data.GetNumberOfBlocks() == 1:
            data = data.GetBlock(0)
        info = illumination_of(data)
        if info is None:
            return "no illumination in the data"
        if mapper.GetArrayName() != info["scalars"]:
            return "the display colours by another array than the illuminated one"
        if mapper.GetScalarMode() not in (3,):  # VTK_SCALAR_MODE_USE_POINT_FIELD_DATA
            return "not point data"
        if mapper.GetBlendMode() != 0:
            return "blend mode is not Composite"
        if pvvol.GetProperty().GetTransferFunctionMode() != 0:
            return "2D transfer function"
        return None

    def __init__(self, pvvol) -> None:
        self._pvvol = pvvol
        self.volume = vtkVolume()
        self.mapper = vtkOpenGLGPUVolumeRayCastMapper()
        self.mapper.SetBlendModeToComposite()
        self.volume.SetMapper(self.mapper)
        shader = self.volume.GetShaderProperty()
        shader.AddFragmentShaderReplacement("//VTK::CustomUniforms::Dec", True, UNIFORMS_DEC,
                                            False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Dec", True, SHADING_DEC, False)
        shader.AddFragmentShaderReplacement("//VTK::ComputeVolumetricShadow::Dec", True,
                                            LATE_DEC, False)
        shader.AddFragmentShaderReplacement("//VTK::Shading::Impl", True, SHADING_IMPL, False)
        self.textures = {name: _Texture() for name in ("il_T0", "il_T1", "il_S")}
        self._data_key = None
        self._host: dict = {}
        self._active: list = []

    # --- place in the renderer -----------------------------------------------------------------
    def take_place_of(self, renderer) -> None:
        volumes = renderer.GetVolumes()
        if volumes.IsItemPresent(self._pvvol):
            renderer.RemoveVolume(self._pvvol)
        if not volumes.IsItemPresent(self.volume):
            renderer.AddVolume(self.volume)

    def restore(self, renderer) -> None:
        """Put ParaView's own volume back."""
        self.remove(renderer)
        if not renderer.GetVolumes().IsItemPresent(self._pvvol):
            renderer.AddVolume(self._pvvol)

    def remove(self, renderer) -> None:
        self.release_textures()
        if renderer.GetVolumes().IsItemPresent(self.volume):
            renderer.RemoveVolume(self.volume)
        window = renderer.GetRenderWindow()
        if window is not None:  # free the GPU memory while the window's context exists
            for texture in self.textures.values():
                texture.texture.ReleaseGraphicsResources(window)
                texture.key = None
            self.volume.ReleaseGraphicsResources(window)

    # --- every render --------------------------------------------------------------------------
    def sync(self, renderer) -> None:
        pvvol = self._pvvol
        pv_mapper = pvvol.GetMapper()
        data = pv_mapper.GetInputDataObject(0, 0)
        if data.IsA("vtkMultiBlockDataSet"):
            data = data.GetBlock(0)
        info = illumination_of(data)
        prop = pvvol.GetProperty()
        self.volume.SetProperty(prop)
        self.volume.SetVisibility(pvvol.GetVisibility())
        matrix = pvvol.GetMatrix()
        self.volume.SetUserMatrix(matrix)
        self._set_input(data, info, prop)
        window = renderer.GetRenderWindow()
        self._set_textures(window, data, info)
        self._set_uniforms(renderer, data, info, prop, matrix)

    def _set_input(self, data, info, prop) -> None:
        name = info["scalars"]
        array = data.GetPointData().GetArray(name)
        lut = prop.GetRGBTransferFunction(0)
        mode = (lut.GetVectorMode(), lut.GetVectorComponent()) \
            if array.GetNumberOfComponents() > 1 else (None, None)
        key = (data.GetAddressAsString("vtkImageData"), data.GetMTime(), name, mode)
        if key == self._data_key:
            return
        image = vtkImageData()
        image.CopyStructure(data)
        if array.GetNumberOfComponents() == 1:
            scalars = array
        else:  # as the colour map reduces it: Magnitude or one component
            values = vtk_to_numpy(array).astype(np.float32)
            reduced = values[:, min(mode[1], values.shape[1] - 1)] if mode[0] == 1 \
                else np.linalg.norm(values, axis=1)
            scalars = vtkFloatArray()
            scalars.SetName(name)
            scalars.SetNumberOfTuples(len(reduced))
            vtk_to_numpy(scalars)[:] = reduced
        image.GetPointData().SetScalars(scalars)
        self.mapper.SetInputDataObject(image)
        self._data_key = key
        self._host = {}

    def _set_textures(self, window, data, info) -> None:
        dims = data.GetDimensions()
        npts = data.GetNumberOfPoints()
        key = self._data_key
        tiny = np.zeros((1, 4), dtype=np.float32)
        if info["transmittance"] is not None:
            t = vtk_to_numpy(info["transmittance"]).reshape(npts, -1)[:, :MAX_LIGHTS]
            packed = np.zeros((npts, 8), dtype=np.float32)
            packed[:, : t.shape[1]] = t
            self.textures["il_T0"].upload(window, key, packed[:, :4], dims)
            if t.shape[1] > 4:
                self.textures["il_T1"].upload(window, key, packed[:, 4:], dims)
            else:
                self.textures["il_T1"].upload(window, "zero", tiny, (1, 1, 1))
            source = info["scattered"]
        else:
            self.textures["il_T0"].upload(window, "zero", tiny, (1, 1, 1))
            self.textures["il_T1"].upload(window, "zero", tiny, (1, 1, 1))
            source = info["fluence"]
        if source is not None:
            rgb = vtk_to_numpy(source).reshape(npts, -1)
            if rgb.shape[1] == 1:
                rgb = np.repeat(rgb, 3, axis=1)
            self.textures["il_S"].upload(window, key, rgb[:, :3], dims)
        else:
            self.textures["il_S"].upload(window, "zero", tiny[:, :3], (1, 1, 1))
        uniforms = self.volume.GetShaderProperty().GetFragmentCustomUniforms()
        self.release_textures()
        for name, texture in self.textures.items():
            texture.texture.Activate()
            self._active.append(texture.texture)
            uniforms.SetUniformi(name, texture.texture.GetTextureUnit())

    def release_textures(self) -> None:
        while self._active:
            self._active.pop().Deactivate()

    def _set_uniforms(self, renderer, data, info, prop, matrix) -> None:
        uniforms = self.volume.GetShaderProperty().GetFragmentCustomUniforms()
        m = np.array([[matrix.GetElement(i, j) for j in range(4)] for i in range(4)])
        dims = np.array(data.GetDimensions(), dtype=np.float64)
        spacing = np.array(data.GetSpacing(), dtype=np.float64)
        origin = np.array(data.GetOrigin(), dtype=np.float64)
        extent = np.array(data.GetExtent()[0::2], dtype=np.float64)
        direction = np.eye(3)
        if hasattr(data, "GetDirectionMatrix"):
            dm = data.GetDirectionMatrix()
            direction = np.array([[dm.GetElement(i, j) for j in range(3)] for i in range(3)])
        # texture coordinate t -> index (t n - 1/2) + extent start -> dataset -> world
        tex_to_data = np.eye(4)
        tex_to_data[:3, :3] = direction @ np.diag(spacing * dims)
        tex_to_data[:3, 3] = origin + direction @ (spacing * (extent - 0.5))
        tex_to_world = m @ tex_to_data
        linear = m[:3, :3] @ direction
        normal_matrix = np.linalg.inv(linear).T
        uniforms.SetUniform1fv("il_texToWorld", 16, tex_to_world.reshape(-1).tolist())
        uniforms.SetUniform1fv("il_worldToTex", 16,
                               np.linalg.inv(tex_to_world).reshape(-1).tolist())
        uniforms.SetUniform1fv("il_normalMatrix", 9, normal_matrix.reshape(-1).tolist())
        uniforms.SetUniform3f("il_texel", (1.0 / dims).tolist())
        uniforms.SetUniform3f("il_spacing", spacing.tolist())

        lights = np.zeros((MAX_LIGHTS, LIGHT_STRIDE))
        rows = info["lights"][:MAX_LIGHTS]
        half_voxel = 0.5 * float(spacing.min())
        for i, (kind, x, y, z, r, g, b, radius) in enumerate(rows):
            if kind < 0.5:  # travel direction -> unit vector towards the light (world)
                d = -(m[:3, :3] @ np.array([x, y, z]))
                d = d / (np.linalg.norm(d) or 1.0)
                radius = 0.0
            else:
                d = (m @ np.array([x, y, z, 1.0]))[:3]
                radius = radius if radius > 0 else half_voxel  # (vtkillum.core.lights)
            lights[i] = [kind, *d, r, g, b, radius]
        if len(info["lights"]) > MAX_LIGHTS:
            _warn(f"vtkIllum: the render view uses the first {MAX_LIGHTS} of "
                  f"{len(info['lights'])} lights")
        uniforms.SetUniformi("il_numLights", len(rows))
        uniforms.SetUniformi("il_mode", 0 if info["transmittance"] is not None else 1)
        uniforms.SetUniform1fv("il_lights", MAX_LIGHTS * LIGHT_STRIDE, lights.reshape(-1).tolist())

        if prop.GetShade(0):
            shading = [prop.GetAmbient(0), prop.GetDiffuse(0), prop.GetSpecular(0),
                       prop.GetSpecularPower(0)]
        else:
            shading = [1.0, 0.0, 0.0, 1.0]
        uniforms.SetUniform4f("il_shading", [float(v) for v in shading])
        camera = renderer.GetActiveCamera()
        parallel = bool(camera.GetParallelProjection())
        if parallel:
            cam = np.array(camera.GetFocalPoint()) - np.array(camera.GetPosition())
        else:
            cam = np.array(camera.GetPosition())
        uniforms.SetUniform3f("il_camera", cam.tolist())
        # near: two cells of the grid the transmittance was computed on (world units)
        cells = float(NEAR_CELLS)  # (read at each render: a module setting)
        near = cells * info["light_spacing"] if info["light_spacing"] > 0 \
            else cells * float(spacing.max())
        uniforms.SetUniform4f("il_params", [info["albedo"] * info["exposure"], info["anisotropy"],
                                            near, 1.0 if parallel else 0.0])
        self._mirror_mapper()

    def _mirror_mapper(self) -> None:
        """Sampling as ParaView's volume mapper (its defaults; 5.11's mapper has no getters),
        jittered if :data:`JITTER`."""
        self.mapper.SetAutoAdjustSampleDistances(1)
        self.mapper.SetLockSampleDistanceToInputSpacing(0)
        self.mapper.SetUseJittering(1 if JITTER else 0)


def _warn(message: str) -> None:
    from vtkmodules.vtkCommonCore import vtkOutputWindow

    vtkOutputWindow.GetInstance().DisplayWarningText(message + "\n")


__all__ = ["IlluminatedVolume", "ViewHook", "hook_views", "illumination_of"]
