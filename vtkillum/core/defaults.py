"""Data-aware defaults: a first picture of unknown data without a scene file.

What ``vtkillum render FILE`` uses when the scene file gives no transfer function,
camera or lights (or there is no scene file), and how the CLI picks its exposure:

Transfer function (:func:`default_transfer_function`), from the histogram
    The values are histogrammed (:data:`HISTOGRAM_BINS` bins over the 0th to 99.95th
    percentile of up to :data:`MAX_SAMPLES` voxels, smoothed). *Air* is the histogram
    peak holding the volume's border value (the median of its six faces); everything up
    to the first valley above it is transparent. The *material classes* are the peaks
    above that valley holding at least :data:`MIN_CLASS_FRACTION` of the foreground
    voxels (at most :data:`MAX_CLASSES`, the most populated). Each class gets a plateau
    of opacity over its peak, the lowest class the least opaque (optical depth
    :data:`OUTER_DEPTH` across the volume, so it is a veil one sees through), the highest
    the most (:data:`INNER_DEPTH`), geometric in between; colours run from a warm tone
    (soft, low values) to near white (dense, high values). Without an air peak (e.g. a
    smoke field) the transparent part is the lowest :data:`NO_AIR_FRACTION` of the
    range; without any class peak, one class spans the foreground.

Camera (:func:`default_camera`), from the orientation
    For medical images (``frame="LPS"`` or ``"RAS"``: what the NIfTI, DICOM, MetaImage
    and anatomical NRRD readers produce, see :mod:`vtkillum.io.readers`) an **anterior
    view, superior up**: the camera in front of the face looking posterior, so the
    patient's left is on the right of the picture (as when facing a person). Otherwise
    VTK's default view (looking down ``-z`` with ``+y`` up, turned a little for depth)
    *in the image's own frame*: the direction matrix rotates it with the grid. The
    camera frames the foreground (the voxels above the air threshold) rather than the
    whole box.

Light (:func:`key_light`)
    One white directional key light from the upper front-left of the camera, as a
    photographer places a key light: it shows shape by shading and shadows.
    Irradiance :data:`KEY_IRRADIANCE`, so that an opaque lit surface of albedo 0.9 is
    near white at exposure 1 (the CLI's automatic exposure rescales anyway).

Exposure (:func:`auto_exposure`, :func:`picture`)
    The 99.5th percentile of the brightest channel over the pixels the volume covers
    (``alpha > 0.02``; all pixels if it covers fewer than 0.1 %) maps to white.

Image size (:func:`default_image_size`)
    256 x 256 on a CPU (warp runs kernels on one core there), 512 x 512 with CUDA.

The command line (``vtkillum render``) and the pyvista accessor (``grid.illum.render``)
both take these defaults from here, :func:`default_scene` for the camera and light,
:func:`picture` for the exposure of a PNG and :func:`default_image_size`, so that the
same data, transfer function and method give the same picture in both.
:func:`camera_inside_warning` is the one line both print when a camera starts inside
the data (a scene written for other units, say metres for data in millimetres).

numpy only (a core module): no vtk, no warp.
"""

from __future__ import annotations

import numpy as np

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction

#: Voxels looked at for the histogram (a regular subsample of larger volumes).
MAX_SAMPLES = 1 << 21
#: Histogram bins over the robust range.
HISTOGRAM_BINS = 256
#: Smoothing of the histogram (Gaussian, in bins).
SMOOTHING_BINS = 2.0
#: Upper percentile of the robust range (a few hot voxels do not stretch the histogram).
UPPER_PERCENTILE = 99.95
#: Smallest share of the foreground voxels that makes a histogram peak a material class.
MIN_CLASS_FRACTION = 0.03
#: Two peaks are one material unless the valley between them is below this fraction of the
#: lower peak.
VALLEY_DEPTH = 0.8
#: At most this many classes get their own opacity plateau.
MAX_CLASSES = 4
#: Share of the range kept transparent when there is no air peak.
NO_AIR_FRACTION = 0.05
#: Optical depth across the volume's mean size of the lowest (outer) class ...
OUTER_DEPTH = 6.0
#: ... and of the highest (densest) class.
INNER_DEPTH = 80.0
#: Colours of the classes, from the lowest to the highest value (interpolated between).
CLASS_COLORS = np.array([[0.92, 0.62, 0.52], [0.96, 0.82, 0.70], [1.0, 0.97, 0.92]])
#: Irradiance of the key light (white).
KEY_IRRADIANCE = 10.0
#: Direction towards the key light in the camera's (right, up, backwards) frame:
#: upper front-left.
KEY_FROM_CAMERA = (-0.55, 0.65, 1.0)
#: VTK-like default view in the image's own frame (from the camera to the data).
GRID_VIEW = (-0.4, -0.3, -1.0)
#: Vertical view angle of the default camera (degrees) and margin around the foreground.
VIEW_ANGLE = 30.0
MARGIN = 1.08
#: Default image side (pixels) on a CPU and with CUDA.
CPU_IMAGE_SIDE = 256
GPU_IMAGE_SIDE = 512
#: Anatomical frames: the world axis pointing anterior, and superior.
ANATOMICAL_AXES = {"LPS": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
                   "RAS": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}


