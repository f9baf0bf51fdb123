"""The ``"refraction"`` render method (Magnus & Bruckner 2017).

``render(volume, scene, method="refraction", ...)`` sweeps planes parallel to the
image plane through the volume, propagating the light buffer and the view rays
together (:mod:`~vtkillum.core.refraction.sweep`), then composites the background
along the bent rays (:mod:`~vtkillum.core.refraction.environment`). Nothing is
cached between frames except device buffers, tables and (on CUDA) the captured
launch graph: a camera, light or transfer-function change simply renders again.

Options (keyword arguments; the scene's ``refraction`` section gives the defaults
once registered in :data:`vtkillum.core.scene.METHOD_OPTIONS`):

``optics``               :class:`~vtkillum.core.refraction.optics.RefractiveOptics`
                         (η_tf and m_tf); default the scene's, else η ≡ 1, m ≡ white
``sample_distance``      plane spacing in units of the smallest voxel spacing (1: the
                         paper's setting, one sample per voxel in every orientation)
``step_size``            plane spacing in world units (overrides ``sample_distance``)
``softness``             soft light: tan of the light's angular radius, the per-plane
                         blur of the light buffer (0: hard shadows)
``direction_blur``       the same kernel on the light directions (1; paper: reduces the
                         backward mapping's bias at refracting boundaries)
``intensity_correction`` caustics from the intensity law (eqs. 11–13); True
``max_concentration``    largest intensity gain of the intensity law (100): bounds the
                         light at foci the light grid cannot resolve
``specular``             weight of the Cook–Torrance term (1; 0 turns it off)
``roughness``            Beckmann RMS slope of the specular lobe (0.3)
``light_buffer_scale``   light texel size relative to the pixel footprint at the
                         volume's centre depth (1)
``environment``          equirectangular map (H, W, 3) linear RGB, or a ``.npy``/image
                         path; seen along the final ray directions (section 4.4)
``composite_background`` include the background (map or ``scene.background``) in the
                         radiance; default: when a map is given or the background is not
                         black (then alpha is 1)
``early_termination``    view rays stop computing past this opacity (0.999)
``seed``                 seed of the blur's random rotations
``graph``                on CUDA, capture the launches once per 32 planes of depth and
                         replay them (True)
``cull_light``           propagate the light only over each plane's cross-section with the
                         box (plus a margin), as the paper's slice polygons do (True; off,
                         and with ``record_light``, the whole sheared grid)

The light is one distant (directional) light within :data:`MAX_LIGHT_ANGLE` degrees
of the view direction, as in the paper; anything else is refused with an error
that names the limit. Radiance is linear, in the units of the light's irradiance
per steradian (the project's convention, ``single`` for η ≡ 1, m ≡ white).
"""

from __future__ import annotations

import ctypes
import time

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.lights import DIRECTIONAL
from vtkillum.core.refraction.environment import make_environment
from vtkillum.core.refraction.light_propagation import GP_LAYERS
from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.core.refraction.preintegration import make_refractive_medium
from vtkillum.core.refraction.planes import (
    MAX_LIGHT_ANGLE,
    SweepParams,
    light_angle,
    make_params,
    plane_rects,
    sweep_geometry,
)
from vtkillum.core.refraction.sweep import (
    BLOCK_DIM,
    SweepBuffers,
    sweep_kernels,
    sweep_launches,
)
from vtkillum.core.render import RenderResult
from vtkillum.core.warp_common import HostReader

#: Method options and their defaults (also the scene file's ``refraction`` section).
REFRACTION_OPTIONS = {
    "sample_distance": 1.0,
    "softness": 0.0,
    "direction_blur": 1.0,
    "intensity_correction": True,
    "max_concentration": 100.0,
    "specular": 1.0,
    "roughness": 0.3,
    "light_buffer_scale": 1.0,
    "environment": "",
    "early_termination": 0.999,
    "seed": 0,
}
#: Keyword-only options (not in the scene file).
EXTRA_OPTIONS = {"optics": None, "step_size": None, "composite_background": None,
                 "graph": True, "record_light": None, "cull_light": True}

#: Threads of a light-plane launch in a captured graph, as a fraction of the light grid's
#: capacity (they stride over the plane's rectangle, on average 0.3-0.5 of the grid; 0.35,
#: 0.5, 1 and the largest rectangle were within run-to-run noise on an H100).
LIGHT_THREADS = 0.5
#: A captured graph covers a multiple of this many planes (see :func:`graph_planes`).
PLANE_BUCKET = 32


