"""Fixed launch sequences replayed as captured graphs (CUDA graphs on GPUs).

An interactive update (the outer iterations of a multigrid solve, the wavefront sweeps of
the lights) is hundreds of small kernel launches whose arguments do not change from one
update to the next. Launched one by one from Python, each costs several microseconds
of host time, more than the kernel itself on small grids. :class:`LaunchGraphs` records
such a sequence once per key with :class:`warp.ScopedCapture` and replays it with
:func:`warp.capture_launch`: one call for the whole sequence.

Rules for a recorded sequence (what makes a replay equal to running it again):

* only device work: launches, ``array.zero_()``, device-to-device copies; no reads to
  the host, no allocations, no decisions on device values;
* everything it depends on is in its key: the arrays it touches (a replay uses the
  addresses of the capture) and every scalar argument;
* running it twice, or a part of it and then all of it, is harmless (a failed capture
  falls back to running it plainly).

A capture records without running (on CUDA and on the CPU alike), so the first call
replays right after recording.
``VTKILLUM_GRAPHS=0`` turns capture off (profiling per kernel, debugging).
"""

from __future__ import annotations

import os
import warnings

import warp as wp

#: Environment variable: "0" runs every sequence launch by launch.
ENV = "VTKILLUM_GRAPHS"
#: Graphs kept per cache before the oldest are dropped (keys change with the arrays).
MAX_GRAPHS = 64


def graphs_enabled() -> bool:
    """Whether capture is allowed (``VTKILLUM_GRAPHS`` is not ``0``)."""
    return os.environ.get(ENV, "1").strip().lower() not in ("0", "false", "no", "off")


def array_key(*arrays) -> tuple:
    """Identity of arrays for a graph key: address, shape and dtype (``None`` kept)."""
    return tuple(None if a is None else (a.ptr, tuple(a.shape), a.dtype) for a in arrays)


class LaunchGraphs:
    """A cache of captured launch sequences of one device.

    Parameters
    ----------
    device : str or warp.Device
        Where the sequences run.
    enabled : bool, optional
        Capture at all (default: :func:`graphs_enabled`).
    """

    def __init__(self, device, enabled: bool | None = None):
        self.device = wp.get_device(device)
        self.enabled = graphs_enabled() if enabled is None else bool(enabled)
        self._graphs: dict = {}
        #: Replays and captures so far (benchmarks and tests).
        self.replays = 0
        self.captures = 0

    def recorded(self, key) -> bool:
        """Whether :meth:`run` would replay ``key`` (its ``record`` is then not called)."""
        return self.enabled and key in self._graphs

    def run(self, key, record, keep=None) -> None:
        """Run ``record()``, from its captured graph when ``key`` was recorded before.

        ``keep``: objects the recording reads that nothing else keeps alive (e.g. small
        parameter arrays made for it); held as long as the graph.
        """
        if not self.enabled:
            record()
            return
        entry = self._graphs.get(key)
        graph = entry[0] if entry is not None else None
        if graph is None:
            try:
                with wp.ScopedCapture(device=self.device) as capture:
                    record()
            except Exception as exc:  # noqa: BLE001  (an uncapturable driver/op: run plainly)
                warnings.warn(f"vtkillum: launch-graph capture failed on {self.device} "
                              f"({exc}); running launch by launch from now on", RuntimeWarning,
                              stacklevel=2)
                self.enabled = False
                self._graphs.clear()
                record()
                return
            graph = capture.graph
            if len(self._graphs) >= MAX_GRAPHS:
                self._graphs.pop(next(iter(self._graphs)))
            self._graphs[key] = (graph, keep)
            self.captures += 1
        wp.capture_launch(graph)
        self.replays += 1

    def clear(self) -> None:
        """Forget every recorded sequence (e.g. after reallocating the arrays)."""
        self._graphs.clear()

    def __len__(self) -> int:
        return len(self._graphs)
