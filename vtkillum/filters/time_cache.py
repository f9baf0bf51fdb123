"""A least-recently-used cache of filter outputs with a memory budget in bytes.

Illumination filters keep one output per time step so that animating back and
forth through a time series re-executes neither the filter nor its upstream
(see :class:`vtkillum.filters.base.IlluminationFilterBase`). Entries are keyed
by ``(time, upstream pipeline MTime, filter MTime)``; once either MTime moves
on, older entries can never be hit again and :meth:`TimeStepCache.keep_only`
drops them.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass

#: Share of the memory available when vtkillum is imported that each filter's time cache
#: may use by default, and the least it gets.
DEFAULT_SHARE = 0.25
FLOOR_MB = 512.0


def available_memory_mb() -> float | None:
    """Memory available to new allocations without swapping (MB), or None if unknown."""
    try:
        with open("/proc/meminfo") as meminfo:  # Linux: MemAvailable counts reclaimable cache
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (AttributeError, ValueError, OSError):
        return None


def default_cache_mb(share: float = DEFAULT_SHARE, floor: float = FLOOR_MB) -> float:
    """Default time-cache budget: ``share`` of the available memory, at least ``floor`` MB.

    A fixed 512 MB held fewer than 4 steps of a 197x233x189 brain's illumination (six
    float arrays per point), so stepping back through a series recomputed; a quarter of
    what is free holds tens of such steps on a workstation and still leaves room for the
    data, ParaView and other filters (each filter has its own budget). Rounded down to
    a multiple of 64 MB.
    """
    available = available_memory_mb()
    if available is None:
        return floor
    return max(floor, float(int(share * available) // 64 * 64))


@dataclass
class CacheStatistics:
    """Counters of a :class:`TimeStepCache` (for reports and tests)."""

    hits: int = 0
    misses: int = 0
    evictions: int = 0  # dropped to stay within the budget
    invalidations: int = 0  # dropped because the pipeline or the parameters changed
    entries: int = 0
    bytes: int = 0
    max_bytes: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class TimeStepCache:
    """LRU mapping ``key -> value`` whose values' sizes add up to at most ``max_bytes``.

    Parameters
    ----------
    max_bytes : int
        Memory budget; 0 disables caching. A value larger than the budget is not stored.
    """

    def __init__(self, max_bytes: int) -> None:
        self._entries: OrderedDict = OrderedDict()  # key -> (value, nbytes)
        self._stats = CacheStatistics()
        self.max_bytes = max_bytes

    @property
    def max_bytes(self) -> int:
        return self._stats.max_bytes

    @max_bytes.setter
    def max_bytes(self, value: int) -> None:
        value = int(value)
        if value < 0:
            raise ValueError(f"cache size must be >= 0, got {value}")
        self._stats.max_bytes = value
        self._shrink(value)

    def lookup(self, key):
        """The value stored under ``key`` (now most recently used), or ``None``; counted."""
        if key in self._entries:
            self._entries.move_to_end(key)
            self._stats.hits += 1
            return self._entries[key][0]
        self._stats.misses += 1
        return None

    def __contains__(self, key) -> bool:
        return key in self._entries

    def get(self, key):
        """Like :meth:`lookup` but neither counted nor reordered."""
        entry = self._entries.get(key)
        return None if entry is None else entry[0]

    def store(self, key, value, nbytes: int) -> bool:
        """Store ``value`` (``nbytes`` large), evicting least recently used entries.

        Returns ``False`` (and stores nothing) when ``nbytes`` exceeds the budget.
        """
        nbytes = int(nbytes)
        self._remove(key)
        if nbytes > self.max_bytes:
            return False
        self._shrink(self.max_bytes - nbytes)
        self._entries[key] = (value, nbytes)
        self._stats.bytes += nbytes
        return True

    def keep_only(self, predicate) -> None:
        """Drop (as invalidated) every entry whose key fails ``predicate(key)``."""
        for key in [k for k in self._entries if not predicate(k)]:
            self._remove(key)
            self._stats.invalidations += 1

    def clear(self) -> None:
        """Drop every entry (counters other than size are kept)."""
        self._entries.clear()
        self._stats.bytes = 0

    def statistics(self) -> CacheStatistics:
        """A snapshot of the counters."""
        s = CacheStatistics(**self._stats.as_dict())
        s.entries = len(self._entries)
        return s

    def reset_statistics(self) -> None:
        self._stats.hits = self._stats.misses = 0
        self._stats.evictions = self._stats.invalidations = 0

    def __len__(self) -> int:
        return len(self._entries)

    # --- internals --------------------------------------------------------------------------
    def _remove(self, key) -> None:
        entry = self._entries.pop(key, None)
        if entry is not None:
            self._stats.bytes -= entry[1]

    def _shrink(self, limit: int) -> None:
        while self._entries and self._stats.bytes > limit:
            _, (_, nbytes) = self._entries.popitem(last=False)
            self._stats.bytes -= nbytes
            self._stats.evictions += 1
