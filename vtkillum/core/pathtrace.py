"""Unbiased reference: a progressive volumetric path tracer.

It solves the radiative transfer equation with the project's optical model
(``DESIGN.md``): grey extinction ``sigma_t(s)``, scattering
``sigma_s,c = albedo * color_c(s) * sigma_t``, the Henyey–Greenstein phase
function, directional and point lights. The background is not a light: the
radiance counts light that left a light and scattered at least once in the
volume, and ``alpha = 1 - T`` along the primary ray, so
``RenderResult.composite(background)`` puts the background behind it.

Estimators
----------
Paths start at the camera (jittered sub-pixel position) and walk backwards
towards the lights. At each step:

* **Free flight: delta (Woodcock) tracking** against the global majorant
  ``mu = max sigma_t`` (:attr:`Medium.majorant`). Tentative distances are drawn
  from ``mu exp(-mu t)``; a tentative point ``x`` is a real collision with
  probability ``sigma_t(x) / mu``. Real collisions are then distributed as
  ``sigma_t T``. A path that leaves the volume ends (the background emits
  nothing).
* **Collision weight.** Every real collision scatters, and the throughput is
  multiplied by the single-scattering albedo colour
  ``sigma_s,c / sigma_t = albedo * color_c(s)`` (absorption as a weight rather
  than as path termination, so RGB colours need no spectral sampling).
* **Next-event estimation** at every scattering vertex to every light:
  ``throughput * p(theta) * E * T_shadow`` with ``E`` the light's irradiance
  (``I / d^2`` for point lights), ``theta`` between the light's travel direction
  and the direction towards the previous vertex (the camera for the first one),
  and ``T_shadow`` estimated by **ratio tracking** (product of
  ``1 - sigma_t / mu`` over majorant-rate tentative points up to the box exit or
  the point light). Lights are deltas, so NEE is their only contribution and
  there is nothing to weight with MIS.
* **Direction sampling** from the HG phase function itself (``sample_hg``), whose
  weight ``p / pdf`` is exactly 1.
* ``max_bounces`` is the number of scattering vertices that receive NEE;
  ``max_bounces = 1`` is single scattering and the estimate is then unbiased for
  the radiance of paths with at most ``max_bounces`` scattering events. The
  default, ``max_bounces = 0``, is **unlimited**: only Russian roulette ends a
  walk, so the estimate is unbiased for the full radiative transfer equation.
  A safety cap of :data:`MAX_PATH_VERTICES` vertices still bounds a walk (a
  medium of albedo 1 with no exit would otherwise never end); walks that reach
  it are counted and reported in ``info["capped_paths"]`` (with a warning), so
  a truncated estimate is never silent.
* **Russian roulette** from the ``RR_START``-th vertex on: the walk continues to
  the next vertex with probability ``q = min(1, max_c throughput_c)`` and the
  throughput is divided by ``q`` (unbiased; a path whose weight has dropped to
  ``w < 1`` survives with probability ``w`` and then carries weight 1).
  Shadow rays use a weight-window roulette: when their running transmittance
  ``T`` drops below ``SHADOW_RR_THRESHOLD`` they survive with probability
  ``T / threshold`` and carry on with ``T = threshold`` (unbiased too).
* **Alpha**: ratio tracking along the whole primary ray (no roulette), an
  unbiased estimate of the transmittance ``T`` in [0, 1]; ``alpha = 1 - T``.
  This costs one extra traversal per sample but has far less variance than the
  fraction of primary paths that collide.

Random numbers: each kernel launch ("pass") seeds one PCG stream per pixel with
``wp.rand_init(hash(seed, pass), pixel)``, so a fixed seed gives bit-identical
images on one device, and passes are independent.

Guards: delta and ratio tracking take about ``majorant × length`` steps per traversal,
so a medium whose optical depth across the box (majorant × diagonal) exceeds
:data:`MAX_OPTICAL_DEPTH` is refused with the smallest usable opacity unit distance, and
so is a camera so far away that float32 distances along its rays cannot resolve a mean
free path (``t + step == t`` would never end a traversal). On the CPU a pass is launched
in bands of rows (or parts of a row) of about :data:`BAND_EVENTS` estimated events, so
Ctrl-C is seen between launches.

Accumulation is in float64 on the device (running sums of radiance, its square
and alpha), so thousands of passes lose no precision; :attr:`PathTracer.radiance`
is the running mean.
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.render import RenderResult
from vtkillum.core.units import canonical
from vtkillum.core.warp_common import (
    CameraParams,
    Lights,
    Medium,
    camera_ray,
    free_path,
    hg_phase,
    light_incidence,
    lookup_color,
    lookup_sigma_t,
    make_camera,
    make_lights,
    make_medium,
    ray_box,
    sample_hg,
    sample_scalar,
    sigma_t_at,
    stream_seed,
    uniform,
)

#: Russian roulette on the path starts after this many scattering vertices.
RR_START = wp.constant(3)
#: Safety cap on the scattering vertices of one walk when ``max_bounces`` is unlimited (0).
MAX_PATH_VERTICES = 100_000
#: Shadow-ray transmittance below which weight-window roulette kicks in.
SHADOW_RR_THRESHOLD = wp.constant(0.1)
#: Salt of the per-pass seeds (keeps them apart from other estimators' streams).
PASS_SALT = 0x165667B1
#: Largest optical depth of the majorant across the volume's diagonal: delta and ratio
#: tracking take about that many steps per traversal (cf. ``MAX_STEPS_PER_RAY``).
MAX_OPTICAL_DEPTH = 1 << 20
#: Largest ``majorant × distance`` from the camera to the volume's far corner: beyond it
#: a mean free path is below one float32 ulp of the distances along camera rays.
MAX_FREE_PATHS_FROM_CAMERA = 1 << 23
#: Estimated tracking events per kernel launch (``(2 + lights) (1 + optical depth)`` per
#: sample): CPU launches stay well under a second, so Ctrl-C is seen between them.
BAND_EVENTS = {"cpu": 1 << 23, "cuda": 1 << 40}


def render_path(volume, scene, width: int, height: int, device: str | None = None, progress=None,
                spp: int | None = None, max_bounces: int | None = None, seed: int | None = None,
                **options) -> RenderResult:
    """Path-trace ``volume`` with ``spp`` samples per pixel (the ``"path"`` method).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
        Optical model, lights and camera; ``scene.options["path"]`` gives the defaults
        of ``spp`` (64), ``max_bounces`` (0: unlimited) and ``seed`` (0).
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device (see :func:`vtkillum.core.device.resolve_device`).
    progress : callable, optional
        Called as ``progress(fraction_done)`` after each pass (one sample per pixel).
    spp : int, optional
        Samples per pixel.
    max_bounces : int, optional
        Maximum number of scattering vertices receiving next-event estimation (1: single
        scattering); 0 (the default) leaves the walk to Russian roulette alone, up to the
        safety cap :data:`MAX_PATH_VERTICES`.
    seed : int, optional
        Random seed; the same seed gives the same image on one device.

    Returns
    -------
    RenderResult
        Linear radiance (H, W, 3), alpha = 1 - transmittance (H, W), and ``info`` with
        ``spp``, ``max_bounces``, ``seed``, ``ms_per_pass``, ``samples_per_second`` (camera
        paths per second, all pixels), ``capped_paths`` (walks that reached the safety cap;
        0 unless ``max_bounces`` is unlimited and the medium hardly absorbs) and, from two
        passes on, the per-pixel ``radiance_variance`` of the mean (H, W, 3).
    """
    if options:
        raise ValueError(
            f"path: unknown option(s) {sorted(options)}; the path tracer takes spp, "
            "max_bounces and seed"
        )
    defaults = scene.options["path"]
    spp = _positive_int(defaults["spp"] if spp is None else spp, "spp")
    max_bounces = _bounce_limit(defaults["max_bounces"] if max_bounces is None else max_bounces)
    seed = _int(defaults["seed"] if seed is None else seed, "seed")
    tracer = PathTracer(volume, scene, width, height, device=device, seed=seed,
                        max_bounces=max_bounces)
    for i in range(spp):
        tracer.run(1)
        if progress is not None:
            progress((i + 1) / spp)
    return tracer.result()


class PathTracer:
    """Progressive path tracer: accumulate passes of one sample per pixel, read the mean.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
        Transfer function, unit distance, albedo, anisotropy, lights and camera
        (``scene.resolved_camera(volume)`` when it has none).
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device.
    seed : int
        Random seed (pass ``p`` of pixel ``i`` uses ``rand_init(hash(seed, p), i)``).
    max_bounces : int
        Maximum number of scattering vertices receiving next-event estimation; 0
        (default): unlimited, walks end by Russian roulette (or at the safety cap
        :data:`MAX_PATH_VERTICES`, counted in :attr:`capped_paths`).
    samples_per_pass : int
        Samples per pixel taken by one kernel launch (more per launch amortises launch
        overhead on a GPU; the variance estimate then is over per-pass means).

    Attributes
    ----------
    units : vtkillum.core.units.WorldUnits
        The tracer works in canonical units (any world length scale gives the same image);
        cameras given to :meth:`reset` are in world units.

    Examples
    --------
    >>> tracer = PathTracer(volume, scene, 64, 64, seed=1)      # doctest: +SKIP
    >>> tracer.run(16).radiance.shape                            # doctest: +SKIP
    (64, 64, 3)
    """

    def __init__(self, volume, scene, width: int, height: int, device: str | None = None,
                 seed: int = 0, max_bounces: int = 0, samples_per_pass: int = 1) -> None:
        self.device = resolve_device(device)
        self.width = _positive_int(width, "width")
        self.height = _positive_int(height, "height")
        self.seed = _int(seed, "seed")
        self.max_bounces = _bounce_limit(max_bounces)
        self.samples_per_pass = _positive_int(samples_per_pass, "samples_per_pass")
        # Trace in canonical units (vtkillum.core.units): any world length scale works.
        camera = scene.resolved_camera(volume)
        volume, scene, _, self.units = canonical(volume, scene)
        with self.units.explained():
            self._setup(volume, scene, camera)

    def _setup(self, volume, scene, camera) -> None:
        self._volume = volume
        self._n_lights = len(scene.lights)
        self._torn = False
        self.medium = make_medium(
            volume, scene.resolved_transfer_function(volume), scene.resolved_unit_distance(volume),
            scene.albedo, scene.anisotropy, self.device,
        )
        self._unit_distance = scene.resolved_unit_distance(volume)
        self._transfer_function = scene.resolved_transfer_function(volume)
        self._check_optical_depth()
        self.lights = make_lights(scene.lights, volume, self.device)
        shape = (self.height, self.width)
        self._sum = wp.zeros(shape, dtype=wp.vec3d, device=self.device)
        self._sum2 = wp.zeros(shape, dtype=wp.vec3d, device=self.device)
        self._sum_alpha = wp.zeros(shape, dtype=wp.float64, device=self.device)
        self._capped = wp.zeros(1, dtype=wp.int64, device=self.device)
        self._seconds = 0.0
        # Compile/load the kernels now so that the first pass's timing is the kernel's own.
        wp.load_module(sys.modules[__name__], device=self.device)
        self.reset(camera)

    # --- progressive accumulation --------------------------------------------------------
    def reset(self, camera=None) -> "PathTracer":
        """Discard the accumulated samples (and pass counter); optionally move the camera.

        Parameters
        ----------
        camera : vtkillum.core.camera.Camera, optional
            New camera (world units); the current one is kept when omitted.
        """
        if camera is not None:
            if not callable(getattr(camera, "basis", None)):
                raise ValueError(
                    f"camera must be a vtkillum.core.camera.Camera, got {type(camera).__name__}; "
                    "convert a vtkCamera with its position, focal point, view up and view angle"
                )
            cam = make_camera(self.units.camera(camera), self._volume, self.width, self.height)
            with self.units.explained():
                self._check_camera_distance(cam)
            self.camera = camera
            self._cam: CameraParams = cam
        self._sum.zero_()
        self._sum2.zero_()
        self._sum_alpha.zero_()
        self._capped.zero_()
        self._torn = False
        self.passes = 0
        self._seconds = 0.0
        return self

    def run(self, passes: int = 1) -> "PathTracer":
        """Add ``passes`` passes of ``samples_per_pass`` samples per pixel.

        A pass is one kernel launch, or on the CPU several over bands of the image (see
        :meth:`bands`); a pass interrupted (Ctrl-C) between them is not counted, and the
        tracer must be :meth:`reset` before it is used again.
        """
        passes = _positive_int(passes, "passes")
        self._check_whole()
        start = time.perf_counter()
        bands = self.bands()
        for _ in range(passes):
            seed = stream_seed(self.seed, self.passes, PASS_SALT)
            self._torn = len(bands) > 1
            for row0, col0, rows, cols in bands:
                wp.launch(
                    path_trace_kernel,
                    dim=(rows, cols),
                    inputs=[self.medium, self._cam, self.lights, seed, self.samples_per_pass,
                            self._vertex_limit, row0, col0, self._sum, self._sum2,
                            self._sum_alpha, self._capped],
                    device=self.device,
                )
            self._torn = False
            self.passes += 1
        wp.synchronize_device(self.device)
        self._seconds += time.perf_counter() - start
        return self

    def bands(self) -> list:
        """``(row0, col0, rows, cols)`` of the launches of one pass.

        The whole image on CUDA; on the CPU bands of whole rows, or parts of a row, of
        about :data:`BAND_EVENTS` estimated events each.
        """
        events = (2 + self._n_lights) * (1.0 + self.optical_depth) \
            * self.samples_per_pass
        budget = BAND_EVENTS["cpu" if self.device == "cpu" else "cuda"]
        pixels = max(1, int(min(budget / events, self.width * self.height)))
        if pixels >= self.width:
            rows = min(self.height, pixels // self.width)
            return [(r, 0, min(rows, self.height - r), self.width)
                    for r in range(0, self.height, rows)]
        return [(r, c, 1, min(pixels, self.width - c)) for r in range(self.height)
                for c in range(0, self.width, pixels)]

    @property
    def optical_depth(self) -> float:
        """The majorant's optical depth across the volume's diagonal."""
        return float(self.medium.majorant) * float(np.linalg.norm(self._volume.extent))

    def _check_optical_depth(self) -> None:
        tau = self.optical_depth
        if tau <= MAX_OPTICAL_DEPTH:
            return
        smallest = _round_up(self._depth_at_unit_distance_one() / MAX_OPTICAL_DEPTH)
        raise ValueError(
            f"path: opacity_unit_distance {self._unit_distance:g} makes the medium "
            f"{tau:.3g} mean free paths deep across the volume (majorant x diagonal); delta "
            f"tracking takes about that many steps per ray and at most {MAX_OPTICAL_DEPTH} "
            f"are allowed: use an opacity_unit_distance of at least {smallest:.3g} world units "
            "(or a lower opacity)"
        )

    def _depth_at_unit_distance_one(self) -> float:
        """The optical depth with ``opacity_unit_distance = 1`` (it scales as ``1 / u``)."""
        tau = self.optical_depth
        if np.isfinite(tau):
            return tau * self._unit_distance
        sig, _, _, _ = self._transfer_function.lookup_tables(1.0, self._volume.value_range)
        return float(np.max(sig)) * 1.0001 * float(np.linalg.norm(self._volume.extent))

    def _check_camera_distance(self, cam: CameraParams) -> None:
        corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)],
                           dtype=np.float64) * np.asarray(self._volume.extent, dtype=np.float64)
        far = float(np.linalg.norm(corners - np.asarray(cam.position, np.float64), axis=1).max())
        majorant = float(self.medium.majorant)
        if majorant * far <= MAX_FREE_PATHS_FROM_CAMERA:
            return
        closest = MAX_FREE_PATHS_FROM_CAMERA / majorant
        raise ValueError(
            f"path: the camera is {far:.3g} world units from the volume's far corner, "
            f"{majorant * far:.3g} mean free paths of the densest medium; float32 distances "
            f"along camera rays cannot resolve them beyond {MAX_FREE_PATHS_FROM_CAMERA}: move "
            f"the camera closer (within {closest:.3g} world units of every corner, e.g. a "
            "smaller distance with a wider view angle or parallel scale) or raise "
            "opacity_unit_distance"
        )

    def _check_whole(self) -> None:
        if self._torn:
            raise RuntimeError("a pass of this PathTracer was interrupted part-way (its sums "
                               "hold part of a pass); call reset() before using it again")

    @property
    def _vertex_limit(self) -> int:
        return self.max_bounces if self.max_bounces > 0 else MAX_PATH_VERTICES

    @property
    def capped_paths(self) -> int:
        """Walks that reached the safety cap :data:`MAX_PATH_VERTICES` (unlimited mode only)."""
        return int(self._capped.numpy()[0]) if self.max_bounces == 0 else 0

    @property
    def samples(self) -> int:
        """Samples per pixel accumulated so far."""
        return self.passes * self.samples_per_pass

    @property
    def radiance(self) -> np.ndarray:
        """Running mean of the radiance, (H, W, 3) float32 (zeros before the first pass)."""
        self._check_whole()
        return (self._sum.numpy() / max(self.passes, 1)).astype(np.float32)

    @property
    def alpha(self) -> np.ndarray:
        """Running mean of ``1 - T`` along the primary rays, (H, W) float32."""
        self._check_whole()
        return (self._sum_alpha.numpy() / max(self.passes, 1)).astype(np.float32)

    @property
    def radiance_variance(self) -> np.ndarray:
        """Estimated variance of :attr:`radiance` (of the mean), (H, W, 3) float64.

        ``(mean of squares - square of mean) / (passes - 1)`` over per-pass values; needs two
        passes at least.
        """
        self._check_whole()
        n = self.passes
        if n < 2:
            raise ValueError("the variance needs at least two passes; call run(2) first")
        mean = self._sum.numpy() / n
        var = np.maximum(self._sum2.numpy() / n - mean * mean, 0.0) * n / (n - 1)
        return var / n

    def result(self) -> RenderResult:
        """The current image as a :class:`~vtkillum.core.render.RenderResult`."""
        pixels = self.width * self.height * self.samples
        info = {
            "method": "path",
            "spp": self.samples,
            "passes": self.passes,
            "max_bounces": self.max_bounces,
            "seed": self.seed,
            "device": self.device,
            "ms_per_pass": 1000.0 * self._seconds / max(self.passes, 1),
            "samples_per_second": pixels / self._seconds if self._seconds > 0 else float("nan"),
            "capped_paths": self.capped_paths,
        }
        if info["capped_paths"]:
            warnings.warn(
                f"path: {info['capped_paths']} of {pixels} walks reached the safety cap of "
                f"{MAX_PATH_VERTICES} scattering vertices (albedo near 1 in a closed medium); "
                "their light beyond it is missing", RuntimeWarning, stacklevel=2)
        if self.passes >= 2:
            info["radiance_variance"] = self.radiance_variance  # float64: squares of huge lights
        return RenderResult(self.radiance, self.alpha, self.units.info(info))


def _round_up(x: float, digits: int = 3) -> float:
    """``x`` rounded up to ``digits`` significant digits (so that the printed value works)."""
    scale = 10.0 ** (digits - 1 - int(np.floor(np.log10(x))))
    return float(np.ceil(x * scale * (1 - 1e-12)) / scale)


def _is_integral(value) -> bool:
    try:
        return not isinstance(value, bool) and float(value).is_integer()
    except (TypeError, ValueError, OverflowError):
        return False


def _bounce_limit(value) -> int:
    if not _is_integral(value) or int(value) < 0:
        raise ValueError(
            f"max_bounces must be a non-negative integer (0: unlimited), got {value!r}")
    return int(value)


def _positive_int(value, name: str) -> int:
    if not _is_integral(value) or int(value) < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _int(value, name: str) -> int:
    if not _is_integral(value):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


# --- kernels and device functions ---------------------------------------------------------------
@wp.func
def delta_tracking(m: Medium, o: wp.vec3, d: wp.vec3, t_start: float, t_end: float,
                   state: wp.uint32):
    """Sample a real collision on ``o + t d``, ``t`` in ``(t_start, t_end)``.

    Returns ``(collided, t, scalar value at the collision, state)``.
    """
    t = t_start
    while True:
        step, state = free_path(m.majorant, state)
        t = t + step
        if t >= t_end:
            return False, t_end, 0.0, state
        s = sample_scalar(m.scalars, m.inv_spacing, o + t * d)
        u, state = uniform(state)
        if u * m.majorant < lookup_sigma_t(m, s):
            return True, t, s, state
    return False, t_end, 0.0, state


@wp.func
def ratio_tracking(m: Medium, o: wp.vec3, d: wp.vec3, t_start: float, t_end: float,
                   roulette: int, state: wp.uint32):
    """Transmittance estimate along ``o + t d`` for ``t`` in ``(t_start, t_end)``.

    With ``roulette != 0`` a weight-window Russian roulette ends hopeless estimates early.
    Returns ``(T, state)``.
    """
    T = float(1.0)
    t = t_start
    while True:
        step, state = free_path(m.majorant, state)
        t = t + step
        if t >= t_end:
            return T, state
        T = T * wp.max(0.0, 1.0 - sigma_t_at(m, o + t * d) / m.majorant)
        if roulette != 0 and T < SHADOW_RR_THRESHOLD:
            u, state = uniform(state)
            if u * SHADOW_RR_THRESHOLD >= T:
                return 0.0, state
            T = SHADOW_RR_THRESHOLD
    return T, state


@wp.func
def trace_path(m: Medium, lights: Lights, o: wp.vec3, d: wp.vec3, max_bounces: int,
               state: wp.uint32):
    """One camera path: returns ``(radiance, primary transmittance, capped, state)``.

    ``capped`` is 1 when the walk was still alive after ``max_bounces`` vertices.
    """
    radiance = wp.vec3(0.0)
    box = ray_box(o, d, m.extent)
    t_start = wp.max(box[0], 0.0)
    t_end = box[1]
    if t_end <= t_start:
        return radiance, 1.0, 0, state
    T_primary, state = ratio_tracking(m, o, d, t_start, t_end, 0, state)

    throughput = wp.vec3(1.0)
    x = o
    capped = int(0)
    for bounce in range(max_bounces):
        hit, t, s, state = delta_tracking(m, x, d, t_start, t_end, state)
        if not hit:
            break
        x = x + t * d
        throughput = wp.cw_mul(throughput, m.albedo * lookup_color(m, s))
        if wp.max(throughput[0], wp.max(throughput[1], throughput[2])) <= 0.0:
            break
        # Next-event estimation: light arrives travelling along -wl and leaves towards -d,
        # so cos(theta) = dot(-wl, -d) = dot(wl, d).
        for li in range(lights.count):
            wl, dist, irradiance = light_incidence(lights, li, x)
            shadow_box = ray_box(x, wl, m.extent)
            T_light, state = ratio_tracking(m, x, wl, 0.0, wp.min(shadow_box[1], dist), 1, state)
            if T_light > 0.0:
                radiance = radiance + (T_light * hg_phase(wp.dot(wl, d), m.g)) * wp.cw_mul(
                    throughput, irradiance)
        if bounce + 1 >= max_bounces:
            capped = 1
            break
        if bounce + 1 >= RR_START:
            q = wp.min(1.0, wp.max(throughput[0], wp.max(throughput[1], throughput[2])))
            u, state = uniform(state)
            if u >= q:
                break
            throughput = throughput / q
        # New path direction d' with pdf p(dot(d, d')): the light scattered towards -d
        # arrived travelling along -d', and dot(-d', -d) = dot(d, d').
        u1, state = uniform(state)
        u2, state = uniform(state)
        d = sample_hg(d, m.g, u1, u2)
        t_start = 0.0
        t_end = ray_box(x, d, m.extent)[1]
    return radiance, T_primary, capped, state


@wp.kernel
def path_trace_kernel(m: Medium, cam: CameraParams, lights: Lights, seed: int, spp: int,
                      max_bounces: int, row0: int, col0: int,
                      sum_radiance: wp.array2d(dtype=wp.vec3d),
                      sum_radiance2: wp.array2d(dtype=wp.vec3d),
                      sum_alpha: wp.array2d(dtype=wp.float64),
                      capped_paths: wp.array(dtype=wp.int64)):
    """One pass of ``spp`` camera paths per pixel, added to the running sums.

    ``wp.tid()`` is ``(row - row0, col - col0)`` of the image, row 0 at the top (a pass
    may be launched in bands; each pixel's stream depends only on ``(row, col)``). Radiance is in the
    lights' units (irradiance E, or I / d^2, per steradian through the phase function);
    ``sum_radiance2`` accumulates the square of the per-pass mean (for the variance);
    ``capped_paths[0]`` counts walks still alive after ``max_bounces`` vertices.
    """
    r, c = wp.tid()
    row = row0 + r
    col = col0 + c
    state = wp.rand_init(seed, row * cam.width + col)
    total = wp.vec3(0.0)
    alpha = float(0.0)
    for _ in range(spp):
        jx, state = uniform(state)
        jy, state = uniform(state)
        o, d = camera_ray(cam, float(col) + jx, float(row) + jy)
        radiance, T, capped, state = trace_path(m, lights, o, d, max_bounces, state)
        if capped != 0:
            wp.atomic_add(capped_paths, 0, wp.int64(1))
        total = total + radiance
        alpha = alpha + (1.0 - T)
    mean = total / float(spp)
    md = wp.vec3d(wp.float64(mean[0]), wp.float64(mean[1]), wp.float64(mean[2]))
    sum_radiance[row, col] = sum_radiance[row, col] + md
    sum_radiance2[row, col] = sum_radiance2[row, col] + wp.cw_mul(md, md)
    sum_alpha[row, col] = sum_alpha[row, col] + wp.float64(alpha / float(spp))
