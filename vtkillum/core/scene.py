"""The scene file: one JSON description shared by the CLI, the tests and users.

Fields (unknown ones are an error, missing ones take the defaults below)::

    transfer_function      {"scalars": [...], "opacity": [...], "colors": [[r,g,b], ...]}
                           default: opacity ramp over the data range, white; optional
                           "refractive_index" and "medium_color" (core/refraction/optics.py)
    opacity_unit_distance  u in world units; default: the volume's mean spacing
    albedo                 single-scattering albedo Λ in [0, 1]; default 0.9
    anisotropy             Henyey–Greenstein g in (-1, 1); default 0
    lights                 list of {"type": "directional", "direction", "irradiance"} or
                           {"type": "point", "position", "intensity"};
                           default: one white directional light travelling (1, -1, -1)
    camera                 {"position", "focal_point", "view_up", "view_angle" | "parallel_scale"};
                           default: frames the volume like vtkRenderer.ResetCamera
    background             RGB composited behind the volume; default [0, 0, 0]
    step_size              ray-marching step in world units; default: half the smallest spacing
    shading                Phong terms of the illumination-volume shading (Zhang & Ma eq. 24):
                           {"ambient": 1.0, "diffuse": 0.0, "specular": 0.0, "shininess": 32}
    <method sections>      per-method options, see ``METHOD_OPTIONS``

Scene files are parsed by :func:`parse_json`, which bounds what plain ``json`` does not:
nesting (:data:`MAX_JSON_DEPTH` levels), integers (:data:`MAX_INTEGER_DIGITS` digits),
number literals (:data:`MAX_NUMBER_CHARS` characters) and refuses ``NaN``/``Infinity`` and
numbers beyond the float range, each in one message naming the line and column. A file is
read once (:func:`read_scene_data`), so a pipe such as ``/dev/stdin`` works.
"""

from __future__ import annotations

import copy
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vtkillum.core.camera import Camera
from vtkillum.core.lights import DirectionalLight, light_from_dict
from vtkillum.core.transfer_function import TransferFunction, check_unit_distance

#: Options of the methods that have their own scene section: field -> default.
METHOD_OPTIONS: dict[str, dict] = {
    "path": {"spp": 64, "max_bounces": 0, "seed": 0},  # max_bounces 0: unlimited (roulette)
    "convection_diffusion": {
        "light_volume_scale": 0.5,     # light-volume resolution relative to the data
        "diffusion_model": "physical",  # "physical" (radiative transfer) or "paper" (Zhang & Ma)
        "scattering": [0.0, 0.0, 0.0],  # paper model: diffusion coefficient sigma_hat_s, world units²
        "iterations": 0,               # diffusion iteration budget; 0: solve to convergence
        "solver": "multigrid",         # diffusion solver: multigrid, cg, gauss-seidel, dct
        "tolerance": 3e-4,             # relative residual (physical: relative correction)
        "source_radius": 0.0,          # point-light source region, world units; 0: 2 spacings
    },
    "ambient_scattering": {
        "radius": 4.0,                 # sphere radius r
        "radius_units": "voxels",      # "voxels" (x mean spacing) or "world"
        "radiance_cache_scale": 0.5,   # radiance-cache resolution relative to the data
        "specular": 0.0,               # weight of the specular lobe (0: off)
        "ambient_occlusion": False,    # add the SAT-based ambient-occlusion term
        "ambient_occlusion_strength": 0.25,  # its ambient fluence / sum of light irradiances
        "hardware_filtering": False,   # CUDA texture filtering of the grids (faster, ~1e-3 off)
        "data_textures": True,         # CUDA: the gather's data and TF through textures (~1e-3)
        "gather": "centred",           # "centred" or the paper's Algorithm 1 ("paper")
    },
    "photon": {  # photon mapping with Historygrams (Jönsson et al. 2012), core/photon/render.py
        "photons": 0, "radius": 0.0, "kernel_photons": 128, "max_order": 0, "segments": 8,
        "seed": 0,
        "historygrams": True, "spatial_historygram": True, "direct": "exact", "passes": 1,
        "alpha": 0.6666666666666666, "surface_range": [0.0, 0.0], "surface_gradient": 0.02,
        "surface_diffuse": 0.6, "surface_specular": 0.4, "surface_shininess": 40.0,
    },
    "refraction": {                    # Magnus & Bruckner 2017, see core/refraction/render.py
        "sample_distance": 1.0, "softness": 0.0, "direction_blur": 1.0,
        "intensity_correction": True, "max_concentration": 100.0, "specular": 1.0,
        "roughness": 0.3, "light_buffer_scale": 1.0, "environment": "",
        "early_termination": 0.999, "seed": 0,
    },
    "many_lights": {                   # see vtkillum.core.many_lights.render
        "count": 1024, "sets": 0, "max_sets": 64, "time_budget": 60.0, "noise_target": 0.03,
        "virtual_lights": "clamped", "vsl_radius": 0.0, "vsl_radius_mfp": 0.0,
        "vsl_neighbours": 16, "radius_exponent": 1.0 / 3.0,
        "transmittance": "avsm", "avsm_resolution": 16, "avsm_nodes": 8,
        "avsm_lookup": "trilinear", "distance_sampling": "delta-tracking", "phase_sampling": "hg",
        "view_samples": 4, "update_fraction": 0.1, "update_budget": 0,
        "scale_range": [1.0, 1.0], "density_scale": 1.0, "seed": 0,
    },
}

