"""A least-recently-used cache of filter outputs with a memory budget in bytes.

Illumination filters keep one output per time step so that animating back and
forth through a time series re-executes neither the filter nor its upstream
(see :class:`vtkillum.filters.base.IlluminationFilterBase`). Entries are keyed
by ``(time, upstream pipeline MTime, filter MTime)``; once either MTime moves
on, older entries can never be hit again and :meth:`TimeStepCache.keep_only`
drops them.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass


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
