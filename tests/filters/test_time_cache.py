"""TimeStepCache: LRU order, byte budget, invalidation and counters."""

import pytest

from vtkillum.filters.time_cache import TimeStepCache


def test_lru_order_and_budget():
    cache = TimeStepCache(max_bytes=100)
    assert cache.store("a", 1, 40) and cache.store("b", 2, 40)
    assert cache.lookup("a") == 1  # "a" becomes the most recently used
    assert cache.store("c", 3, 40)  # evicts "b", the least recently used
    assert "b" not in cache and cache.get("a") == 1 and cache.get("c") == 3
    s = cache.statistics()
    assert (s.hits, s.evictions, s.entries, s.bytes) == (1, 1, 2, 80)
    assert cache.lookup("b") is None and cache.statistics().misses == 1


def test_too_large_values_are_not_stored_and_shrinking_evicts():
    cache = TimeStepCache(max_bytes=100)
    assert not cache.store("big", 0, 101) and len(cache) == 0
    for i in range(4):
        cache.store(i, i, 25)
    cache.max_bytes = 50
    assert [k for k in range(4) if k in cache] == [2, 3]
    assert cache.statistics().bytes == 50
    cache.max_bytes = 0
    assert len(cache) == 0 and not cache.store("x", 1, 1)
    with pytest.raises(ValueError):
        cache.max_bytes = -1


def test_replacing_a_key_and_invalidation():
    cache = TimeStepCache(max_bytes=100)
    cache.store((0.0, 1, 5), "x", 30)
    cache.store((0.0, 1, 5), "y", 20)  # same key: replaced, bytes not double counted
    cache.store((1.0, 1, 5), "z", 20)
    cache.store((1.0, 2, 5), "w", 20)
    assert cache.statistics().bytes == 60
    cache.keep_only(lambda key: key[1:] == (2, 5))
    s = cache.statistics()
    assert (s.entries, s.invalidations, s.bytes) == (1, 2, 20)
    cache.clear()
    assert len(cache) == 0 and cache.statistics().bytes == 0