SHADING_DEFAULTS = {"ambient": 1.0, "diffuse": 0.0, "specular": 0.0, "shininess": 32.0}


def _integer(lo: int, hi: int = 2**63 - 1):
    # Bounded above too: the kernels take 64-bit integers at most.
    return lambda v: float(v).is_integer() and lo <= v <= hi


def _number(lo: float, hi: float = np.inf, lo_open: bool = False, hi_open: bool = False):
    return lambda v: ((v > lo) if lo_open else (v >= lo)) and ((v < hi) if hi_open else (v <= hi))


#: Ranges of the scene's sections, checked when a scene is built so that a mistake in a
#: scene file is reported with the file's name, before any rendering: (section, field) ->
#: (test of a value that already has the default's type, what the value must be). The
#: methods check their options again; fields not listed here (names such as the solver)
#: are left to them.
OPTION_CHECKS = {
    ("shading", "ambient"): (_number(0.0), "a non-negative number"),
    ("shading", "diffuse"): (_number(0.0), "a non-negative number"),
    ("shading", "specular"): (_number(0.0), "a non-negative number"),
    ("shading", "shininess"): (_number(0.0, lo_open=True), "a positive number"),
    ("path", "spp"): (_integer(1), "a positive integer below 2**63"),
    ("path", "max_bounces"): (_integer(0), "a non-negative integer below 2**63 (0: unlimited)"),
    ("path", "seed"): (_integer(-(2**63)), "an integer in [-2**63, 2**63)"),
    ("convection_diffusion", "scattering"): (
        lambda v: all(_real(x) and x >= 0 for x in v), "three non-negative numbers"),
    ("convection_diffusion", "iterations"): (
        _integer(0), "a non-negative integer below 2**63 (0: solve to convergence)"),
    ("convection_diffusion", "tolerance"): (
        _number(0.0, 1.0, lo_open=True, hi_open=True), "a number in (0, 1)"),
    ("convection_diffusion", "source_radius"): (
        _number(0.0), "a non-negative number of world units (0: 2 spacings)"),
    ("ambient_scattering", "radius"): (_number(0.0, lo_open=True), "a positive number"),
    ("ambient_scattering", "radius_units"): (lambda v: v in ("voxels", "world"),
                                             "'voxels' or 'world'"),
    ("ambient_scattering", "radiance_cache_scale"): (
        _number(0.0, 1.0, lo_open=True), "a number in (0, 1]"),
    ("ambient_scattering", "specular"): (_number(0.0), "a non-negative number"),
    ("ambient_scattering", "ambient_occlusion_strength"): (_number(0.0), "a non-negative number"),
}


