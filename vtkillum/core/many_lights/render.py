"""The ``"many-lights"`` render method and its progressive renderer.

``render(volume, scene, method="many-lights", ...)`` generates ``sets`` VL sets
(:mod:`~vtkillum.core.many_lights.walk`), caches their transmittance in AVSMs
(:mod:`~vtkillum.core.many_lights.avsm`) and renders exact single scattering plus the
VLs' multiple scattering (:mod:`~vtkillum.core.many_lights.gather`). Sets are
independent (set ``s`` uses the path streams of ``(seed, s)``) and are combined as one
estimate: single scattering averaged over the sets' jittered passes, multiple
scattering summed over all VLs and divided by the total number of light paths. The
radius of the VLs of set ``s`` (VSL or clamping radius) is ``r_s = r_0 (s + 1)^-beta``
(``radius_exponent`` ``beta``), so the accumulated image converges to the unregularised
estimate, i.e. to the path tracer.

:class:`ManyLightsRenderer` is the progressive form (like
:class:`~vtkillum.core.pathtrace.PathTracer`): ``run(n)`` adds sets, ``reset(camera)``
restarts the image but keeps the VLs (they do not depend on the camera), ``update(scene)``
applies an edit at once (contribution update, eq. 6) and :meth:`ManyLightsRenderer.frame`
is one interactive frame: a step of progressive regeneration while the set is stale
(the image then shows set 0 alone), else one more set.

Options (keyword arguments; the first group defaults to the scene's ``many_lights``
section, :data:`vtkillum.core.scene.METHOD_OPTIONS`). The defaults make a first picture
without blobs (issue 34, ``docs/many_lights.md``); the paper's setting of earlier versions
is ``count=256 sets=1 virtual_lights=spherical vsl_radius=2 vsl_radius_mfp=0.5
avsm_resolution=48 view_samples=8``.

``count``               VLs per set (1024)
``sets``                VL sets rendered by ``render``; 0 (default): automatic, sets are
                        added until the estimated noise (:meth:`ManyLightsRenderer.noise`)
                        is at most ``noise_target`` (0.03; 0: no target), or the next set
                        would end later than ``time_budget`` seconds after the start (60;
                        0: none), or ``max_sets``; at least one. The number of sets then
                        depends on the machine's speed: give ``sets`` for a reproducible
                        image
``max_sets``            sets a progressive renderer accumulates at most (64)
``virtual_lights``      ``"clamped"`` (default: bounded contributions, the clamped energy
                        spread nearby, :mod:`~vtkillum.core.many_lights.clamp`),
                        ``"spherical"`` (VSLs, eq. 5) or ``"point"`` (VPLs, eq. 4)
``vsl_radius``          radius ``r_0`` of clamped or spherical VLs in voxels (x mean
                        spacing); 0 (default): automatic, for clamped VLs the median
                        distance to the ``vsl_neighbours``-th nearest other light path
                        (16), for VSLs 2 voxels
``vsl_radius_mfp``      ... and at most this many mean free paths at the VL (0: no bound,
                        the default; 0.5 was the VSLs' default)
``radius_exponent``     ``beta`` of the radius schedule, in [0, 1) (1/3)
``transmittance``       ``"avsm"`` (cached) or ``"ray-marching"`` (exact)
``avsm_resolution``     texels per cube-map face edge (16)
``avsm_nodes``          nodes ``m`` per texel, 2 .. 16 (8)
``avsm_lookup``         ``"trilinear"`` or ``"point"``
``distance_sampling``   ``"ray-marching"`` (Algorithm 1) or ``"delta-tracking"``
``phase_sampling``      ``"hg"`` (importance sampling) or ``"isotropic"`` (section 5.2)
``view_samples``        multiple-scattering positions per view ray (4)
``update_fraction``     fraction of the paths regenerated per frame after an edit (0.1)
``update_budget``       most AVSMs rebuilt per frame (0: no limit)
``scale_range``         ``[S_min, S_max]`` of eq. 8; equal values: sample the current medium
``density_scale``       global density scale ``S`` (eq. 7) (1)
``seed``                seed of the light paths and of the view-ray jitter (0)

and ``step_size`` (view rays and segment depths; the scene's), ``jitter`` (True),
``early_termination`` (0.999), ``vl_step`` (ray-marched VL shadow rays; ``step_size``),
``avsm_step`` (texel rays; the smallest voxel spacing).
"""