def graph_planes(planes: int) -> int:
    """Planes of the graph that renders ``planes``: rounded up to :data:`PLANE_BUCKET`, so
    that a camera that moves (and changes the plane count by a few) replays the same graph
    instead of capturing a new one (~100 ms); the extra planes cost a launch each that
    returns at once."""
    return -(-int(planes) // PLANE_BUCKET) * PLANE_BUCKET

_RENDERERS: dict[str, "RefractionRenderer"] = {}


def render_refraction(volume, scene, width: int, height: int, device: str | None = None,
                      progress=None, **options) -> RenderResult:
    """Render ``volume`` with refraction and caustics (see the module docstring).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
        Transfer function, unit distance, albedo, anisotropy, the one directional
        light, camera and background.
    width, height : int
    device : str, optional
    progress : callable, optional
        ``progress(fraction)`` between planes (CPU, or with ``graph=False``).
    **options
        See the module docstring.

    Returns
    -------
    RenderResult
        ``info`` holds the plane count, light-grid size, timings and, with
        ``record_light``, the recorded light planes.
    """
    device = resolve_device(device)
    renderer = _RENDERERS.get(device)
    if renderer is None:
        renderer = _RENDERERS[device] = RefractionRenderer(device)
    return renderer.render(volume, scene, width, height, progress, **options)


def release_renderers() -> None:
    """Free the device buffers kept between calls."""
    _RENDERERS.clear()


def parse_options(options: dict, volume, scene) -> dict:
    """Merge keyword options over the scene's ``refraction`` section and validate them."""
    known = set(REFRACTION_OPTIONS) | set(EXTRA_OPTIONS)
    unknown = set(options) - known
    if unknown:
        raise ValueError(f"unknown refraction option(s) {sorted(unknown)}; known: {sorted(known)}")
    opts = dict(REFRACTION_OPTIONS)
    opts.update(getattr(scene, "options", {}).get("refraction", {}))
    opts.update(EXTRA_OPTIONS)
    opts.update(options)

    def number(name, lo=None, hi=None, lo_open=False):
        x = opts[name]
        if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)) \
                or not np.isfinite(x):
            raise ValueError(f"refraction.{name} must be a finite number, got {x!r}")
        x = float(x)
        if lo is not None and (x < lo or (lo_open and x <= lo)):
            raise ValueError(f"refraction.{name} must be {'>' if lo_open else '>='} {lo}, got {x}")
        if hi is not None and x > hi:
            raise ValueError(f"refraction.{name} must be <= {hi}, got {x}")
        opts[name] = x

    number("sample_distance", 0.0, lo_open=True)
    number("softness", 0.0)
    number("direction_blur", 0.0)
    number("max_concentration", 1.0)
    number("specular", 0.0)
    number("roughness", 0.0, lo_open=True)
    number("light_buffer_scale", 0.0, lo_open=True)
    number("early_termination", 0.0, 1.0, lo_open=True)
    step = opts["step_size"]
    if step is None:
        opts["step_size"] = opts["sample_distance"] * float(volume.spacing.min())
    else:
        if isinstance(step, bool) or not isinstance(step, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(step) and step > 0):
            raise ValueError(f"refraction: step_size (the plane spacing) must be a positive "
                             f"number of world units, got {step!r}")
        opts["step_size"] = float(step)
    diagonal = float(np.linalg.norm(volume.extent))
    if diagonal / opts["step_size"] > 1 << 16:
        raise ValueError(f"refraction: a plane spacing of {opts['step_size']:g} needs "
                         f"{diagonal / opts['step_size']:.3g} planes; use a larger sample_distance")
    for name in ("intensity_correction", "graph", "cull_light"):
        if not isinstance(opts[name], (bool, np.bool_)):
            raise ValueError(f"refraction.{name} must be true or false, got {opts[name]!r}")
    seed = opts["seed"]
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**31:
        raise ValueError(f"refraction.seed must be an integer in [0, 2**31), got {seed!r}")
    optics = opts["optics"]
    if optics is None:
        optics = getattr(scene, "optics", None) or RefractiveOptics.identity()
    if not isinstance(optics, RefractiveOptics):
        raise ValueError(f"optics must be a RefractiveOptics, got {type(optics).__name__}")
    opts["optics"] = optics
    env = opts["environment"]
    if isinstance(env, str) and env == "":
        env = None
    opts["environment"] = env
    composite = opts["composite_background"]
    if composite is None:
        composite = env is not None or bool(np.any(np.asarray(scene.background) > 0))
    opts["composite_background"] = bool(composite)
    return opts


