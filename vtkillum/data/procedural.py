"""Procedural test volumes, generated with numpy alone (no VTK needed).

Every generator returns a :class:`~vtkillum.core.volume.Volume` with values in
[0, 1], isotropic spacing and a world placement that does not depend on the
resolution: a larger ``n`` samples the same object more finely (except that the
Cornell box's walls are kept at least two voxels thick, so they thicken below
``n = 51``, and the CT phantom's borders are anti-aliased over one voxel). The value
ranges each dataset uses are listed in its docstring and in :data:`VALUE_RANGES`;
:func:`default_scene` gives each one a transfer function, lights and a camera
that show shadows and scattering.

==================  =====================  ==============================================
dataset             world box              values of interest
==================  =====================  ==============================================
``plume``           x, y in [-1, 1],       0 air; 0.02–0.3 wisps; 0.3–0.7 body;
                    z in [0, 3] (default)  0.7–1 dense core near the source
``cornell``         [-1, 1]^3, open at +z  0.1–0.2 fog (denser near the floor);
                                           0.5 white walls and blocks; 0.75 red wall
                                           (x = -1); 1.0 green wall (x = +1)
``ct``              [-120, 120]^3 mm       0 air; 0.3 skin; 0.4 fluid (eyes, ventricles);
                                           0.5 soft tissue; 0.65 lesion; 0.9 bone
``marschner-lobb``  [-1, 1]^3              smooth in [0, 1]; the classic isovalue is 0.5
==================  =====================  ==============================================
"""

from __future__ import annotations

import numpy as np

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

#: Dataset name -> {feature: (low, high)} value ranges (see the module docstring).
VALUE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "plume": {"air": (0.0, 0.0), "wisps": (0.02, 0.3), "body": (0.3, 0.7), "core": (0.7, 1.0)},
    "cornell": {"fog": (0.1, 0.2), "white walls and blocks": (0.5, 0.5),
                "red wall": (0.75, 0.75), "green wall": (1.0, 1.0)},
    "ct": {"air": (0.0, 0.0), "skin": (0.3, 0.3), "fluid": (0.4, 0.4), "soft tissue": (0.5, 0.5),
           "lesion": (0.65, 0.65), "bone": (0.9, 0.9)},
    "marschner-lobb": {"field": (0.0, 1.0), "isovalue": (0.5, 0.5)},
}

# CT phantom materials (documented values).
CT_AIR, CT_SKIN, CT_FLUID, CT_TISSUE, CT_LESION, CT_BONE = 0.0, 0.3, 0.4, 0.5, 0.65, 0.9

# Cornell box materials.
CORNELL_FOG_LOW, CORNELL_FOG_HIGH = 0.1, 0.2
CORNELL_WHITE, CORNELL_RED, CORNELL_GREEN = 0.5, 0.75, 1.0