# --- histogram ------------------------------------------------------------------------------------
class HistogramClasses:
    """What :func:`analyse_histogram` found: the air threshold and the material classes.

    Attributes
    ----------
    air : float or None
        Value of the air peak (``None``: no air peak found).
    threshold : float
        Values up to here are transparent.
    classes : list of (centre, half_width, fraction)
        Material classes in increasing value: the peak's value, half its width at half
        height, and its share of the foreground voxels.
    lo, hi : float
        The robust value range histogrammed.
    """

    def __init__(self, air, threshold, classes, lo, hi):
        self.air, self.threshold, self.classes, self.lo, self.hi = air, threshold, classes, lo, hi

    def __repr__(self) -> str:
        cls = ", ".join(f"{c:.4g}±{w:.2g} ({100 * f:.0f} %)" for c, w, f in self.classes)
        return (f"HistogramClasses(air={self.air}, threshold={self.threshold:.4g}, "
                f"classes=[{cls}], range=[{self.lo:.4g}, {self.hi:.4g}])")


def sample_values(volume, max_samples: int = MAX_SAMPLES) -> np.ndarray:
    """Up to ``max_samples`` values of ``volume``: a regular subsample (deterministic)."""
    flat = np.asarray(volume.scalars).reshape(-1)
    step = max(1, int(np.ceil(flat.size / max_samples)))
    return flat[::step].astype(np.float64)


def border_values(volume) -> np.ndarray:
    """The values on the six faces of the grid."""
    s = np.asarray(volume.scalars)
    return np.concatenate([s[[0, -1]].ravel(), s[:, [0, -1]].ravel(),
                           s[:, :, [0, -1]].ravel()]).astype(np.float64)


def analyse_histogram(volume) -> HistogramClasses:
    """Find the air threshold and the material classes of ``volume`` (module docstring)."""
    values = sample_values(volume)
    lo = float(values.min())
    hi = float(np.percentile(values, UPPER_PERCENTILE))
    if hi <= lo:
        hi = float(values.max())
    if hi <= lo:  # constant data
        return HistogramClasses(None, lo, [(lo, 0.0, 1.0)], lo, lo + 1.0)
    bins = HISTOGRAM_BINS
    hist, edges = np.histogram(np.clip(values, lo, hi), bins=bins, range=(lo, hi))
    centres = 0.5 * (edges[:-1] + edges[1:])
    width = edges[1] - edges[0]
    smooth = _smooth(hist.astype(np.float64), SMOOTHING_BINS)

    # Air: the peak holding the border's median value, if it is a substantial one.
    border = float(np.median(border_values(volume)))
    b = int(np.clip((border - lo) / width, 0, bins - 1))
    top = _climb(smooth, b)
    air, start = None, 0
    left_mass = hist[: _valley(smooth, top, +1) + 1].sum()
    if top < bins // 2 and left_mass >= 0.02 * hist.sum():
        air = float(centres[top])
        start = _valley(smooth, top, +1)
        threshold = float(edges[start + 1]) if start > top else float(centres[top] + width)
    else:
        threshold = lo + NO_AIR_FRACTION * (hi - lo)
        start = int(np.clip((threshold - lo) / width, 0, bins - 1))

    # Material classes: peaks above the air valley.
    fg = hist[start + 1:].sum() if start + 1 < bins else 0
    classes = []
    if fg > 0:
        peaks = [i for i in range(start + 1, bins)
                 if smooth[i] > 0 and smooth[i] >= smooth[max(i - 1, 0)]
                 and smooth[i] > smooth[min(i + 1, bins - 1)] or
                 (i == bins - 1 and smooth[i] > smooth[i - 1])]
        peaks = _merge_shallow(smooth, peaks)
        found = []
        for p in peaks:
            left = max(_valley(smooth, p, -1), start + 1)
            right = _valley(smooth, p, +1)
            mass = hist[left: right + 1].sum() / fg
            half = smooth[p] / 2
            a = p
            while a > left and smooth[a] > half:
                a -= 1
            c = p
            while c < right and smooth[c] > half:
                c += 1
            hw = max(0.5 * (c - a) * width, width)
            found.append((float(centres[p]), float(hw), float(mass)))
        found = [f for f in found if f[2] >= MIN_CLASS_FRACTION]
        found.sort(key=lambda f: -f[2])
        classes = sorted(found[:MAX_CLASSES])
    if not classes:
        fgv = values[values > threshold]
        if fgv.size:
            centre = float(np.median(fgv))
            hw = float(0.5 * (np.percentile(fgv, 84) - np.percentile(fgv, 16))) or width
            classes = [(centre, hw, 1.0)]
        else:
            classes = [(hi, width, 1.0)]
    return HistogramClasses(air, threshold, classes, lo, hi)