def check_light(scene, camera) -> object:
    """The scene's one directional light, or a ``ValueError`` naming the method's limit."""
    lights = list(scene.lights)
    if len(lights) != 1:
        raise ValueError(
            f"the refraction method (Magnus & Bruckner 2017) supports exactly one distant light in "
            f"the camera's hemisphere; the scene has {len(lights)} lights")
    light = lights[0]
    if light.kind != DIRECTIONAL:
        raise ValueError(
            "the refraction method supports one distant (directional) light only, not a point "
            "light (the light buffer is propagated along one direction, Magnus & Bruckner 2017)")
    angle = light_angle(light.direction, camera.forward)
    if angle > MAX_LIGHT_ANGLE:
        raise ValueError(
            f"the refraction method needs the light within {MAX_LIGHT_ANGLE:g} degrees of the view "
            f"direction (one distant light in the camera's hemisphere, the paper's limit for "
            f"view-aligned planes); this light travels at {angle:.1f} degrees to it. Move the "
            "light towards the camera or use another method")
    return light


class RefractionRenderer:
    """Device state kept between frames on one device: buffers, tables, launch graphs."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.buffers = SweepBuffers(device)
        self.tables: dict = {}
        self._medium = None
        self._medium_key = None
        self._environment = None
        self._environment_key = None
        self._params = wp.zeros(1, dtype=SweepParams, device=device)
        self._graphs: dict = {}
        self._graph_error = None  # why graph capture failed on this device, if it did
        self._readers: dict = {}  # the image download's, per view buffer
        self._params_host = None  # pinned host copy of the frame record (CUDA)

    def render(self, volume, scene, width: int, height: int, progress=None,
               **options) -> RenderResult:
        t_start = time.perf_counter()
        width, height = int(width), int(height)
        if width < 1 or height < 1:
            raise ValueError(f"image size must be positive, got {width} x {height}")
        opts = parse_options(options, volume, scene)
        camera = scene.resolved_camera(volume)
        light = check_light(scene, camera)
        optics = opts["optics"]
        tf = scene.resolved_transfer_function(volume)
        u = scene.resolved_unit_distance(volume)
        medium = self._get_medium(volume, tf, optics, u, scene.albedo, scene.anisotropy)
        environment = self._get_environment(opts["environment"])
        geometry = sweep_geometry(volume, camera, width, height, light.direction,
                                  opts["step_size"], opts["light_buffer_scale"],
                                  max(opts["softness"], opts["direction_blur"]))
        replaced = self.buffers.ensure(geometry.texels, width * height,
                                       graph_planes(geometry.planes))
        if replaced:
            self._graphs.clear()
        params = make_params(volume, camera, width, height, geometry, light.irradiance, opts,
                             scene.background)
        self._upload_params(params)
        record = opts["record_light"]
        if opts["cull_light"] and record is None:
            rects = plane_rects(geometry, 2 * geometry.reach)
        else:
            rects = np.tile(np.array([0, 0, geometry.nx, geometry.ny], np.int32),
                            (geometry.planes, 1))
        wp.copy(self.buffers.light.rect, wp.array(rects, dtype=wp.vec4i, device="cpu"),
                count=geometry.planes)
        light_dims = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
        t_setup = time.perf_counter()

        recorded = {}
        after = None
        if record is not None:
            wanted = set(range(geometry.planes)) if record is True else {int(j) for j in record}

            def after(j):
                if j in wanted:
                    n = geometry.texels
                    lb = self.buffers.light
                    recorded[j] = {
                        name: getattr(lb, field).numpy()[j % layers, :n].reshape(
                            geometry.ny, geometry.nx, -1).copy()
                        for name, field, layers in (("light", "l", lb.ring),
                                                    ("direction", "v", lb.ring),
                                                    ("eta_gradient", "g", GP_LAYERS),
                                                    ("tube", "p", GP_LAYERS))}
        elif progress is not None and not self._use_graph(opts):
            step = max(1, geometry.planes // 20)

            def after(j):
                if j % step == 0 and j > 0:
                    wp.synchronize_device(self.device)
                    progress(j / (geometry.planes + 1))

        launches = self._run(medium, environment, geometry.planes, width, height, opts,
                             light_dims, after)
        wp.synchronize_device(self.device)
        t_sweep = time.perf_counter()
        n = width * height
        rad = self._download("radiance", n).reshape(height, width, 3)
        alp = self._download("alpha", n).reshape(height, width)
        t_end = time.perf_counter()
        if progress is not None:
            progress(1.0)
        info = {
            "method": "refraction",
            "device": self.device,
            "planes": geometry.planes,
            "plane_spacing": geometry.dz,
            "light_grid": (geometry.nx, geometry.ny),
            "light_texels": int(light_dims.sum()),
            "light_texel": geometry.texel,
            "light_angle_deg": light_angle(light.direction, camera.forward),
            "eta_outside": float(medium.eta_outside),
            "launches": launches,
            "graph": self._use_graph(opts),
            "graph_error": self._graph_error,
            "composite_background": opts["composite_background"],
            "setup_s": t_setup - t_start,
            "sweep_s": t_sweep - t_setup,
            "download_s": t_end - t_sweep,
            "total_s": t_end - t_start,
        }
        if record is not None:
            info["light_planes"] = recorded
            info["geometry"] = geometry
        return RenderResult(rad, alp, info)

    # --- internals ---------------------------------------------------------------------------
    def _upload_params(self, params: SweepParams) -> None:
        """Copy the frame record into the device array the kernels (and a captured graph)
        read: its bytes through a pinned host record on CUDA (building a one-element
        structured array per frame cost more than the copy)."""
        value = params.__ctype__()
        size = ctypes.sizeof(value)
        if not self._params.device.is_cuda:
            ctypes.memmove(self._params.ptr, ctypes.addressof(value), size)
            return
        if self._params_host is None:
            self._params_host = wp.empty(1, dtype=SweepParams, device="cpu", pinned=True)
        ctypes.memmove(self._params_host.ptr, ctypes.addressof(value), size)
        wp.copy(self._params, self._params_host)

    def _download(self, name: str, n: int) -> np.ndarray:
        """A host copy of the first ``n`` entries of view buffer ``name`` (float32; on CUDA
        through a pinned array kept between frames, :class:`HostReader`: a copy at full bus
        speed instead of a pageable one into a fresh array)."""
        src = self.buffers.view[name]
        reader = self._readers.get(name)
        if reader is None or reader.array is not src:  # the buffers were replaced
            reader = self._readers[name] = HostReader(src)
        return reader.read(n)

    def _use_graph(self, opts) -> bool:
        return bool(opts["graph"]) and self.device.startswith("cuda") \
            and opts["record_light"] is None and self._graph_error is None

    def _run(self, medium, environment, planes, width, height, opts, light_dims,
             after) -> int:
        if not self._use_graph(opts):
            return sweep_launches(medium, self._params, self.buffers, environment, planes,
                                  width, height, self.device, light_dims, after_plane=after)
        # A graph fixes its launch sizes while the camera changes the plane count and the
        # rectangles: it runs a whole number of PLANE_BUCKETs (the planes past the frame's
        # own return at once), and every light plane gets a fixed share of the grid's
        # capacity, whose threads stride over the plane's rectangle.
        planes = graph_planes(planes)
        dim = -(-int(self.buffers.capacity * LIGHT_THREADS) // BLOCK_DIM) * BLOCK_DIM
        args = (medium, self._params, self.buffers, environment, planes, width, height,
                self.device, [dim] * planes)
        key = (planes, width, height, self.buffers.capacity, self._medium_key,
               self._environment_key)
        entry = self._graphs.get(key)
        if entry is None:
            if len(self._graphs) > 16:
                self._graphs.clear()
            sweep_kernels(True)  # their modules exist before the capture loads all modules
            try:
                with wp.ScopedCapture(device=self.device, force_module_load=True) as capture:
                    launches = sweep_launches(*args)
            except Exception as err:  # a driver without graph capture: launch plane by plane
                self._graph_error = f"{type(err).__name__}: {err}"
                return sweep_launches(*args, after_plane=after)
            entry = self._graphs[key] = (capture.graph, launches)
        wp.capture_launch(entry[0])
        return entry[1]

    def _get_medium(self, volume, tf, optics, u, albedo, g):
        key = (id(volume), volume.content_key, tf.scalars.tobytes(), tf.opacity.tobytes(),
               tf.colors.tobytes(), optics.key(), float(u), float(albedo), float(g))
        if key != self._medium_key:
            self._medium = make_refractive_medium(volume, tf, optics, u, albedo, g, self.device,
                                                  arrays=self.tables)
            self._medium_key = key
        return self._medium

    def _get_environment(self, env):
        if env is None:
            key = None
        elif isinstance(env, np.ndarray):
            key = ("array", env.shape, hash(np.ascontiguousarray(env).tobytes()))
        else:
            key = ("file", str(env))
        if self._environment is None or key != self._environment_key:
            self._environment = make_environment(env, self.device)
            self._environment_key = key
        return self._environment