# --- smoke plume --------------------------------------------------------------------------------
def smoke_plume(shape=(64, 64, 96), seed: int = 0, time: float = 0.0) -> Volume:
    """A rising, turbulent smoke plume.

    The density is a Gaussian column around a wobbling centre line whose radius
    grows with height, broken up by fractal value noise that rises with the smoke
    (advected upward at speed 1 world unit per time unit) and whose sampling
    positions are displaced by a second noise field (domain warping) so that the
    edges curl. Everything is a smooth function of position and ``time``, so
    consecutive times give a smoothly evolving plume. This is a kinematic model,
    not a fluid simulation.

    Parameters
    ----------
    shape : (nx, ny, nz) int
        Grid points; z is up. The spacing is ``2 / (nx - 1)`` on every axis, so
        x spans [-1, 1], y is centred on 0 and z starts at 0 (``(64, 64, 96)``
        gives a 2 x 2 x 3 box).
    seed : int
        Seed of the noise lattices.
    time : float
        Time (smoke rises 1 world unit per time unit).

    Returns
    -------
    Volume
        Density in [0, 1]: 0 air, 0.02–0.3 thin wisps, 0.3–0.7 the plume body,
        0.7–1 the dense core near the source.
    """
    nx, ny, nz = _shape3(shape, "shape", minimum=4)
    h = 2.0 / (nx - 1)
    origin = np.array([-1.0, -0.5 * (ny - 1) * h, 0.0])
    x, y, z = _grid_axes((nx, ny, nz), h, origin)
    height = (nz - 1) * h
    rng = np.random.default_rng(seed)
    lattices = [rng.random((16, 16, 16), dtype=np.float32) for _ in range(6)]
    phases = rng.uniform(0.0, 2.0 * np.pi, 2)
    t = float(time)

    X, Y, Z = np.meshgrid(x, y, z, indexing="ij", sparse=True)
    # Centre line: a slow lean plus a travelling wobble that grows with height.
    zf = Z / height
    cx = 0.12 * zf + 0.18 * zf * np.sin(2.3 * Z - 1.1 * t + phases[0])
    cy = 0.14 * zf * np.sin(1.7 * Z - 0.9 * t + phases[1])
    # Advected noise coordinates: the smoke pattern rises with the flow (speed 1).
    freq = 3.0
    q = np.stack(np.broadcast_arrays(X * freq, Y * freq, (Z - t) * freq), -1).astype(np.float32)
    # Domain warping: displace the lookup by a low-frequency noise so that edges curl;
    # the warp field drifts slowly so the plume also changes shape while it rises.
    drift = np.array([0.31 * t, -0.23 * t, 0.0], dtype=np.float32)
    warp = np.stack([_fbm(0.5 * q + drift + 7.1 * c, lattices[c:c + 1]) for c in range(3)], -1)
    warp = (warp - 0.5) * 2.0  # about [-1, 1]
    qw = q + 0.9 * warp
    # Distance to the centre line relative to the local radius (the plume widens as it
    # rises), bent by the same warp field so that the column curls.
    radius = 0.18 + 0.42 * zf
    dx = X - cx + 0.2 * zf * warp[..., 0]
    dy = Y - cy + 0.2 * zf * warp[..., 1]
    rel = np.sqrt(dx * dx + dy * dy) / radius
    # Billows: the noise pushes the boundary in and out (edge erosion) and varies the
    # density inside; more erosion higher up, where the plume breaks into puffs.
    # fbm has a standard deviation of about 0.15: stretch it to about 0.4.
    turbulence = np.clip(0.5 + 2.5 * (_fbm(qw + 13.7, lattices[3:6]) - 0.5), 0.0, 1.0)
    edge = rel + (0.5 + 0.6 * zf) * (0.5 - turbulence)
    body = _smoothstep(1.0, 0.1, edge)
    detail = np.clip(0.6 + 1.2 * (turbulence - 0.5), 0.0, None)
    # Dilution with height (the same smoke spread over a wider section), a dense core
    # just above the source, and fades at the source and the top of the box.
    dilution = (0.18 / radius) ** 0.7
    core = 0.5 * np.exp(-4.0 * rel * rel) * (1.0 - _smoothstep(0.0, 0.3, zf))
    fade = _smoothstep(0.0, 0.1, zf) * (1.0 - _smoothstep(0.85, 1.0, zf))
    density = (body * detail * dilution + core) * fade
    return Volume(np.clip(density, 0.0, 1.0).astype(np.float32), (h, h, h), origin)


def plume_series(steps: int = 3, shape=(48, 48, 72), seed: int = 0, dt: float = 0.25):
    """A time-varying plume: :func:`smoke_plume` at ``time = k * dt``, ``k < steps``.

    Parameters
    ----------
    steps : int
        Number of time steps (at least 1).
    shape : (nx, ny, nz) int
        Grid of every step (see :func:`smoke_plume`).
    seed : int
        Noise seed shared by all steps (the same plume, evolving).
    dt : float
        Time between steps; the plume rises ``dt`` world units per step and
        changes smoothly (halving ``dt`` halves the change between steps).

    Returns
    -------
    list of (float, Volume)
    """
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number, got {dt!r}")
    return [(k * float(dt), smoke_plume(shape, seed=seed, time=k * float(dt)))
            for k in range(int(steps))]


#: Diffusion length of the default scenes' convection-diffusion section, in voxels.
DIFFUSION_VOXELS = 3.0