from __future__ import annotations

import time

import numpy as np

from vtkillum.core.device import resolve_device
from vtkillum.core.many_lights.avsm import FILTERS, MAX_NODES
from vtkillum.core.many_lights.cache import ManyLightsState
from vtkillum.core.many_lights.gather import TRANSMITTANCE, gather_params, render_image
from vtkillum.core.many_lights.walk import SAMPLING
from vtkillum.core.raymarch import RAY_OPTIONS, ray_options
from vtkillum.core.render import RenderResult
from vtkillum.core.units import canonical
from vtkillum.core.warp_common import make_camera, stream_seed

#: The scene section's fields and defaults (``METHOD_OPTIONS["many_lights"]``).
DEFAULTS = {
    "count": 1024,
    "sets": 0,
    "max_sets": 64,
    "time_budget": 60.0,
    "noise_target": 0.03,
    "virtual_lights": "clamped",
    "vsl_radius": 0.0,
    "vsl_radius_mfp": 0.0,
    "vsl_neighbours": 16,
    "radius_exponent": 1.0 / 3.0,
    "transmittance": "avsm",
    "avsm_resolution": 16,
    "avsm_nodes": 8,
    "avsm_lookup": "trilinear",
    "distance_sampling": "delta-tracking",
    "phase_sampling": "hg",
    "view_samples": 4,
    "update_fraction": 0.1,
    "update_budget": 0,
    "scale_range": [1.0, 1.0],
    "density_scale": 1.0,
    "seed": 0,
}
#: Keyword-only options.
KEYWORDS = {**RAY_OPTIONS, "vl_step": None, "avsm_step": None}
#: Salt of the per-pass view-ray seeds.
PASS_SALT = 0x7F4A7C15


def render_many_lights(volume, scene, width: int, height: int, device: str | None = None,
                       progress=None, **options) -> RenderResult:
    """Render with virtual lights and transmittance caching (see the module docstring).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device.
    progress : callable, optional
        ``progress(fraction)`` after each set.
    **options
        See the module docstring.

    Returns
    -------
    RenderResult
        Radiance = single + multiple scattering; ``info`` holds ``single`` and
        ``multiple`` (the two terms, (H, W, 3)), VL and path counts, timings in ms.
    """
    start = time.perf_counter()
    renderer = ManyLightsRenderer(volume, scene, width, height, device, **options)
    o = renderer.opts
    if o["sets"] > 0:
        for i in range(o["sets"]):
            renderer.run(1)
            if progress is not None:
                progress((i + 1) / o["sets"])
        return renderer.result()
    # Automatic: add sets until the noise estimate meets the target, the next set would end
    # past the time budget (set 0 is always rendered), or max_sets.
    budget, target = o["time_budget"], o["noise_target"]
    while True:
        renderer.run(1)
        n = renderer.passes
        elapsed = time.perf_counter() - start
        noise = renderer.noise()
        if n >= o["max_sets"]:
            renderer.stopped = "max_sets"
        elif noise is not None and target > 0 and noise <= target:
            renderer.stopped = "noise_target"
        elif budget > 0 and elapsed * (n + 1) / n > budget:
            renderer.stopped = "time_budget"
        if progress is not None:
            fractions = [n / o["max_sets"]]
            if budget > 0:
                fractions.append(elapsed / budget)
            progress(1.0 if renderer.stopped else min(max(fractions), 0.99))
        if renderer.stopped:
            return renderer.result()