#: Light fields that hold numbers (strings such as "0.5" are refused, as for ``albedo``).
NUMERIC_LIGHT_FIELDS = {"direction", "irradiance", "position", "intensity", "radius"}


def _real(value) -> bool:
    """A finite real number (not a bool, not a string)."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, np.integer)):
        return True  # (np.isfinite refuses Python integers beyond 64 bits)
    return isinstance(value, (float, np.floating)) and bool(np.isfinite(value))


def _check_numbers(value, where: str, depth: int = 0) -> None:
    """Refuse anything but (nested lists of) numbers: strings such as "0.5" included."""
    items = value if isinstance(value, (list, tuple)) else [value]
    for item in items:
        if isinstance(item, (list, tuple)):
            if depth >= 2:  # vectors and lists of vectors at most: no deep recursion
                raise ValueError(f"{where} must hold numbers (or lists of numbers), got lists "
                                 "nested deeper")  # (no repr: it would recurse as deep)
            _check_numbers(item, where, depth + 1)
        elif not _real(item):
            raise ValueError(f"{where} must hold finite numbers, got {_short(value)}")


#: Characters of a user-supplied value that an error message shows at most.
MAX_SHOWN = 300


def _short(value, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters (the length said when cut)."""
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[: limit - 30]}... ({len(text)} characters)"


def _names(keys) -> str:
    """Field names for a message: each cut to 60 characters, at most ten of them."""
    keys = sorted(str(k) for k in keys)
    shown = [_short(k, 60) for k in keys[:10]]
    more = f", ... ({len(keys) - 10} more)" if len(keys) > 10 else ""
    return f"[{', '.join(shown)}{more}]"


def shorten_message(text: str, limit: int = MAX_SHOWN) -> str:
    """``text`` with every run of more than ``limit`` non-blank characters cut.

    A safety net for messages that quote what the user typed (a 100 kB key, a number of
    5000 digits): the head and tail of the run stay, the middle says how long it was.
    The whole message is also kept under ``4 * limit`` characters.
    """
    def cut(match):
        run = match.group()
        return f"{run[: limit // 2]}...({len(run)} characters)...{run[-limit // 6:]}"

    text = re.sub(rf"\S{{{limit + 1},}}", cut, text)
    if len(text) > 4 * limit:
        text = f"{text[: 3 * limit]} ...({len(text)} characters)... {text[-limit // 2:]}"
    return text


# --- bounded JSON -------------------------------------------------------------------------------
#: Deepest nesting of arrays and objects accepted: a scene needs four levels; the bound
#: keeps every parser and check far from Python's recursion limit.
MAX_JSON_DEPTH = 64
#: Longest integer accepted, in digits (Python refuses to convert more than 4300 and
#: no field needs more than a 64-bit seed).
MAX_INTEGER_DIGITS = 30
#: Longest number literal of any kind accepted, in characters.
MAX_NUMBER_CHARS = 100

#: What the scan of :func:`parse_json` looks at: strings (skipped, also unterminated
#: ones), brackets, the non-standard constants and number literals.
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"?|[\[{\]}]|-?Infinity|NaN|-?[0-9][0-9.eE+\-]*')


class JSONLimitError(ValueError):
    """Valid JSON (to Python) beyond what vtkillum accepts: too deep, a number too long or
    not finite. Raised before any conversion, naming the place."""