# --- Cornell box --------------------------------------------------------------------------------
def cornell_box(n: int = 64) -> Volume:
    """A Cornell box as a volume: dense walls and blocks around a thin fog.

    The box spans [-1, 1]³ (y up) and is open towards +z, where the camera looks
    in. Walls are 0.08 world units (at least two voxels) thick; a tall block
    (back left) and a short block (front right) stand on the floor, each rotated
    about y by about ±17°. Values (point-sampled, so material borders are one
    voxel wide):

    - fog: 0.1 at the ceiling to 0.2 at the floor (a thin, ground-hugging medium);
    - floor, ceiling, back wall and both blocks: 0.5 (white);
    - left wall (x = -1): 0.75 (red); right wall (x = +1): 1.0 (green).

    Colours come from the transfer function of :func:`default_scene` (narrow opacity
    peaks per material). One scalar cannot keep coloured materials apart under
    post-classification, as VTK renders them: where the red wall (0.75) meets the
    fog, the interpolated values pass the white peak, and the green wall's (1.0)
    border passes the white and red ones, so thin white/red streaks line those
    borders. They are a fraction of a voxel wide: use ``n >= 64`` for pictures.

    Parameters
    ----------
    n : int
        Grid points per axis (spacing ``2 / (n - 1)``).
    """
    n = _size(n, "n", minimum=16)
    h = 2.0 / (n - 1)
    x, y, z = _grid_axes((n, n, n), h, (-1.0, -1.0, -1.0))
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij", sparse=True)
    wall = max(0.08, 2.0 * h)

    values = np.broadcast_to(
        CORNELL_FOG_LOW + (CORNELL_FOG_HIGH - CORNELL_FOG_LOW) * (1.0 - Y) / 2.0, (n, n, n)
    ).astype(np.float32)
    white = (Y <= -1 + wall) | (Y >= 1 - wall) | (Z <= -1 + wall)
    values = np.where(white, CORNELL_WHITE, values)
    values = np.where(np.broadcast_to(X <= -1 + wall, values.shape), CORNELL_RED, values)
    values = np.where(np.broadcast_to(X >= 1 - wall, values.shape), CORNELL_GREEN, values)
    floor = -1 + wall
    for centre, half, top, angle in (((-0.33, -0.3), (0.27, 0.27), 0.25, np.radians(17.0)),
                                     ((0.35, 0.3), (0.27, 0.27), -0.4, np.radians(-17.0))):
        u = (X - centre[0]) * np.cos(angle) - (Z - centre[1]) * np.sin(angle)
        v = (X - centre[0]) * np.sin(angle) + (Z - centre[1]) * np.cos(angle)
        block = (np.abs(u) <= half[0]) & (np.abs(v) <= half[1]) & (Y >= floor) & (Y <= top)
        values = np.where(block, CORNELL_WHITE, values)
    return Volume(values.astype(np.float32), (h, h, h), (-1.0, -1.0, -1.0))


# --- CT phantom ---------------------------------------------------------------------------------
def ct_phantom(n: int = 64, noise: float = 0.0, seed: int = 0) -> Volume:
    """A CT-like head-and-neck phantom of nested ellipsoids (in the spirit of 3D Shepp–Logan).

    World units are millimetres: the grid spans [-120, 120] mm on every axis in
    a right-handed, RAS-like frame (+x the patient's right, +y anterior: the face
    looks along +y, +z superior). Materials, painted in this order (later ones
    replace earlier ones), with borders anti-aliased over one voxel (so values
    between two materials occur only at their border):

    ======================  =======  =========================================
    material                value    where
    ======================  =======  =========================================
    air                     0.0      outside; trachea
    skin (and fat)          0.3      6 mm shell around head and neck
    soft tissue             0.5      brain, neck muscles
    bone                    0.9      skull (6-10 mm shell), vertebral column, jaw
    fluid                   0.4      ventricles, eyes
    lesion                  0.65     a sphere of radius 12 mm, left hemisphere
    ======================  =======  =========================================

    Parameters
    ----------
    n : int
        Grid points per axis (spacing ``240 / (n - 1)`` mm).
    noise : float
        Standard deviation of added Gaussian noise (CT-like graininess); the
        result is clipped to [0, 1]. Default 0 (exact values).
    seed : int
        Seed of the noise.
    """
    n = _size(n, "n", minimum=16)
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a non-negative number, got {noise!r}")
    h = 240.0 / (n - 1)
    x, y, z = _grid_axes((n, n, n), h, (-120.0, -120.0, -120.0))
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij", sparse=True)
    values = np.zeros((n, n, n), dtype=np.float32)

    def paint(value, inside):
        nonlocal values
        values = values + (value - values) * inside

    head_c, head_r = (0.0, 0.0, 25.0), np.array([72.0, 88.0, 92.0])
    neck_r, neck_top = 40.0, -10.0
    # Skin: the outer head ellipsoid and the neck cylinder.
    head = _ellipsoid(X, Y, Z, head_c, head_r, h)
    neck = _cylinder_z(X, Y - (-8.0), Z, neck_r, -200.0, neck_top, h)
    paint(CT_SKIN, np.maximum(head, neck))
    # Soft tissue 6 mm inside the skin.
    paint(CT_TISSUE, np.maximum(_ellipsoid(X, Y, Z, head_c, head_r - 6.0, h),
                                _cylinder_z(X, Y + 8.0, Z, neck_r - 6.0, -200.0, neck_top, h)))
    # Skull: a 6 mm bone shell, then brain inside it.
    skull_r = head_r - 8.0
    paint(CT_BONE, _ellipsoid(X, Y, Z, head_c, skull_r, h))
    paint(CT_TISSUE, _ellipsoid(X, Y, Z, (0.0, -2.0, 30.0), skull_r - (6.0, 6.0, 10.0), h))
    # Jaw: a U-shaped bone band (an elliptic ring, front half) low in the face.
    slab = _smooth_halfspace(Z + 50.0, h) * _smooth_halfspace(-32.0 - Z, h)
    jaw_outer = _ellipsoid(X, Y, Z, (0.0, 12.0, -41.0), (50.0, 62.0, 1e4), h)
    jaw_inner = _ellipsoid(X, Y, Z, (0.0, 12.0, -41.0), (42.0, 54.0, 1e4), h)
    paint(CT_BONE, jaw_outer * (1.0 - jaw_inner) * slab * _smooth_halfspace(Y - 12.0, h))
    # Vertebral column behind the trachea.
    paint(CT_BONE, _cylinder_z(X, Y + 22.0, Z, 11.0, -200.0, -50.0, h))
    # Trachea (air) in front of it.
    paint(CT_AIR, _cylinder_z(X, Y - 10.0, Z, 7.0, -200.0, -30.0, h))
    # Ventricles and eyes (fluid).
    for cx in (-11.0, 11.0):
        paint(CT_FLUID, _ellipsoid(X, Y, Z, (cx, -5.0, 40.0), (7.0, 28.0, 11.0), h))
    for cx in (-30.0, 30.0):
        paint(CT_FLUID, _ellipsoid(X, Y, Z, (cx, 68.0, 20.0), (11.0, 11.0, 11.0), h))
    # A lesion in the left hemisphere (-x).
    paint(CT_LESION, _ellipsoid(X, Y, Z, (-32.0, 20.0, 55.0), (12.0, 12.0, 12.0), h))

    if noise > 0:
        rng = np.random.default_rng(seed)
        values = values + rng.normal(0.0, noise, values.shape).astype(np.float32)
    return Volume(np.clip(values, 0.0, 1.0).astype(np.float32), (h, h, h), (-120.0,) * 3)