def _merge_shallow(h: np.ndarray, peaks: list) -> list:
    """Drop peaks separated from a higher neighbour by a valley shallower than
    :data:`VALLEY_DEPTH` (noise on one material's peak, not two materials)."""
    peaks = list(peaks)
    merged = True
    while merged and len(peaks) > 1:
        merged = False
        for n in range(len(peaks) - 1):
            a, b = peaks[n], peaks[n + 1]
            valley = h[a:b + 1].min()
            if valley > VALLEY_DEPTH * min(h[a], h[b]):
                del peaks[n if h[a] < h[b] else n + 1]
                merged = True
                break
    return peaks


def _smooth(hist: np.ndarray, sigma: float) -> np.ndarray:
    radius = int(np.ceil(3 * sigma))
    x = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel /= kernel.sum()
    padded = np.pad(hist, radius, mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def _climb(h: np.ndarray, i: int) -> int:
    """The local maximum reached from bin ``i`` going uphill."""
    while True:
        left = h[i - 1] if i > 0 else -1.0
        right = h[i + 1] if i + 1 < h.size else -1.0
        if right > h[i] and right >= left:
            i += 1
        elif left > h[i]:
            i -= 1
        else:
            return i


def _valley(h: np.ndarray, i: int, step: int) -> int:
    """The first local minimum from peak ``i`` in direction ``step`` (the end if none)."""
    j = i
    while 0 <= j + step < h.size and h[j + step] <= h[j]:
        j += step
    return j


# --- transfer function ----------------------------------------------------------------------------
def default_transfer_function(volume, classes: HistogramClasses | None = None
                              ) -> TransferFunction:
    """Air transparent, the material classes visible (see the module docstring).

    Opacities are per unit distance = the volume's mean spacing (the scene's default
    unit distance), chosen from the volume's mean size in voxels ``n``: the lowest class
    has optical depth :data:`OUTER_DEPTH` across ``n`` voxels, the highest
    :data:`INNER_DEPTH` (capped at opacity 0.95 per voxel).
    """
    h = classes if classes is not None else analyse_histogram(volume)
    n = float(np.mean(volume.dims))
    k = len(h.classes)
    depths = (np.geomspace(OUTER_DEPTH, INNER_DEPTH, k) if k > 1 else np.array([OUTER_DEPTH * 4]))
    alphas = np.minimum(1.0 - np.exp(-depths / n), 0.95)
    colours = _class_colours(k)
    scalars, opacity, colors = [h.threshold], [0.0], [colours[0]]
    for n_class, (centre, hw, _) in enumerate(h.classes):
        lo_edge = centre - 0.5 * hw
        hi_edge = centre + 0.5 * hw
        if n_class + 1 < k:
            hi_edge = min(hi_edge, 0.5 * (centre + h.classes[n_class + 1][0]))
        lo_edge = max(lo_edge, scalars[-1])
        for v in (lo_edge, hi_edge):
            if v > scalars[-1] * (1 + 1e-12) + 1e-300 and v > scalars[-1]:
                scalars.append(v)
                opacity.append(alphas[n_class])
                colors.append(colours[n_class])
        if len(scalars) == 1:  # the class sits on the threshold: a step just above it
            scalars.append(np.nextafter(h.threshold, np.inf) if centre <= h.threshold
                           else centre)
            opacity.append(alphas[n_class])
            colors.append(colours[n_class])
    return TransferFunction(scalars, opacity, colors)


def _class_colours(k: int) -> np.ndarray:
    if k == 1:
        return CLASS_COLORS[1:2]
    t = np.linspace(0.0, 1.0, k)
    x = np.linspace(0.0, 1.0, len(CLASS_COLORS))
    return np.stack([np.interp(t, x, CLASS_COLORS[:, c]) for c in range(3)], -1)


# --- camera and light -----------------------------------------------------------------------------
def foreground_bounds(volume, threshold: float) -> np.ndarray:
    """World-space corners ``(8, 3)`` of the box of the voxels above ``threshold``
    (the whole grid when none is)."""
    s = np.asarray(volume.scalars)
    step = max(1, int(np.ceil((s.size / MAX_SAMPLES) ** (1 / 3))))
    sub = s[::step, ::step, ::step] > threshold
    lo_idx = np.zeros(3)
    hi_idx = np.asarray(volume.dims, dtype=np.float64) - 1
    if sub.any():
        for axis in range(3):
            other = tuple(a for a in range(3) if a != axis)
            present = np.flatnonzero(sub.any(axis=other))
            lo_idx[axis] = max(present[0] * step - step, 0)
            hi_idx[axis] = min(present[-1] * step + step, volume.dims[axis] - 1)
    corners_idx = np.array([[lo_idx[0] if i == 0 else hi_idx[0],
                             lo_idx[1] if j == 0 else hi_idx[1],
                             lo_idx[2] if k == 0 else hi_idx[2]]
                            for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    local = corners_idx * volume.spacing
    return local @ np.asarray(volume.direction).T + volume.origin


def view_directions(volume, frame: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World ``(forward, view_up)`` of the default view (see the module docstring)."""
    if frame is not None:
        key = str(frame).upper()
        if key not in ANATOMICAL_AXES:
            raise ValueError(f"frame must be one of {sorted(ANATOMICAL_AXES)} or None, "
                             f"got {frame!r}")
        anterior, superior = (np.asarray(v) for v in ANATOMICAL_AXES[key])
        return -anterior, superior
    d = np.asarray(volume.direction, dtype=np.float64)
    forward = d @ np.asarray(GRID_VIEW)
    return forward / np.linalg.norm(forward), d @ np.array([0.0, 1.0, 0.0])


def default_camera(volume, frame: str | None = None, threshold: float | None = None,
                   aspect: float = 1.0) -> Camera:
    """The default view of ``volume`` framing its foreground (module docstring).

    Parameters
    ----------
    frame : {"LPS", "RAS", None}
        The anatomical frame of the world coordinates (medical images), or ``None``.
    threshold : float, optional
        Values above it are foreground (default: the air threshold of the histogram).
    aspect : float
        Width / height of the picture the camera must frame the foreground in.
    """
    if threshold is None:
        threshold = analyse_histogram(volume).threshold
    forward, up = view_directions(volume, frame)
    corners = foreground_bounds(volume, threshold)
    centre = 0.5 * (corners.min(0) + corners.max(0))
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = corners - centre
    tan_v = np.tan(np.radians(VIEW_ANGLE) / 2)
    tan_h = tan_v * max(float(aspect), 1e-3)
    depth = rel @ forward
    need = np.maximum(np.abs(rel @ up) / tan_v, np.abs(rel @ right) / tan_h) - depth
    distance = MARGIN * float(max(need.max(), 1e-6))
    distance = max(distance, 1.5 * float(np.linalg.norm(rel, axis=1).max()))
    return Camera(centre - distance * forward, centre, up, VIEW_ANGLE)


def key_light(camera: Camera, irradiance: float = KEY_IRRADIANCE) -> DirectionalLight:
    """A white directional light from the upper front-left of ``camera``."""
    right, up, forward = camera.basis()
    x, y, z = KEY_FROM_CAMERA
    towards_light = x * right + y * up - z * forward
    return DirectionalLight(-towards_light, (irradiance,) * 3)


def default_scene(volume, frame: str | None = None, base: Scene | None = None,
                  fill=("transfer_function", "camera", "lights"), aspect: float = 1.0) -> Scene:
    """``base`` (default ``Scene()``) with the data-aware defaults filled in.

    Parameters
    ----------
    volume : Volume
    frame : {"LPS", "RAS", None}
        Anatomical frame of the world coordinates (see :func:`default_camera`).
    base : Scene, optional
        Its transfer function and camera are kept where set; ``fill`` names what to
        replace with the defaults (``"lights"`` replaces the lights with the key light).
    aspect : float
        Width / height of the picture (the camera frames the foreground in it).
    """
    import dataclasses

    scene = base if base is not None else Scene()
    h = analyse_histogram(volume)
    changes = {}
    if "transfer_function" in fill and scene.transfer_function is None:
        changes["transfer_function"] = default_transfer_function(volume, h)
    camera = scene.camera
    if "camera" in fill and camera is None:
        camera = changes["camera"] = default_camera(volume, frame, threshold=h.threshold,
                                                    aspect=aspect)
    if "lights" in fill:
        camera = camera if camera is not None else scene.resolved_camera(volume)
        changes["lights"] = [key_light(camera)]
    return dataclasses.replace(scene, **changes) if changes else scene


# --- exposure -------------------------------------------------------------------------------------
def auto_exposure(radiance, alpha=None, background=(0.0, 0.0, 0.0), percentile: float = 99.5,
                  coverage: float = 0.02) -> float:
    """Exposure mapping the ``percentile`` of the covered pixels' brightest channel to 1.

    The radiance is composited over ``background``; "covered" pixels have ``alpha >
    coverage``; if fewer than 0.1 % are, all pixels count. Non-finite values are ignored;
    1 when nothing is bright.
    """
    rad = np.asarray(radiance, dtype=np.float32)
    peak = rad.max(axis=-1)
    if alpha is not None:
        a = np.asarray(alpha, dtype=np.float32)
        bg = np.asarray(background, dtype=np.float32)
        peak = (rad + (1.0 - a)[..., None] * bg).max(axis=-1)
        covered = a > coverage
        if covered.sum() >= max(1, 0.001 * covered.size):
            peak = peak[covered]
    values = peak[np.isfinite(peak)]
    if values.size == 0:
        return 1.0
    level = float(np.percentile(values, percentile))
    return 1.0 / level if level > 0 else 1.0


def picture(radiance, alpha=None, background=(0.0, 0.0, 0.0), exposure="auto",
            gamma: float = 2.2) -> np.ndarray:
    """The 8-bit RGB picture (H, W, 3) of a render, as written to a PNG.

    The radiance composited over ``background``, multiplied by ``exposure`` (``"auto"``:
    :func:`auto_exposure`; else a positive factor), clipped to [0, 1] and gamma-encoded
    (:func:`vtkillum.core.tonemap.tonemap`).
    """
    from vtkillum.core.tonemap import tonemap

    if isinstance(exposure, str):
        if exposure.lower() != "auto":
            raise ValueError(f"exposure must be a positive number or 'auto', got {exposure!r}")
        exposure = auto_exposure(radiance, alpha=alpha, background=background)
    elif not (np.isfinite(float(exposure)) and float(exposure) > 0):
        raise ValueError(f"exposure must be a positive number or 'auto', got {exposure!r}")
    return tonemap(radiance, alpha, background, float(exposure), gamma=gamma)


# --- image size and camera checks -------------------------------------------------------------------
def default_image_size(device: str) -> tuple[int, int]:
    """``(width, height)`` of a picture when none is asked for, on a resolved ``device``:
    :data:`CPU_IMAGE_SIDE` squared on a CPU, :data:`GPU_IMAGE_SIDE` squared with CUDA."""
    side = GPU_IMAGE_SIDE if str(device).lower().startswith("cuda") else CPU_IMAGE_SIDE
    return side, side


def camera_inside_warning(camera: Camera, volume) -> str | None:
    """One line when ``camera`` starts inside ``volume``'s box, else ``None``.

    Such a picture shows the inside of the data (often uniform noise): usually the
    camera was written for other units than the data's (millimetres for medical images).
    Not an error: a view from inside can be meant.
    """
    position = np.asarray(camera.position, dtype=np.float64)
    local = volume.to_local(position)
    if not np.all((local >= 0.0) & (local <= volume.extent)):
        return None
    lo, hi = volume.bounds[0::2], volume.bounds[1::2]
    box = ", ".join(f"{a}: {l:.4g} to {h:.4g}" for a, l, h in zip("xyz", lo, hi))
    where = ", ".join(f"{v:.4g}" for v in position)
    return (f"the camera at ({where}) is inside the data ({box}, in the data's units); the "
            "picture shows the inside of the volume; place the camera outside (e.g. leave "
            "the camera out of the scene for the default view)")