def parse_json(text: str, what: str = "JSON"):
    """``json.loads(text)`` with bounds on nesting and numbers, finite numbers only.

    Parameters
    ----------
    text : str
        The JSON text.
    what : str
        What the text is, for messages (a file name, ``--option step_size``).

    Raises
    ------
    JSONLimitError
        Nesting deeper than :data:`MAX_JSON_DEPTH`, an integer longer than
        :data:`MAX_INTEGER_DIGITS` digits, a number literal longer than
        :data:`MAX_NUMBER_CHARS`, ``NaN``/``Infinity`` or a number beyond the float range;
        the message names the line and column and shows at most a short part of the value.
    json.JSONDecodeError
        Not JSON.
    """
    depth = 0
    for match in _JSON_TOKENS.finditer(text):
        token = match.group()
        first = token[0]
        if first == '"':
            continue
        if first in "[{":
            depth += 1
            if depth > MAX_JSON_DEPTH:
                raise JSONLimitError(
                    f"{what}: arrays/objects nested more than {MAX_JSON_DEPTH} levels deep "
                    f"({_position(text, match.start())}); scenes and options need only a few")
        elif first in "]}":
            depth = max(depth - 1, 0)
        elif token.lstrip("-") in ("NaN", "Infinity"):
            raise JSONLimitError(f"{what}: {token} ({_position(text, match.start())}) is not a "
                                 "number vtkillum accepts; give finite numbers")
        else:
            _check_number_literal(token, what, text, match.start())
    return json.loads(text, parse_int=_parse_int, parse_float=_parse_float,
                      parse_constant=_parse_constant)


def _position(text: str, index: int) -> str:
    line = text.count("\n", 0, index) + 1
    column = index - text.rfind("\n", 0, index)
    return f"line {line}, column {column}"


def _check_number_literal(token: str, what: str, text: str, index: int) -> None:
    digits = sum(c.isdigit() for c in token)
    integer = not any(c in token for c in ".eE")
    shown = token if len(token) <= 40 else f"{token[:20]}...{token[-10:]}"
    if integer and digits > MAX_INTEGER_DIGITS:
        raise JSONLimitError(f"{what}: an integer of {digits} digits ({shown}, "
                             f"{_position(text, index)}); integers may have at most "
                             f"{MAX_INTEGER_DIGITS} digits")
    if len(token) > MAX_NUMBER_CHARS:
        raise JSONLimitError(f"{what}: a number of {len(token)} characters ({shown}, "
                             f"{_position(text, index)}); numbers may have at most "
                             f"{MAX_NUMBER_CHARS}")
    try:
        value = float(token)
    except ValueError:
        return  # not a number after all: json.loads reports it
    if not np.isfinite(value):
        raise JSONLimitError(f"{what}: {shown} ({_position(text, index)}) is beyond the range "
                             "of floating-point numbers (about 1.8e308)")


# Backstops of the scan (json.loads calls them for every number and constant).
def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INTEGER_DIGITS:
        raise JSONLimitError(f"an integer of {len(text.lstrip('-'))} digits; integers may have "
                             f"at most {MAX_INTEGER_DIGITS} digits")
    return int(text)


def _parse_float(text: str) -> float:
    value = float(text)
    if not np.isfinite(value):
        raise JSONLimitError(f"{text[:40]} is beyond the range of floating-point numbers")
    return value


def _parse_constant(text: str):
    raise JSONLimitError(f"{text} is not a number vtkillum accepts; give finite numbers")

TOP_LEVEL = {"transfer_function", "opacity_unit_distance", "albedo", "anisotropy", "lights",
             "camera", "background", "step_size", "shading"} | set(METHOD_OPTIONS)