# --- Marschner–Lobb -----------------------------------------------------------------------------
def marschner_lobb(n: int = 41, fM: float = 6.0, alpha: float = 0.25) -> Volume:
    """The Marschner–Lobb test signal on [-1, 1]³ (Marschner & Lobb 1994).

    ``ρ(x, y, z) = (1 - sin(π z / 2) + α (1 + ρr(√(x² + y²)))) / (2 (1 + α))`` with
    ``ρr(r) = cos(2π fM cos(π r / 2))``. Values lie in [0, 1]; the usual
    isovalue is 0.5. With the standard ``n = 41``, ``fM = 6``, ``alpha = 0.25`` the
    signal is close to the sampling limit, which makes reconstruction errors
    (trilinear interpolation, classification) visible.

    Parameters
    ----------
    n : int
        Grid points per axis (spacing ``2 / (n - 1)``).
    fM : float
        Modulation frequency.
    alpha : float
        Modulation amplitude.
    """
    n = _size(n, "n", minimum=4)
    if not (np.isfinite(alpha) and alpha >= 0) or not np.isfinite(fM):
        raise ValueError("marschner_lobb: alpha must be a non-negative number and fM finite")
    h = 2.0 / (n - 1)
    x = -1.0 + h * np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij", sparse=True)
    r = np.sqrt(X * X + Y * Y)
    rho_r = np.cos(2.0 * np.pi * fM * np.cos(np.pi * r / 2.0))
    rho = (1.0 - np.sin(np.pi * Z / 2.0) + alpha * (1.0 + rho_r)) / (2.0 * (1.0 + alpha))
    return Volume(np.clip(rho, 0.0, 1.0).astype(np.float32), (h, h, h), (-1.0, -1.0, -1.0))


# --- recommended scenes -------------------------------------------------------------------------
#: Dataset names understood by :func:`default_scene` (with accepted aliases).
SCENE_ALIASES = {
    "plume": "plume", "smoke": "plume", "smoke_plume": "plume", "smoke-plume": "plume",
    "cornell": "cornell", "cornell_box": "cornell", "cornell-box": "cornell",
    "ct": "ct", "ct_phantom": "ct", "ct-phantom": "ct", "phantom": "ct",
    "marschner-lobb": "marschner-lobb", "marschner_lobb": "marschner-lobb", "ml": "marschner-lobb",
    "glass": "glass", "stemmed_glass": "glass", "stemmed-glass": "glass",
}


