"""Device memory of every rendering method: an estimate before allocating, and a clear refusal.

A render allocates its device state on first use: the scalars, block occupancy, light
grids, solver work arrays, caches, image buffers. :func:`estimate_bytes` adds up the peak
of that state from the volume's dimensions, the light count, the light-grid scale and the
image size; :func:`check_fits` compares it with the memory the device has free and, when
it does not fit, raises :class:`DeviceMemoryError` *before* anything is allocated, naming
the method, the bytes needed and free, the largest cube that fits and the way down
(``light_volume_scale`` in core, the CLI and pyvista; ``OutputScale`` in ParaView).
:func:`largest_cube` answers "what is the largest volume this method handles here".

The model
---------
Peak bytes ``= d N + l N_l + p L N_l + q P + c`` with ``N`` the data's points, ``N_l`` the
points of the method's light grid (``scale³ N``: ``light_volume_scale`` or, for
ambient scattering, ``radiance_cache_scale``), ``L`` the lights, ``P`` the image's pixels
and ``c`` what does not grow with them (tables, photon maps, shadow-map pools). The
coefficients (:data:`FOOTPRINTS`) come from the methods' allocations:

==========================  =========================================================
method                      where the bytes are (B per point unless stated)
==========================  =========================================================
emission, single            scalars (4); block ranges and occupancy (2 floats + 1 int
                            per 8³ block); radiance + alpha + sample count (20 B/pixel)
path                        as above plus the accumulation buffers (56 B/pixel measured)
transmittance               scalars (4); per light a float32 transmittance grid (4 per
                            light-grid point); the RGB fluence grid (vec3, 12) that the
                            light pass writes alongside; on CUDA the ray caster's
                            textures of the scalars (4) and the light grids (4 per
                            light-grid point and light; convection-diffusion's RGBA-half
                            fluence: 8 more)
convection-diffusion        scalars (4); the solver's grids of the light-grid shape:
                            σt and σ·colour (4 + 12), the convection and diffusion
                            sources, solution, residual and estimate (vec3), the
                            first-moment grids, Anderson history, multigrid levels
                            (1/7 more) and the ray-march stacks: 352 B per light-grid
                            point with one light (that sum is measured, see below),
                            plus a transmittance grid per light (12 B: T and its
                            composed RGB)
ambient-scattering          scalars, σt, σ̃t, a temporary of the separable passes and
                            a σ work grid (4 each): 20; per light an RGB
                            radiance cache (12 per cache point); on CUDA the two-channel
                            data texture and its staging array (8 + 8); the
                            preintegration table (~2.7 MB)
photon                      scalars and the hash grid's cells (16 measured); the photon
                            map (up to ``MAX_PHOTONS`` paths × ~146 B: interaction
                            records, scratch and path arrays, measured at the
                            automatic photon count); view segments (``segments`` × 40
                            B/pixel) and the image
many-lights                 scalars (4); the AVSM pool (``count`` × 6 res² × nodes × 8 B,
                            grown by 1.5×), the view samples (``view_samples`` × 24
                            B/pixel) and the virtual-light walks (a fixed ~220 MB
                            measured at the default 1024 lights)
refraction                  scalars (4); the light planes: ``1.25 × texels`` of a ring
                            of ``l``/``v`` planes (24 B a texel and plane, 17 planes on
                            the CPU, 33 on CUDA, at most 4 GiB) and two layers of
                            ``g``/``p``/``o`` (72 B); ``texels ≈ 2.5 P`` (the light
                            grid's texel is the image's footprint); 92 B/pixel of view
                            state
==========================  =========================================================

Verification: :func:`track_allocations` counts warp's allocations on a device (the CPU
device has no memory pool to ask); ``tests/core/test_memory.py`` renders at two sizes on
the CPU and checks the estimate against the measured peak. Measured on the CPU device
(smoke plume, one light, 16² image; peak of warp allocations / estimate): transmittance
32³ and 48³ 0.99 and 1.00, convection-diffusion (scale 0.5) 0.98 and 1.00, ambient 1.0.

What is simplified: the estimate is the sum of a method's stages' arrays, not the exact
peak of their overlap (photon: trace and segments are counted together: an
overestimate); CUDA textures are counted where the code makes them (ambient's data
texture) but not the driver's own overheads; the photon map and the many-lights walks
depend on the data (how many interactions a photon has) and are taken at the measured
values of the default settings (their own allocators refuse a map that does not fit:
``photon.memory_limit_mb``, the AVSM pool's ``MemoryError``); refraction's texel count
is the typical ``2.5 P``, not its bound ``max(4 P, 65536)``. Caches other than the
volume's own (the ambient default cache holding the previous volume) are not counted:
they hold memory the device reports as not free, so the check stays conservative.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

#: Share of the free memory a render may plan to use (allocators round up; the driver and
#: other processes take some while it runs).
USABLE_FRACTION = 0.9

#: Default light-grid scale per method (what the method uses when not told).
DEFAULT_SCALES = {"transmittance": 1.0, "convection-diffusion": 0.5, "ambient-scattering": 0.5}

#: Cells per block edge of the empty-space grid (``vtkillum.core.empty_space.BLOCK``).
_BLOCK = 8


@dataclass(frozen=True)
class Footprint:
    """Bytes a method holds at its peak, by what they grow with.

    Attributes
    ----------
    data : float
        Bytes per data point.
    light : float
        Bytes per light-grid point (independent of the light count).
    per_light : float
        Bytes per light-grid point and light.
    pixel : float
        Bytes per image pixel.
    fixed : float
        Bytes that grow with none of these.
    """

    data: float
    light: float = 0.0
    per_light: float = 0.0
    pixel: float = 20.0
    fixed: float = 0.0


#: Footprints at the default options (see the module docstring for where they come from).
FOOTPRINTS = {
    "emission": Footprint(4.0),
    "single": Footprint(4.0),
    "illumination": Footprint(4.0, per_light=4.0, light=12.0),
    "path": Footprint(4.0, pixel=56.0),
    "transmittance": Footprint(4.0, light=12.0, per_light=4.0),
    "convection-diffusion": Footprint(4.0, light=352.0, per_light=12.0),
    "ambient-scattering": Footprint(20.0, per_light=12.0, fixed=2.7e6),
    "photon": Footprint(16.0, pixel=20.0 + 8 * 40.0, fixed=146e6),
    "many-lights": Footprint(4.0, pixel=20.0 + 4 * 24.0, fixed=220e6),
    "refraction": Footprint(4.0, pixel=92.0, fixed=0.4e6),
}

#: Methods whose light grid ``light_volume_scale`` sets (the way down named in errors).
SCALED = ("transmittance", "convection-diffusion")


class DeviceMemoryError(MemoryError):
    """A render that would not fit in the device's free memory (raised before allocating)."""