@dataclass
class Scene:
    """Everything but the data that a render needs. See the module docstring for fields."""

    transfer_function: TransferFunction | None = None
    opacity_unit_distance: float | None = None
    albedo: float = 0.9
    anisotropy: float = 0.0
    lights: list = field(default_factory=lambda: [DirectionalLight((1.0, -1.0, -1.0))])
    camera: Camera | None = None
    background: np.ndarray = (0.0, 0.0, 0.0)
    step_size: float | None = None
    shading: dict = field(default_factory=lambda: dict(SHADING_DEFAULTS))
    options: dict = field(default_factory=lambda: copy.deepcopy(METHOD_OPTIONS))
    #: Refractive index and medium colour (``transfer_function.refractive_index`` /
    #: ``.medium_color`` in the file): a RefractiveOptics, None for η ≡ 1, m ≡ white.
    optics: object = None

    def __post_init__(self) -> None:
        if not (0.0 <= float(self.albedo) <= 1.0):
            raise ValueError(f"albedo must lie in [0, 1], got {self.albedo}")
        if not (-1.0 < float(self.anisotropy) < 1.0):
            raise ValueError(f"anisotropy must lie in (-1, 1), got {self.anisotropy}")
        self.albedo, self.anisotropy = float(self.albedo), float(self.anisotropy)
        if self.opacity_unit_distance is not None:
            self.opacity_unit_distance = check_unit_distance(self.opacity_unit_distance)
        if self.step_size is not None:
            step = float(self.step_size)  # (np.isfinite refuses Python integers beyond 64 bits)
            if not (np.isfinite(step) and step > 0):
                raise ValueError(f"step_size must be positive, got {_short(self.step_size)}")
            self.step_size = step
        if np.asarray(self.background).dtype.kind not in "iuf":
            raise ValueError(f"background must be three non-negative numbers, got "
                             f"{_short(self.background)}")
        bg = np.asarray(self.background, dtype=np.float64).reshape(-1)
        if bg.shape != (3,) or not np.all(np.isfinite(bg)) or np.any(bg < 0):
            raise ValueError("background must be three non-negative numbers")
        self.background = bg
        if not self.lights:
            raise ValueError("lights: at least one light is needed")
        self.shading = _merge("shading", SHADING_DEFAULTS, self.shading)
        merged = copy.deepcopy(METHOD_OPTIONS)
        for name, opts in (self.options or {}).items():
            if name not in METHOD_OPTIONS:
                raise ValueError(f"unknown method section {_short(name, 60)}; known: "
                                 f"{sorted(METHOD_OPTIONS)}")
            merged[name] = _merge(name, METHOD_OPTIONS[name], opts)
        self.options = merged
        if self.optics is not None:
            from vtkillum.core.refraction.optics import RefractiveOptics

            if not isinstance(self.optics, RefractiveOptics):
                raise ValueError("optics must be a RefractiveOptics (refractive index and medium "
                                 f"colour), got {type(self.optics).__name__}")

    # --- resolution of data-dependent defaults --------------------------------------------
    def resolved_transfer_function(self, volume) -> TransferFunction:
        if self.transfer_function is not None:
            return self.transfer_function
        lo, hi = volume.value_range
        return TransferFunction.ramp(lo, hi if hi > lo else lo + 1.0, 0.5)

    def resolved_unit_distance(self, volume) -> float:
        return self.opacity_unit_distance or volume.mean_spacing()

    def resolved_step_size(self, volume) -> float:
        return self.step_size or 0.5 * float(volume.spacing.min())

    def resolved_camera(self, volume) -> Camera:
        return self.camera or Camera.looking_at_bounds(volume.bounds, direction=(-0.4, -0.3, -1.0))

    # --- (de)serialisation -------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {
            "albedo": self.albedo,
            "anisotropy": self.anisotropy,
            "lights": [l.to_dict() for l in self.lights],
            "background": self.background.tolist(),
            "shading": dict(self.shading),
        }
        if self.transfer_function is not None:
            d["transfer_function"] = self.transfer_function.to_dict()
            if self.optics is not None:
                d["transfer_function"].update(self.optics.to_dict())
        if self.opacity_unit_distance is not None:
            d["opacity_unit_distance"] = self.opacity_unit_distance
        if self.camera is not None:
            d["camera"] = self.camera.to_dict()
        if self.step_size is not None:
            d["step_size"] = self.step_size
        d.update(copy.deepcopy(self.options))
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Scene":
        """Validate and build; a ``ValueError`` names the offending field."""
        if not isinstance(d, dict):
            raise ValueError("a scene must be a JSON object")
        unknown = set(d) - TOP_LEVEL
        if unknown:
            raise ValueError(f"unknown scene field(s) {_names(unknown)}; known: "
                             f"{sorted(TOP_LEVEL)}")
        kw = {}
        if "transfer_function" in d:
            from vtkillum.core.refraction.optics import split_transfer_function

            tf, optics = split_transfer_function(d["transfer_function"])
            kw["transfer_function"] = TransferFunction.from_dict(tf)
            if optics is not None:
                kw["optics"] = optics
        if "lights" in d:
            if not isinstance(d["lights"], list):
                raise ValueError("lights must be a list of light objects")
            for i, light in enumerate(d["lights"]):
                if isinstance(light, dict):
                    for key, value in light.items():
                        if key in NUMERIC_LIGHT_FIELDS:
                            _check_numbers(value, f"lights[{i}].{key}")
            kw["lights"] = [light_from_dict(l, i) for i, l in enumerate(d["lights"])]
        if "camera" in d:
            if isinstance(d["camera"], dict):
                for key, value in d["camera"].items():
                    _check_numbers(value, f"camera.{key}")
            kw["camera"] = Camera.from_dict(d["camera"])
        for key in ("opacity_unit_distance", "albedo", "anisotropy", "step_size"):
            if key in d:
                if not isinstance(d[key], (int, float)) or isinstance(d[key], bool):
                    raise ValueError(f"{key} must be a number, got {_short(d[key])}")
                kw[key] = d[key]
        if "background" in d:
            kw["background"] = d["background"]
        if "shading" in d:
            kw["shading"] = d["shading"]
        kw["options"] = {k: d[k] for k in METHOD_OPTIONS if k in d}
        try:
            return cls(**kw)
        except (TypeError, ValueError) as err:
            raise ValueError(str(err)) from err