def default_scene(name: str, volume: Volume) -> Scene:
    """The recommended transfer function, lights and camera for a procedural dataset.

    Each scene is lit from the side so that a single-scattering render shows
    self-shadowing and scattering; light strengths are chosen so that exposure 1
    gives a well-exposed picture with the ``single`` method. The convection–diffusion
    section gets a diffusion length of ``DIFFUSION_VOXELS`` voxels (``sigma_hat_s =
    (3 h)**2`` per channel, ``h`` the mean spacing), so that method shows multiple
    scattering out of the box (the scene file's own default, 0, turns diffusion off).

    Parameters
    ----------
    name : str
        ``"plume"``, ``"cornell"``, ``"ct"`` or ``"marschner-lobb"`` (aliases such
        as ``"smoke_plume"`` or ``"ct_phantom"`` are accepted).
    volume : Volume
        The dataset (the camera frames its bounds; unit distances scale with it).
    """
    key = SCENE_ALIASES.get(str(name).lower())
    if key is None:
        raise ValueError(
            f"no default scene for dataset {name!r}; known: {sorted(set(SCENE_ALIASES.values()))}"
        )
    scene = _SCENES[key](volume)
    h = volume.mean_spacing()
    scene.options["convection_diffusion"]["scattering"] = [(DIFFUSION_VOXELS * h) ** 2] * 3
    return scene


def _plume_scene(volume: Volume) -> Scene:
    tf = TransferFunction(
        [0.0, 0.02, 0.3, 0.7, 1.0],
        [0.0, 0.0, 0.35, 0.8, 0.95],
        [[1.0, 1.0, 1.0], [0.95, 0.95, 0.97], [0.92, 0.9, 0.88], [0.85, 0.8, 0.75],
         [0.8, 0.72, 0.65]],
    )
    camera = _framing_camera(volume, direction=(0.25, 1.0, -0.12), view_up=(0.0, 0.0, 1.0),
                             zoom=1.2)
    return Scene(
        transfer_function=tf,
        opacity_unit_distance=0.04,
        albedo=0.95,
        anisotropy=0.3,
        lights=[DirectionalLight((1.0, 0.5, -0.6), (40.0, 38.0, 34.5)),
                DirectionalLight((-0.6, 1.0, 0.2), (1.0, 1.2, 1.6))],
        camera=camera,
        background=(0.04, 0.05, 0.07),
    )


def _cornell_scene(volume: Volume) -> Scene:
    fog = (CORNELL_FOG_LOW + CORNELL_FOG_HIGH) / 2
    white, red, green = CORNELL_WHITE, CORNELL_RED, CORNELL_GREEN
    w = 0.04  # half-width of the narrow opacity peaks of the solid materials
    tf = TransferFunction(
        [0.0, 0.09, fog, 0.25, white - w, white, white + w, red - w, red, red + w, green - w,
         green],
        [0.0, 0.001, 0.0015, 0.0, 0.0, 0.4, 0.0, 0.0, 0.4, 0.0, 0.0, 0.4],
        [[1, 1, 1], [0.9, 0.92, 1.0], [0.9, 0.92, 1.0], [0.9, 0.92, 1.0],
         [0.8, 0.8, 0.8], [0.8, 0.8, 0.8], [0.8, 0.8, 0.8],
         [0.8, 0.12, 0.1], [0.8, 0.12, 0.1], [0.8, 0.12, 0.1],
         [0.15, 0.7, 0.15], [0.15, 0.7, 0.15]],
    )
    camera = Camera((0.0, 0.0, 4.6), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), view_angle=30.0)
    return Scene(
        transfer_function=tf,
        opacity_unit_distance=0.01,
        albedo=0.9,
        anisotropy=0.0,
        lights=[PointLight((0.0, 0.8, 0.1), (8.0, 7.5, 6.4))],
        camera=camera,
        background=(0.0, 0.0, 0.0),
    )


def _ct_scene(volume: Volume) -> Scene:
    # Narrow peaks: a border between two materials passes through the values between
    # them (e.g. tissue -> bone crosses the lesion's 0.65) over one voxel only.
    tf = TransferFunction(
        [0.0, 0.12, CT_SKIN, 0.42, 0.45, CT_TISSUE, 0.55, 0.62, CT_LESION, 0.68, 0.75, CT_BONE,
         1.0],
        [0.0, 0.0, 0.08, 0.0, 0.0, 0.008, 0.0, 0.0, 0.5, 0.0, 0.0, 0.85, 0.9],
        [[1, 1, 1], [0.95, 0.75, 0.6], [0.95, 0.75, 0.6], [0.95, 0.75, 0.6],
         [0.85, 0.45, 0.4], [0.85, 0.45, 0.4], [0.85, 0.45, 0.4],
         [0.9, 0.8, 0.2], [0.9, 0.8, 0.2], [0.9, 0.8, 0.2],
         [0.95, 0.93, 0.88], [0.95, 0.93, 0.88], [0.95, 0.93, 0.88]],
    )
    camera = _framing_camera(volume, direction=(-0.5, -1.0, -0.15), view_up=(0.0, 0.0, 1.0),
                             zoom=1.2)
    return Scene(
        transfer_function=tf,
        opacity_unit_distance=4.0,
        albedo=0.9,
        anisotropy=0.0,
        lights=[DirectionalLight((0.7, -0.8, -0.5), (10.0, 9.6, 9.0)),
                DirectionalLight((-0.5, -0.3, 0.2), (1.0, 1.1, 1.4))],
        camera=camera,
        background=(0.05, 0.05, 0.06),
    )