class ManyLightsRenderer:
    """Progressive many-light rendering: accumulate VL sets, follow edits.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
        Optics, lights, camera (``scene.resolved_camera(volume)`` when it has none) and
        the ``many_lights`` section.
    width, height : int
    device : str, optional
    **options
        See the module docstring.

    Attributes
    ----------
    state : ManyLightsState
        Set 0, the one that is edited.
    passes : int
        Sets accumulated in the image.
    units : vtkillum.core.units.WorldUnits
        The renderer works in canonical units: ``volume``, ``scene`` and ``state`` are in
        them; cameras and scenes given to :meth:`reset` and :meth:`update` are in world
        units (``camera`` too).
    """

    def __init__(self, volume, scene, width: int, height: int, device: str | None = None,
                 **options) -> None:
        self.device = resolve_device(device)
        self.width, self.height = _positive_int(width, "width"), _positive_int(height, "height")
        if not (hasattr(volume, "extent") and hasattr(volume, "scalars")):
            raise TypeError(f"volume must be a vtkillum Volume, got {type(volume).__name__}")
        # Canonical units (vtkillum.core.units): any world length scale works.
        self.camera = scene.resolved_camera(volume)
        volume, scene, options, self.units = canonical(volume, scene, options)
        self.volume = volume
        self.scene = scene
        self._options = dict(options)
        with self.units.explained():
            self.opts = parse_options(options, volume, scene)
            t0 = time.perf_counter()
            self.state = ManyLightsState(volume, scene, self.opts, self.device, 0)
        self._setup_ms = 1e3 * (time.perf_counter() - t0)
        self._extra: ManyLightsState | None = None
        self._cam = make_camera(self.units.camera(self.camera), volume, self.width, self.height)
        self.last: dict = {}
        self.reset()

    # --- accumulation ---------------------------------------------------------------------
    def reset(self, camera=None) -> "ManyLightsRenderer":
        """Discard the image (the VLs are kept); optionally move the camera."""
        if camera is not None:
            self.camera = camera
            self._cam = make_camera(self.units.camera(camera), self.volume, self.width,
                                    self.height)
        shape = (self.height, self.width)
        self._single = np.zeros((*shape, 3))
        self._multiple = np.zeros((*shape, 3))
        self._alpha = np.zeros(shape)
        self._square = np.zeros((*shape, 3))  # sum of the sets' multiple terms squared
        self._paths = 0
        self.stopped = None
        self.passes = 0
        self._render_ms = 0.0
        return self

    def run(self, passes: int = 1) -> "ManyLightsRenderer":
        """Render and add ``passes`` more VL sets (set 0 first, then 1, 2, ...)."""
        for _ in range(_positive_int(passes, "passes")):
            s = self.passes
            if s == 0:
                state = self.state
            else:
                t0 = time.perf_counter()
                if self._extra is None:
                    self._extra = ManyLightsState(self.volume, self.scene, self.opts,
                                                  self.device, s)
                else:
                    self._extra.reseed(s)
                self.last["generate_ms"] = 1e3 * (time.perf_counter() - t0)
                state = self._extra
            self._render_set(state, s)
        return self

    def frame(self) -> dict:
        """One interactive frame: regenerate while stale (image = set 0), else add a set.

        Returns the regeneration statistics (``complete`` tells whether set 0 is current).
        """
        if self.state.stale:
            stats = self.state.step()
            self.reset()
            self.run(1)
            return stats
        if self.passes < self.opts["max_sets"]:
            self.run(1)
        return {"paths": 0, "vls": 0, "avsms": 0, "reused": 0, "complete": True}

    def update(self, scene=None, density_scale: float | None = None) -> dict:
        """Apply an edit of the scene and/or the density scale at once (eq. 6 and 7); the
        image restarts. See :class:`~vtkillum.core.many_lights.cache.ManyLightsState`."""
        scene = self.scene if scene is None else self.units.scene(scene)
        with self.units.explained():
            edit = self.state.update(scene, density_scale)
        self.scene = scene
        if density_scale is not None:
            self.opts["density_scale"] = float(density_scale)
        if edit["edits"]:
            self._extra = None
            self.reset()
        return edit

    def set_density_scale(self, scale: float) -> dict:
        """Global density scale ``S`` (eq. 7): immediate, no ray marching."""
        return self.update(None, scale)

    def result(self) -> RenderResult:
        """The accumulated image."""
        n = max(self.passes, 1)
        single = (self._single / n).astype(np.float32)
        multiple = (self._multiple / max(self._paths, 1)).astype(np.float32)
        vls = self.state.vls
        info = {
            "method": "many-lights",
            "device": self.device,
            "sets": self.passes,
            "noise": self.noise(),
            "stopped": self.stopped,
            "vls": vls.n_vls,
            "paths": vls.n_paths,
            "stale_paths": vls.stale_paths,
            "capped_paths": vls.capped_paths,
            "radius_shrink": self.shrink(max(self.passes - 1, 0)),
            "transmittance": self.opts["transmittance"],
            "avsm_mib": (self.state.pool.nbytes / 2**20) if self.state.pool else 0.0,
            "setup_ms": self._setup_ms,
            "render_ms": self._render_ms,
            "timings_ms": dict(self.state.timings, **self.last),
            "single": single,
            "multiple": multiple,
        }
        return RenderResult(single + multiple, (self._alpha / n).astype(np.float32),
                            self.units.info(info))

    def noise(self) -> float | None:
        """Estimated relative standard error of the image (``None`` before two sets).

        ``sqrt(mean(var)) / sqrt(mean(L^2))`` over pixels and channels, ``var`` the
        variance of the mean of the sets' multiple-scattering terms (from their spread;
        the single term's jitter noise is left out), ``L`` the accumulated radiance.
        """
        n = self.passes
        if n < 2:
            return None
        mean = self._multiple / max(self._paths, 1)
        var = np.maximum(self._square / n - np.square(mean), 0.0) / (n - 1)
        image = self._single / n + mean
        power = float(np.mean(np.square(image)))
        return float(np.sqrt(np.mean(var) / power)) if power > 0 else 0.0

    def shrink(self, set_index: int) -> float:
        """Factor ``(s + 1)^-beta`` of the VSL radii of set ``s``."""
        return float((set_index + 1) ** (-self.opts["radius_exponent"]))

    # --- internals ------------------------------------------------------------------------
    def _render_set(self, state: ManyLightsState, s: int) -> None:
        o = self.opts
        params = gather_params(o["step_size"], o["jitter"],
                               stream_seed(o["seed"], s, PASS_SALT) & 0x7FFFFFFF,
                               o["early_termination"], o["view_samples"], o["transmittance"],
                               o["vl_step"], state.scale)
        t0 = time.perf_counter()
        vls = state.virtual_lights(state.radii(self.shrink(s)))
        single, multiple, alpha, _ = render_image(
            state.medium, self._cam, state.lights, vls, state.maps(), params, self.width,
            self.height, self.device)
        ms = 1e3 * (time.perf_counter() - t0)
        self.last["render_ms"] = ms
        self._render_ms += ms
        paths = max(state.vls.n_paths, 1)
        self._single += single
        self._alpha += alpha
        self._multiple += multiple * paths
        self._square += np.square(multiple, dtype=np.float64)
        self._paths += paths
        self.passes += 1