def _points(dims) -> int:
    return int(np.prod([int(n) for n in dims]))


def _scaled_points(dims, scale: float) -> int:
    """Points of a grid scaled by ``scale`` (``vtkillum.core.resample.scaled_shape``)."""
    from vtkillum.core.resample import scaled_shape

    return _points(scaled_shape(tuple(int(n) for n in dims), float(scale)))


def _blocks(dims) -> int:
    return _points([max(1, -(-(int(n) - 1) // _BLOCK)) for n in dims])


def estimate_bytes(method: str, dims, n_lights: int = 1, light_volume_scale: float | None = None,
                   options: dict | None = None, image=(1024, 1024),
                   device: str = "cuda") -> int:
    """Peak device bytes of a first render with ``method`` (see the module docstring).

    Parameters
    ----------
    method : str
        A registered method (:data:`vtkillum.core.render.METHODS`).
    dims : (3,) int
        Data points along x, y, z.
    n_lights : int
        Lights in the scene.
    light_volume_scale : float, optional
        Light-grid resolution relative to the data (``transmittance``,
        ``convection-diffusion``); default the method's (:data:`DEFAULT_SCALES`).
    options : dict, optional
        Method options that change the footprint: ``radiance_cache_scale`` and
        ``data_textures`` (ambient), ``photons`` and ``segments`` (photon), ``count``,
        ``avsm_resolution``, ``avsm_nodes`` and ``view_samples`` (many-lights).
    image : (int, int)
        Image width and height in pixels.
    device : str
        ``"cpu"`` or a CUDA device (CUDA-only textures and ring sizes differ).

    Returns
    -------
    int
        Bytes.
    """
    if method not in FOOTPRINTS:
        raise ValueError(f"no memory model for method {method!r}; known: {sorted(FOOTPRINTS)}")
    opts = dict(options or {})
    f = FOOTPRINTS[method]
    cuda = str(device).startswith("cuda")
    n = _points(dims)
    pixels = int(image[0]) * int(image[1])
    lights = max(1, int(n_lights))
    total = f.data * n + 12.0 * _blocks(dims) + f.pixel * pixels + f.fixed
    if method in ("transmittance", "convection-diffusion", "ambient-scattering", "illumination"):
        if method == "ambient-scattering":
            scale = float(opts.get("radiance_cache_scale", DEFAULT_SCALES[method]))
            if cuda and opts.get("data_textures", True):
                total += 16.0 * n
        else:
            scale = DEFAULT_SCALES.get(method, 1.0) if light_volume_scale is None \
                else float(light_volume_scale)
        nl = _scaled_points(dims, scale)
        total += (f.light + f.per_light * lights) * nl
        if method != "ambient-scattering":  # the illumination ray caster's textures
            if cuda and opts.get("textures", True) is not False:
                # textures of the scalars and the light grids (and the RGBA-half fluence)
                total += 4.0 * n + 4.0 * lights * nl
                if method == "convection-diffusion":
                    total += 8.0 * nl
    if method == "photon":
        photons = int(opts.get("photons", 0) or 0)
        if photons:  # the fixed part was measured at the automatic count's ceiling
            from vtkillum.core.photon.radius import MAX_PHOTONS

            total += f.fixed * (photons / MAX_PHOTONS - 1.0)
        total += (int(opts.get("segments", 8)) - 8) * 40.0 * pixels
    if method == "many-lights":
        count = int(opts.get("count", 1024))
        res = int(opts.get("avsm_resolution", 16))
        nodes = int(opts.get("avsm_nodes", 8))
        capacity = max(16, count)
        total += 1.5 * capacity * 6 * res * res * nodes * 8.0  # pool grown by 1.5x
        total += (int(opts.get("view_samples", 4)) - 4) * 24.0 * pixels
        total += (count / 1024.0 - 1.0) * f.fixed
    if method == "refraction":
        texels = 1.25 * 2.5 * pixels + 64
        ring = 33 if cuda else 17
        total += min(ring * 24.0 * texels, float(4 << 30)) + 72.0 * texels
    return math.ceil(total)


def free_device_bytes(device: str) -> int | None:
    """Bytes a new allocation can still get on ``device`` (CUDA: the device's free memory;
    CPU: the host's available memory), ``None`` when unknown."""
    from vtkillum.core.device import available_memory

    host, gpu = available_memory(device)
    return gpu if str(device).startswith("cuda") else host


def largest_cube(method: str, free_bytes: float, n_lights: int = 1,
                 light_volume_scale: float | None = None, options: dict | None = None,
                 image=(1024, 1024), device: str = "cuda") -> int:
    """Largest edge ``n`` of an ``n³`` volume whose estimate fits in ``free_bytes``
    (:data:`USABLE_FRACTION` of it); 0 when not even 2³ fits."""
    budget = USABLE_FRACTION * float(free_bytes)

    def fits(edge):
        return estimate_bytes(method, (edge,) * 3, n_lights, light_volume_scale, options,
                              image, device) <= budget

    if not fits(2):
        return 0
    lo, hi = 2, 4
    while fits(hi) and hi < 1 << 20:
        lo, hi = hi, hi * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return lo


def largest_cubes(free_bytes: float, methods=None, n_lights: int = 1,
                  image=(1024, 1024), device: str = "cuda") -> dict:
    """``{method: largest cube edge}`` for ``free_bytes`` at default options."""
    methods = list(methods or [m for m in FOOTPRINTS if m != "illumination"])
    return {m: largest_cube(m, free_bytes, n_lights, image=image, device=device)
            for m in methods}


def check_fits(method: str, dims, n_lights: int = 1, light_volume_scale: float | None = None,
               options: dict | None = None, image=(1024, 1024), device: str = "cuda",
               free_bytes: int | None = None, held_bytes: int = 0) -> int:
    """Refuse, before allocating, a render that would not fit on ``device``.

    Parameters
    ----------
    method, dims, n_lights, light_volume_scale, options, image, device
        As :func:`estimate_bytes`.
    free_bytes : int, optional
        Free memory to plan with; default :func:`free_device_bytes` (nothing is checked
        when it is unknown).
    held_bytes : int
        Bytes of the estimate already on the device (a volume whose scalars were uploaded
        before): they count as free.

    Returns
    -------
    int
        The estimate, in bytes.

    Raises
    ------
    DeviceMemoryError
        When the estimate exceeds :data:`USABLE_FRACTION` of the free memory; the message
        names the method, the bytes needed and free, the largest cube that fits and
        ``light_volume_scale`` / ``OutputScale`` as the way down.
    """
    need = estimate_bytes(method, dims, n_lights, light_volume_scale, options, image, device)
    free = free_device_bytes(device) if free_bytes is None else int(free_bytes)
    if free is None:
        return need
    free += int(held_bytes)
    if need <= USABLE_FRACTION * free:
        return need
    dims = tuple(int(n) for n in dims)
    edge = largest_cube(method, free, n_lights, light_volume_scale, options, image, device)
    where = "the GPU" if str(device).startswith("cuda") else "host memory"
    lines = [(f"{method}: a {'x'.join(map(str, dims))} volume needs about {_gib(need)} of "
              f"device memory on {device} ({_gib(free)} free in {where}); the largest cube "
              f"that fits is {edge}³ at these settings.")]
    if method in SCALED:
        scale = DEFAULT_SCALES[method] if light_volume_scale is None else light_volume_scale
        lower = _scale_that_fits(method, dims, n_lights, options, image, device, free, scale)
        hint = (f" (light_volume_scale={lower:g} fits)" if lower else "")
        lines.append(f"Lower light_volume_scale (now {scale:g}; core, CLI --option "
                     f"light_volume_scale=..., pyvista) or OutputScale (ParaView){hint}, "
                     "downsample the data (vtkImageResample), or render on device='cpu'.")
    elif method == "ambient-scattering":
        lines.append("Lower radiance_cache_scale (the ambient method's light grid; "
                     "light_volume_scale / OutputScale for the other illumination methods), "
                     "downsample the data (vtkImageResample), or render on device='cpu'.")
    else:
        lines.append("Downsample the data (vtkImageResample), use a smaller image, or render "
                     "on device='cpu'; for the illumination-volume methods "
                     "light_volume_scale (core/CLI/pyvista) or OutputScale (ParaView) lowers "
                     "the light grid.")
    raise DeviceMemoryError(" ".join(lines))


def _scale_that_fits(method, dims, n_lights, options, image, device, free, scale):
    """The largest of 1/2, 1/4, ... of ``scale`` at which the estimate fits, or None."""
    s = float(scale)
    for _ in range(6):
        s /= 2
        if estimate_bytes(method, dims, n_lights, s, options, image, device) \
                <= USABLE_FRACTION * free:
            return s
    return None


def _gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.1f} MiB"


class AllocationCounter:
    """Wraps a warp allocator and counts the bytes it holds (``current``) and its
    high-water mark (``high``, resettable with :meth:`reset`)."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.live: dict[int, int] = {}
        self.current = 0
        self.high = 0
        self.deallocate_requires_context_guard = getattr(
            inner, "deallocate_requires_context_guard", True)
        self.memory_kind = getattr(inner, "memory_kind", None)

    def allocate(self, size_in_bytes: int) -> int:
        ptr = self.inner.allocate(size_in_bytes)
        self.live[ptr] = int(size_in_bytes)
        self.current += int(size_in_bytes)
        self.high = max(self.high, self.current)
        return ptr

    def deallocate(self, ptr: int, size_in_bytes: int) -> None:
        self.inner.deallocate(ptr, size_in_bytes)
        self.current -= self.live.pop(ptr, 0)

    def reset(self) -> None:
        """Start a new high-water mark at what is held now."""
        self.high = self.current


@contextlib.contextmanager
def track_allocations(device: str = "cpu"):
    """Count warp's array allocations on the CPU device while the block runs.

    Yields an :class:`AllocationCounter`; arrays allocated inside and freed after the block
    are still handed back to the real allocator. Pinned host buffers (staging for CUDA
    copies) use another allocator and are not counted. On CUDA use the memory pool's
    counters (``wp.get_mempool_used_mem_high``) instead.
    """
    import warp as wp

    from vtkillum.core.device import init_warp

    init_warp()
    d = wp.get_device(device)
    if not d.is_cpu:
        raise ValueError("track_allocations counts the CPU device's allocator; on CUDA read "
                         "warp's memory-pool counters")
    saved = d.default_allocator
    counter = AllocationCounter(saved)
    d.default_allocator = counter
    try:
        yield counter
    finally:
        d.default_allocator = saved