def _marschner_lobb_scene(volume: Volume) -> Scene:
    tf = TransferFunction([0.0, 0.42, 0.5, 0.58, 1.0], [0.0, 0.0, 0.85, 0.0, 0.0],
                          [[1.0, 1.0, 1.0], [0.9, 0.7, 0.4], [0.95, 0.85, 0.6],
                           [0.9, 0.7, 0.4], [1.0, 1.0, 1.0]])
    camera = _framing_camera(volume, direction=(-0.5, 1.0, -0.6), view_up=(0.0, 0.0, 1.0),
                             zoom=1.3)
    return Scene(
        transfer_function=tf,
        opacity_unit_distance=float(volume.spacing.mean()),
        albedo=0.9,
        anisotropy=0.0,
        lights=[DirectionalLight((0.6, -0.5, -1.0), (10.0, 10.0, 10.0))],
        camera=camera,
        background=(0.05, 0.05, 0.06),
    )


_SCENES = {"plume": _plume_scene, "cornell": _cornell_scene, "ct": _ct_scene,
           "marschner-lobb": _marschner_lobb_scene}
_SCENES["glass"] = lambda volume: _glass_scene(volume)


def _framing_camera(volume: Volume, direction, view_up, zoom: float = 1.0,
                    view_angle: float = 30.0) -> Camera:
    """``Camera.looking_at_bounds`` moved ``zoom`` times closer (the bounding sphere is loose)."""
    cam = Camera.looking_at_bounds(volume.bounds, direction=direction, view_up=view_up,
                                   view_angle=view_angle)
    offset = (cam.position - cam.focal_point) / zoom
    return Camera(cam.focal_point + offset, cam.focal_point, view_up, view_angle)


# --- helpers ------------------------------------------------------------------------------------
def _size(n, name: str, minimum: int) -> int:
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {n!r}")
    return int(n)


def _shape3(shape, name: str, minimum: int) -> tuple[int, int, int]:
    try:
        dims = tuple(shape)
    except TypeError:
        raise ValueError(f"{name} must be three integers (nx, ny, nz), got {shape!r}") from None
    if len(dims) != 3:
        raise ValueError(f"{name} must be three integers (nx, ny, nz), got {shape!r}")
    return tuple(_size(d, name, minimum) for d in dims)


def _grid_axes(dims, h: float, origin):
    return tuple(float(o) + h * np.arange(d) for d, o in zip(dims, origin))


