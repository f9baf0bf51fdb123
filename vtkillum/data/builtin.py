"""Dataset specifications ``builtin:NAME[:SIZE]`` for the procedural volumes.

::

    builtin:plume          smoke plume, 64 x 64 x 96 points
    builtin:plume:128      128 x 128 x 192 points (SIZE is the x resolution; z is 1.5x)
    builtin:ct:96          CT head phantom, 96^3
    builtin:cornell        Cornell box, 64^3
    builtin:marschner-lobb Marschner-Lobb signal, 41^3

Names are case-insensitive and accept the aliases of
:data:`vtkillum.data.procedural.SCENE_ALIASES` (``smoke``, ``cornell-box``,
``phantom``, ``ml``, ...).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from vtkillum.core.scene import Scene
from vtkillum.core.volume import Volume
from vtkillum.data import procedural

PREFIX = "builtin:"

#: Largest SIZE accepted (a 1024^3 float32 volume is already 4 GiB).
MAX_SIZE = 1024


@dataclass(frozen=True)
class BuiltinDataset:
    """A procedural dataset: how to build it at a given size, and its defaults."""

    name: str
    description: str
    default_size: int
    min_size: int
    build: Callable[[int], Volume]


def _plume(size: int) -> Volume:
    return procedural.smoke_plume((size, size, (3 * size) // 2))


#: Canonical name -> dataset.
DATASETS: dict[str, BuiltinDataset] = {
    "plume": BuiltinDataset("plume", "rising turbulent smoke plume (SIZE x SIZE x 1.5 SIZE)",
                            64, 4, _plume),
    "cornell": BuiltinDataset("cornell", "Cornell box: dense walls and blocks in thin fog",
                              64, 16, procedural.cornell_box),
    "ct": BuiltinDataset("ct", "CT head phantom: skin 0.3, tissue 0.5, bone 0.9",
                         64, 16, procedural.ct_phantom),
    "marschner-lobb": BuiltinDataset("marschner-lobb", "Marschner-Lobb test signal on [-1, 1]^3",
                                     41, 4, procedural.marschner_lobb),
    "glass": BuiltinDataset("glass", "stemmed glass with liquid on a checkered floor "
                            "(refraction; SIZE x SIZE x 1.05 SIZE)", 96, 16,
                            procedural.stemmed_glass),
}


def is_builtin(spec) -> bool:
    """Whether ``spec`` is a ``builtin:`` dataset specification (not a file path)."""
    return isinstance(spec, str) and spec.lower().startswith(PREFIX)


def parse_builtin(spec: str) -> tuple[str, int]:
    """Split ``builtin:NAME[:SIZE]`` into the canonical name and the size.

    Raises
    ------
    ValueError
        Not a ``builtin:`` spec, an unknown name (the message lists the names), or
        a SIZE that is not an integer in the dataset's range.
    """
    if not is_builtin(spec):
        raise ValueError(f"{spec!r} is not a built-in dataset spec; use builtin:NAME[:SIZE] "
                         f"with NAME one of {available()}")
    parts = spec[len(PREFIX):].split(":")
    if len(parts) > 2 or not parts[0]:
        raise ValueError(f"{spec!r}: expected builtin:NAME[:SIZE], e.g. builtin:plume:128; "
                         f"NAME is one of {available()}")
    key = procedural.SCENE_ALIASES.get(parts[0].lower())
    if key is None:
        raise ValueError(f"unknown built-in dataset {parts[0]!r}; choose one of {available()} "
                         "(e.g. builtin:plume:128)")
    dataset = DATASETS[key]
    if len(parts) == 1 or parts[1] == "":
        return key, dataset.default_size
    try:
        size = int(parts[1])
    except ValueError:
        raise ValueError(f"{spec!r}: SIZE must be an integer number of grid points, "
                         f"got {parts[1]!r}") from None
    if not dataset.min_size <= size <= MAX_SIZE:
        raise ValueError(f"{spec!r}: SIZE must lie in [{dataset.min_size}, {MAX_SIZE}] for "
                         f"{key}, got {size}")
    return key, size


def load_builtin(spec: str) -> Volume:
    """Build the volume named by ``builtin:NAME[:SIZE]``."""
    name, size = parse_builtin(spec)
    return DATASETS[name].build(size)


def builtin_scene(spec: str, volume: Volume | None = None) -> Scene:
    """The recommended scene (:func:`vtkillum.data.procedural.default_scene`) of a spec."""
    name, _ = parse_builtin(spec)
    return procedural.default_scene(name, volume if volume is not None else load_builtin(spec))


def available() -> str:
    """The dataset names, comma-separated."""
    return ", ".join(DATASETS)


def describe() -> str:
    """One line per dataset: name, default size, description."""
    return "\n".join(f"  builtin:{d.name}[:SIZE]  (default {d.default_size}) {d.description}"
                     for d in DATASETS.values())