def parse_options(options: dict, volume, scene) -> dict:
    """Merge keyword options over the scene's ``many_lights`` section and validate them."""
    unknown = set(options) - set(DEFAULTS) - set(KEYWORDS)
    if unknown:
        raise ValueError(f"unknown many-lights option(s) {sorted(unknown)}; known: "
                         f"{sorted(set(DEFAULTS) | set(KEYWORDS))}")
    section = dict(getattr(scene, "options", {}).get("many_lights", {}))
    opts = dict(KEYWORDS)
    opts.update(DEFAULTS)
    opts.update({k: v for k, v in section.items() if k in DEFAULTS})
    opts.update(options)
    opts.update(ray_options({k: opts[k] for k in RAY_OPTIONS}, volume, scene))
    count = _positive_int(opts["count"], "many_lights.count",
                          " (use method 'single' for no multiple scattering)")
    opts["count"] = count
    sets = opts["sets"]
    if not _is_integral(sets) or int(sets) < 0:
        raise ValueError(f"many_lights.sets must be an integer >= 0 (0: automatic, until "
                         f"noise_target or time_budget), got {sets!r}")
    opts["sets"] = int(sets)
    for key in ("time_budget", "noise_target"):
        value = opts[key]
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or \
                not (np.isfinite(value) and value >= 0):
            raise ValueError(f"many_lights.{key} must be a number >= 0 (0: none), got "
                             f"{value!r}")
        opts[key] = float(value)
    opts["max_sets"] = _positive_int(opts["max_sets"], "many_lights.max_sets")
    _choice(opts, "virtual_lights", ("clamped", "spherical", "point"))
    _choice(opts, "transmittance", tuple(TRANSMITTANCE))
    _choice(opts, "avsm_lookup", tuple(FILTERS))
    _choice(opts, "distance_sampling", tuple(SAMPLING))
    _choice(opts, "phase_sampling", ("hg", "isotropic"))
    radius = opts["vsl_radius"]
    if isinstance(radius, bool) or not isinstance(radius, (int, float, np.floating)) or \
            not (np.isfinite(radius) and radius >= 0):
        raise ValueError(f"many_lights.vsl_radius must be a number of voxels >= 0 (0: "
                         f"automatic; use virtual_lights='point' for point lights), got "
                         f"{radius!r}")
    opts["vsl_radius"] = float(radius)
    opts["vsl_neighbours"] = _positive_int(opts["vsl_neighbours"], "many_lights.vsl_neighbours")
    mfp = opts["vsl_radius_mfp"]
    if isinstance(mfp, bool) or not isinstance(mfp, (int, float, np.floating)) or \
            not (np.isfinite(mfp) and mfp >= 0):
        raise ValueError(f"many_lights.vsl_radius_mfp must be a number >= 0 (0: no bound), "
                         f"got {mfp!r}")
    opts["vsl_radius_mfp"] = float(mfp)
    beta = opts["radius_exponent"]
    if isinstance(beta, bool) or not isinstance(beta, (int, float, np.floating)) or \
            not 0.0 <= beta < 1.0:
        raise ValueError(f"many_lights.radius_exponent must lie in [0, 1), got {beta!r}")
    opts["radius_exponent"] = float(beta)
    res = _positive_int(opts["avsm_resolution"], "many_lights.avsm_resolution")
    if not 2 <= res <= 1024:
        raise ValueError(f"many_lights.avsm_resolution must lie in [2, 1024] texels, got {res}")
    opts["avsm_resolution"] = res
    nodes = _positive_int(opts["avsm_nodes"], "many_lights.avsm_nodes")
    if not 2 <= nodes <= MAX_NODES:
        raise ValueError(f"many_lights.avsm_nodes (depth samples per texel) must lie in "
                         f"[2, {MAX_NODES}], got {nodes}")
    opts["avsm_nodes"] = nodes
    opts["view_samples"] = _positive_int(opts["view_samples"], "many_lights.view_samples")
    frac = opts["update_fraction"]
    if isinstance(frac, bool) or not isinstance(frac, (int, float, np.floating)) or \
            not 0.0 < frac <= 1.0:
        raise ValueError(f"many_lights.update_fraction must lie in (0, 1], got {frac!r}")
    opts["update_fraction"] = float(frac)
    budget = opts["update_budget"]
    if not _is_integral(budget) or int(budget) < 0:
        raise ValueError(f"many_lights.update_budget must be an integer >= 0 (0: no limit), "
                         f"got {budget!r}")
    opts["update_budget"] = int(budget)
    rng = opts["scale_range"]
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        lo = hi = float("nan")
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"many_lights.scale_range must be [S_min, S_max] with 0 < S_min <= "
                         f"S_max, got {rng!r}")
    opts["scale_range"] = (lo, hi)
    opts["density_scale"] = _positive_float(opts["density_scale"], "many_lights.density_scale")
    for key in ("vl_step", "avsm_step"):
        if opts[key] is not None:
            opts[key] = _positive_float(opts[key], key, " world units")
    opts["vl_step"] = opts["vl_step"] or opts["step_size"]
    opts["avsm_step"] = opts["avsm_step"] or float(np.min(volume.spacing))
    return opts


def _choice(opts: dict, key: str, choices: tuple) -> None:
    if opts[key] not in choices:
        raise ValueError(f"many_lights.{key} must be one of {list(choices)}, got {opts[key]!r}")


def _is_integral(value) -> bool:
    try:
        return not isinstance(value, bool) and float(value).is_integer()
    except (TypeError, ValueError, OverflowError):
        return False


def _positive_int(value, name: str, hint: str = "") -> int:
    if not _is_integral(value) or int(value) < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}{hint}")
    return int(value)


def _positive_float(value, name: str, hint: str = "") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if isinstance(value, bool) or not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive number{hint}, got {value!r}")
    return v