def _smoothstep(lo: float, hi: float, x):
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _value_noise(p: np.ndarray, lattice: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] at points ``p`` (..., 3) in lattice units.

    Random values on a periodic integer lattice, interpolated trilinearly with
    smoothstep weights (C¹ in position, so animating ``p`` is smooth).
    """
    size = np.array(lattice.shape)
    base = np.floor(p)
    f = (p - base).astype(np.float32)
    f = f * f * (3.0 - 2.0 * f)
    i0 = np.mod(base.astype(np.int64), size)
    i1 = np.mod(i0 + 1, size)
    out = np.zeros(p.shape[:-1], dtype=np.float32)
    for corner in range(8):
        ix = i1[..., 0] if corner & 1 else i0[..., 0]
        iy = i1[..., 1] if corner & 2 else i0[..., 1]
        iz = i1[..., 2] if corner & 4 else i0[..., 2]
        wx = f[..., 0] if corner & 1 else 1.0 - f[..., 0]
        wy = f[..., 1] if corner & 2 else 1.0 - f[..., 1]
        wz = f[..., 2] if corner & 4 else 1.0 - f[..., 2]
        out += wx * wy * wz * lattice[ix, iy, iz]
    return out


def _fbm(p: np.ndarray, lattices, octaves: int | None = None) -> np.ndarray:
    """Fractal sum of value-noise octaves (frequency ×2, amplitude ×½), normalised to [0, 1]."""
    octaves = octaves or len(lattices)
    total = np.zeros(p.shape[:-1], dtype=np.float32)
    amplitude, norm = 1.0, 0.0
    for o in range(octaves):
        lattice = lattices[o % len(lattices)]
        # Offset each octave so that lattice points of different octaves do not align.
        total += amplitude * _value_noise(p * (2.0 ** o) + 17.3 * o, lattice)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def _ellipsoid(X, Y, Z, centre, radii, h: float) -> np.ndarray:
    """Anti-aliased occupancy of an ellipsoid: 1 inside, 0 outside, a ramp one voxel wide.

    Uses the first-order distance estimate ``(|q| - 1) / |∇|q||`` with ``q`` the
    point scaled by the radii.
    """
    r = np.asarray(radii, dtype=np.float64)
    qx, qy, qz = (X - centre[0]) / r[0], (Y - centre[1]) / r[1], (Z - centre[2]) / r[2]
    k = np.sqrt(qx * qx + qy * qy + qz * qz)
    grad = np.sqrt((qx / r[0]) ** 2 + (qy / r[1]) ** 2 + (qz / r[2]) ** 2)
    # |grad k| = grad / k; k / grad lies in [min r, max r] (min r at the exact centre).
    scale = np.where(grad > 0, k / np.where(grad > 0, grad, 1.0), r.min())
    dist = (k - 1.0) * scale
    return np.clip(0.5 - dist / h, 0.0, 1.0).astype(np.float32)


def _cylinder_z(X, Y, Z, radius: float, z0: float, z1: float, h: float) -> np.ndarray:
    """Anti-aliased occupancy of the z-aligned cylinder ``x² + y² < r²``, ``z0 < z < z1``."""
    radial = np.clip(0.5 - (np.sqrt(X * X + Y * Y) - radius) / h, 0.0, 1.0)
    axial = np.clip(0.5 - (np.maximum(z0 - Z, Z - z1)) / h, 0.0, 1.0)
    return (radial * axial).astype(np.float32)


def _smooth_halfspace(s, h: float) -> np.ndarray:
    """Anti-aliased indicator of ``s > 0``."""
    return np.clip(0.5 + s / h, 0.0, 1.0).astype(np.float32)


# --- stemmed glass (refraction, Magnus & Bruckner 2017 Fig. 8) ----------------------------------
#: Data values of the glass scene: wall and floor tiles, air, glass, liquid. Air sits between
#: the walls and everything else, so the walls' edges do not pass through glass or liquid.
GLASS_WALL_DARK, GLASS_WALL_LIGHT, GLASS_AIR, GLASS_GLASS, GLASS_LIQUID = -1.0, -0.7, 0.0, 1.0, 2.0
#: The glass scene's world box (z up; the camera looks along +y).
GLASS_BOX = ((-0.8, 0.8), (-0.8, 0.8), (-0.08, 1.6))
#: Material presets of :func:`glass_preset` (the series of the paper's Fig. 8).
GLASS_PRESETS = ("no-refraction", "medium", "beer", "juice", "wine")


def stemmed_glass(n: int = 96) -> Volume:
    """A stemmed glass half filled with liquid, on a checkered floor before a checkered wall.

    ``n`` points along x (and y); z has about 1.05 ``n`` (the paper's 768 x 768 x 800 at
    ``n = 768``). Values: -1 / -0.7 floor and back-wall tiles, 0 air, 1 glass (foot,
    stem, a tulip bowl 0.025 thick open at the top), 2 liquid (the bowl up to
    z = 1.0); edges anti-aliased over one voxel. World box: x, y in [-0.8, 0.8],
    z in [-0.08, 1.6]. Built slab by slab along z (float32), so ``n = 768`` needs about
    the volume's own 1.8 GiB.
    """
    n = _size(n, "n", 16)
    (x0, x1), (y0, y1), (z0, z1) = GLASS_BOX
    h = (x1 - x0) / (n - 1)
    nz = int(round((z1 - z0) / h)) + 1
    x = (x0 + h * np.arange(n)).astype(np.float32)
    y = (y0 + h * np.arange(n)).astype(np.float32)
    out = np.empty((n, n, nz), dtype=np.float32)
    X, Y = np.meshgrid(x, y - np.float32(-0.05), indexing="ij")  # glass axis at y = -0.05
    Xw, Yw = np.meshgrid(x, y, indexing="ij")
    tile = 0.2
    for k in range(nz):
        z = np.float32(z0 + h * k)
        Z = np.full_like(X, z)
        foot = _cylinder_z(X, Y, Z, 0.3, 0.0, 0.03, h)
        stem = _cylinder_z(X, Y, Z, 0.03, 0.02, 0.58, h)
        centre, radii = (0.0, 0.0, 0.95), np.array([0.33, 0.33, 0.40])
        outer = _ellipsoid(X, Y, Z, centre, radii, h)
        inner = _ellipsoid(X, Y, Z, centre, radii - 0.025, h)
        rim = _smooth_halfspace(1.22 - z, h)
        glass = np.maximum(np.maximum(foot, stem), outer * (1.0 - inner) * rim)
        liquid = inner * _smooth_halfspace(1.0 - z, h)
        floor = _smooth_halfspace(-z, h) * np.ones_like(X)
        wall = _smooth_halfspace(Yw - 0.62, h)
        solid = np.maximum(floor, wall)
        u = np.where(wall > floor, Xw, Yw)
        v = np.where(wall > floor, Z, Xw)
        checker = (np.floor(u / tile) + np.floor(v / tile)) % 2
        wall_value = np.where(checker > 0, GLASS_WALL_LIGHT, GLASS_WALL_DARK)
        out[:, :, k] = (GLASS_GLASS * glass * (1.0 - liquid) + GLASS_LIQUID * liquid) \
            * (1.0 - solid) + wall_value * solid
    return Volume(out, (h, h, h), (x0, y0, z0))


def _glass_scene(volume: Volume) -> Scene:
    return glass_preset(volume, "beer")[0]


def glass_preset(volume: Volume, preset: str = "beer"):
    """Scene and refractive optics of one of the paper's Fig. 8 materials for :func:`stemmed_glass`.

    ``"no-refraction"``: Porter–Duff only (semi-transparent reflective glass and liquid,
    η ≡ 1, white medium); ``"medium"``: nearly no opacity, colours from the medium only,
    η ≡ 1; ``"beer"``: glass 1.5, liquid 1.33, amber medium; ``"juice"``: the liquid
    dense and orange (dark shadow); ``"wine"``: green-tinted glass, dark red liquid.

    Returns
    -------
    scene : Scene
        Its ``optics`` are set as well.
    optics : vtkillum.core.refraction.optics.RefractiveOptics
    """
    from vtkillum.core.refraction.optics import RefractiveOptics

    if preset not in GLASS_PRESETS:
        raise ValueError(f"unknown glass preset {preset!r}; choose one of {GLASS_PRESETS}")
    white = [1.0, 1.0, 1.0]
    # Control points: wall tiles, the end of the walls' edge ramp, air, glass, liquid.
    s = [GLASS_WALL_DARK, GLASS_WALL_LIGHT, -0.35, GLASS_AIR, 0.45, GLASS_GLASS, 1.55, GLASS_LIQUID]
    wall = [0.9, 0.9, 0.0, 0.0]
    walls = [[0.55, 0.55, 0.6], [0.95, 0.93, 0.9], white, white]
    eta = [1.0, 1.0, 1.0, 1.0, 1.22, 1.5, 1.42, 1.33]
    glass_m, liquid_m = [0.97, 0.99, 0.97], [0.97, 0.8, 0.45]
    glass_a, liquid_a = 0.0005, 0.0005
    glass_c, liquid_c = white, [1.0, 0.75, 0.3]
    if preset == "no-refraction":
        eta = [1.0] * len(s)
        glass_m, liquid_m = white, white
        glass_a, liquid_a = 0.25, 0.12
        glass_c, liquid_c = [0.85, 0.9, 0.95], [1.0, 0.7, 0.25]
    elif preset == "medium":
        eta = [1.0] * len(s)
    elif preset == "juice":
        liquid_a, liquid_c, liquid_m = 0.35, [1.0, 0.55, 0.1], [0.95, 0.6, 0.2]
    elif preset == "wine":
        eta = [1.0, 1.0, 1.0, 1.0, 1.22, 1.5, 1.44, 1.35]
        glass_m, liquid_m = [0.8, 0.97, 0.8], [0.6, 0.04, 0.08]
        liquid_c = [0.5, 0.02, 0.05]
    opacity = wall + [glass_a * 0.5, glass_a, (glass_a + liquid_a) / 2, liquid_a]
    colours = walls + [glass_c, glass_c, glass_c, liquid_c]
    medium = [white] * 4 + [glass_m, glass_m, liquid_m, liquid_m]
    tf = TransferFunction(s, opacity, colours)
    optics = RefractiveOptics(s, eta, s, medium)
    camera = Camera((0.15, -3.3, 1.2), (0.0, 0.0, 0.66), (0.0, 0.0, 1.0), view_angle=24.0)
    scene = Scene(transfer_function=tf, opacity_unit_distance=0.1, albedo=0.9, anisotropy=0.0,
                  lights=[DirectionalLight((-0.35, 0.55, -0.75), (3.0, 2.95, 2.85))],
                  camera=camera, background=(0.0, 0.0, 0.0))
    scene.optics = optics
    return scene, optics