def _merge(section: str, defaults: dict, given) -> dict:
    if not isinstance(given, dict):
        raise ValueError(f"{section} must be an object")
    unknown = set(given) - set(defaults)
    if unknown:
        raise ValueError(f"{section}: unknown field(s) {_names(unknown)}; known: "
                         f"{sorted(defaults)}")
    out = dict(defaults)
    for key, value in given.items():
        ref = defaults[key]
        if isinstance(ref, bool):
            ok = isinstance(value, bool)
        elif isinstance(ref, (int, float)):
            ok = _real(value) and isinstance(value, (int, float))
        elif isinstance(ref, list):
            ok = isinstance(value, list) and len(value) == len(ref)
        else:
            ok = isinstance(value, type(ref))
        if not ok:
            raise ValueError(f"{section}.{key}: expected a value like {ref!r}, got "
                             f"{_short(value)}")
        if isinstance(ref, list) and not all(_real(v) for v in value if not isinstance(v, str)):
            raise ValueError(f"{section}.{key} must hold finite numbers, got {_short(value)}")
        check = OPTION_CHECKS.get((section, key))
        if check is not None and not check[0](value):
            raise ValueError(f"{section}.{key} must be {check[1]}, got {_short(value)}")
        out[key] = value
    return out


def read_scene_data(path):
    """The JSON value of the scene file ``path``, read once (pipes such as ``/dev/stdin``
    work) and parsed with :func:`parse_json`; errors name the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"scene file {path} does not exist") from None
    except IsADirectoryError:
        raise ValueError(f"scene file {path} is a directory; give a JSON file") from None
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not a JSON scene file (binary data: byte "
                         f"0x{err.object[err.start]:02x} at position {err.start} is not UTF-8 "
                         "text)") from None
    try:
        return parse_json(text, str(path))
    except JSONLimitError:
        raise
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from err


def scene_from_data(data, path=None) -> Scene:
    """:meth:`Scene.from_dict` of a scene file's JSON value; errors name ``path`` and are
    cut to a readable length (:func:`shorten_message`)."""
    try:
        return Scene.from_dict(data)
    except ValueError as err:
        where = f"{path}: " if path is not None else ""
        raise ValueError(shorten_message(f"{where}{err}")) from err


def load_scene(path) -> Scene:
    """Read and validate a scene file; errors name the file and the field."""
    return scene_from_data(read_scene_data(path), path)


def scene_json(scene: Scene) -> str:
    """``scene`` as the JSON text :func:`save_scene` writes."""
    return json.dumps(scene.to_dict(), indent=2)


def save_scene(scene: Scene, path) -> None:
    """Write ``scene`` as JSON (round-trips through :func:`load_scene`)."""
    Path(path).write_text(scene_json(scene))
