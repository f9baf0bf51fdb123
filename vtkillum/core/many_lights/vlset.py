"""One set of virtual lights: its light paths, vertex arrays, AVSM slots and regeneration.

A *VL set* is the sequence of light paths ``0, 1, 2, ...`` of one seed (path ``p`` draws
from its own stream, :mod:`~vtkillum.core.many_lights.walk`), taken up to the first path
at which the set holds at least ``target`` VLs — the paper's "we keep spawning new
paths until we reach the desired total number of VPLs" (whole paths are kept, so a set
may hold a few more). Its vertices are stored grouped by path, in vertex order; the
path table holds each path's light, vertex count and creation batch.

Generation and *progressive regeneration* (paper section 4.2) are one procedure,
:meth:`VirtualLightSet.advance`: paths are (re)traced in index order — which is their
creation order — from a *frontier* on, replacing the stored ones; paths before the
frontier are current. An edit that needs redistribution resets the frontier to 0
(after an edit that arrives while a regeneration is unfinished every path is outdated
again, so it restarts at the first, oldest path); a frame then advances it by a fixed
fraction of the paths and a budget of new AVSMs. Once the current paths reach the
target, older paths beyond them are dropped; if all paths are current and short of the
target, new paths are spawned. When the frontier has passed the last path, the set is
exactly what a fresh generation with the same seed gives.

AVSMs (paper rules of section 4.2): the maps of regenerated VLs are built anew; the
maps of VLs not yet regenerated are kept as they are (stale after a change of
``sigma_t``, which is what the paper's Fig. 6 centre shows). A regenerated VL at
exactly the position of the one it replaces keeps that map when the medium it was built
for is unchanged (e.g. the paths of the other lights after a light moved).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from vtkillum.core.many_lights.avsm import ShadowMapPool
from vtkillum.core.many_lights.contribution import evaluate, freeze_densities, segment_depths
from vtkillum.core.many_lights.walk import WalkSetup, count_vertices, write_vertices
from vtkillum.core.warp_common import Lights, Medium

#: A set stops spawning paths after this many per requested VL (a medium that light
#: hardly reaches would otherwise never fill the set).
MAX_PATHS_PER_VL = 1024


@dataclass
class Environment:
    """What (re)generating paths needs, as of the current edit.

    Attributes
    ----------
    walk : WalkSetup
        Media, sources, lights and walk parameters of the distance sampling.
    medium : Medium
        The unscaled medium (optical depths, densities, AVSMs).
    lights : Lights
    scales : (float, float)
        Scales of the sampling density: ``(S, S)``, or ``(S_min, S_max)`` for eq. 8.
    depth_step : float
        Marching step of the segments' optical depths (world units).
    avsm_step, avsm_stop : float
        Texel-ray step (world units) and stopping transmittance of the AVSMs.
    epoch : int
        Version of ``sigma_t``: an AVSM built for another version is stale.
    """

    walk: WalkSetup
    medium: Medium
    lights: Lights
    scales: tuple
    depth_step: float
    avsm_step: float
    avsm_stop: float
    epoch: int


class VirtualLightSet:
    """The VLs of one seed and their AVSMs (see the module docstring).

    Parameters
    ----------
    target : int
        Requested number of VLs (at least 1).
    pool : ShadowMapPool or None
        Where the AVSMs live; ``None``: no transmittance caching (ray marching).
    device : str
    """

    def __init__(self, target: int, pool: ShadowMapPool | None, device: str) -> None:
        self.target = int(target)
        if self.target < 1:
            raise ValueError(f"the VL count must be at least 1, got {target}")
        self.pool = pool
        self.device = device
        self.path_count = np.zeros(0, np.int32)
        self.path_light = np.zeros(0, np.int32)
        self.path_created = np.zeros(0, np.int64)
        self.position = np.zeros((0, 3), np.float32)
        self.geom = np.zeros(0, np.float32)
        self.incident = np.zeros((0, 3), np.float32)
        self.tau = np.zeros(0, np.float32)
        self.pdf = np.zeros(0, np.float32)
        self.slot = np.zeros(0, np.int32)
        self.frontier = 0
        self.complete = False
        self.paths_at_reset = 0
        self.batches = 0
        self.capped_paths = 0
        self.path_limit_reached = False
        self.dev: dict = {}
        self._upload()

    # --- views --------------------------------------------------------------------------------
    @property
    def n_paths(self) -> int:
        return int(len(self.path_count))

    @property
    def n_vls(self) -> int:
        return int(len(self.geom))

    @property
    def path_offset(self) -> np.ndarray:
        """First vertex of each path, plus the total at the end: ``(n_paths + 1,)``."""
        return np.concatenate([[0], np.cumsum(self.path_count, dtype=np.int64)]).astype(np.int64)

    @property
    def vl_path(self) -> np.ndarray:
        """Path of each VL."""
        return np.repeat(np.arange(self.n_paths, dtype=np.int32), self.path_count)

    @property
    def vl_vertex(self) -> np.ndarray:
        """Index of each VL in its path (0: the first scattering vertex)."""
        offsets = self.path_offset[:-1]
        return (np.arange(self.n_vls) - np.repeat(offsets, self.path_count)).astype(np.int32)

    @property
    def stale_paths(self) -> int:
        """Paths not yet regenerated since the last edit (0 when complete)."""
        return 0 if self.complete else max(self.n_paths - self.frontier, 0)

    # --- editing ------------------------------------------------------------------------------
    def reset_frontier(self) -> None:
        """Mark every path outdated: regeneration restarts at path 0."""
        self.frontier = 0
        self.complete = False
        self.paths_at_reset = max(self.n_paths, 1)

    def clear(self) -> None:
        """Forget every path (a full regeneration follows)."""
        if self.pool is not None:
            self.pool.release(self.slot)
        self.__init__(self.target, self.pool, self.device)

    def advance(self, env: Environment, max_paths: int | None = None,
                max_new_vls: int | None = None) -> dict:
        """(Re)generate paths from the frontier on (see the module docstring).

        Parameters
        ----------
        env : Environment
        max_paths : int, optional
            Most paths to trace in this call (``None``: until the set is complete).
        max_new_vls : int, optional
            Most new VLs (AVSMs to build) in this call, at least one path is always
            traced (``None`` or 0: no limit).

        Returns
        -------
        dict
            ``paths`` traced, ``vls`` written, ``avsms`` built, ``reused`` maps kept,
            ``complete``.
        """
        stats = {"paths": 0, "vls": 0, "avsms": 0, "reused": 0}
        paths_left = math.inf if max_paths is None else max(int(max_paths), 1)
        vls_left = math.inf if not max_new_vls else max(int(max_new_vls), 1)
        path_cap = max(MAX_PATHS_PER_VL * self.target, 1 << 16)
        while not self.complete and paths_left > 0 and vls_left > 0:
            a = self.frontier
            have = int(self.path_count[:a].sum())
            need = self.target - have
            rate = have / a if a > 0 else (self.n_vls / self.n_paths if self.n_paths else 0.5)
            guess = math.ceil(need / max(rate, 1e-3) * 1.1) + 8 if need > 0 else 1
            k = int(min(paths_left, guess, path_cap - a, 1 << 22))
            counts, lights, capped = count_vertices(env.walk, a, k)
            self.capped_paths += capped
            cum = have + np.cumsum(counts, dtype=np.int64)
            hit = int(np.searchsorted(cum, self.target))  # first path reaching the target
            done = hit < k
            take = hit + 1 if done else k
            if math.isfinite(vls_left):
                within = int(np.searchsorted(np.cumsum(counts[:take]), vls_left, side="right"))
                if stats["paths"] == 0:
                    within = max(within, 1)  # progress: at least one path per call
                if within < take:
                    take, done = within, False
                if take == 0:
                    break
            if a + take >= path_cap and not done:
                done = True
                self.path_limit_reached = True
            s = self._splice(env, a, counts[:take], lights[:take], done)
            for key in s:
                stats[key] += s[key]
            stats["paths"] += take
            paths_left -= take
            vls_left -= int(counts[:take].sum())
        stats["complete"] = self.complete
        return stats

    def evaluate(self, medium: Medium, scale: float, lights: Lights) -> None:
        """Re-evaluate every VL's contribution (eq. 6) on the device."""
        d = self.dev
        evaluate(medium, scale, lights, d["path_offset"], d["path_count"], d["path_light"],
                 d["position"], d["incident"], d["tau"], d["pdf"], self.n_paths, d["power"],
                 d["direction"], d["extinction"], self.device)

    def remarch(self, env: Environment, only_first_segment: bool = False) -> None:
        """March the optical depths of all stored segments again (after a ``sigma_t`` edit,
        or of the first segments after a light moved)."""
        if self.n_vls == 0:
            return
        d = self.dev
        segment_depths(env.medium, env.lights, d["position"], d["vertex"], d["light_of"],
                       d["tau"], env.depth_step, self.device,
                       only_first_segment=only_first_segment)
        self.tau = d["tau"].numpy()[: self.n_vls].copy()

    def power(self) -> np.ndarray:
        """Current VL power ``(n_vls, 3)`` (host copy)."""
        return self.dev["power"].numpy()[: self.n_vls].copy()

    def extinction(self) -> np.ndarray:
        """``S sigma_t`` at each VL ``(n_vls,)`` (host copy)."""
        return self.dev["extinction"].numpy()[: self.n_vls].copy()

    def direction(self) -> np.ndarray:
        """Current incident directions ``(n_vls, 3)`` (host copy)."""
        return self.dev["direction"].numpy()[: self.n_vls].copy()

    # --- internals ----------------------------------------------------------------------------
    def _splice(self, env: Environment, a: int, counts: np.ndarray, lights: np.ndarray,
                done: bool) -> dict:
        """Replace paths ``a .. a + len(counts) - 1`` by newly traced ones (see advance)."""
        take = len(counts)
        b = a + take
        old_p = self.n_paths
        offsets = self.path_offset
        lo = int(offsets[min(a, old_p)])
        hi = int(offsets[min(b, old_p)])
        new_total = int(counts.sum())
        new_offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
        pos_dev, geom_dev, dir_dev = write_vertices(env.walk, np.arange(a, b, dtype=np.int32),
                                                    new_offsets, new_total)
        new_pos = pos_dev.numpy()[:new_total].reshape(-1, 3)
        new_geom = geom_dev.numpy()[:new_total]
        new_dir = dir_dev.numpy()[:new_total].reshape(-1, 3)

        # AVSM slots: keep the map of a VL that did not move, when its medium is unchanged.
        new_slot = np.full(new_total, -1, np.int32)
        same = np.zeros(new_total, bool)
        if self.pool is not None:
            new_path = np.repeat(np.arange(a, b), counts)
            new_k = np.arange(new_total) - np.repeat(new_offsets, counts)
            old_counts = np.zeros(new_total, np.int64)
            inside = new_path < old_p
            old_counts[inside] = self.path_count[new_path[inside]]
            match = inside & (new_k < old_counts)
            old_index = np.zeros(new_total, np.int64)
            old_index[match] = offsets[new_path[match]] + new_k[match]
            if match.any():
                oi = old_index[match]
                same[match] = (np.all(self.position[oi] == new_pos[match], axis=1)
                               & (self.pool.epoch[self.slot[oi]] == env.epoch))
            new_slot[same] = self.slot[old_index[same]]
            replaced = np.ones(hi - lo, bool)
            replaced[old_index[same] - lo] = False
            released = self.slot[lo:hi][replaced]
            if done:
                released = np.concatenate([released, self.slot[hi:]])
            self.pool.release(released)
            new_slot[~same] = self.pool.allocate(int((~same).sum()))

        # Splice the arrays (paths beyond the frontier are dropped once the set is complete).
        tail = slice(hi, None) if not done else slice(0, 0)
        ptail = slice(min(b, old_p), None) if not done else slice(0, 0)
        self.position = np.concatenate([self.position[:lo], new_pos, self.position[tail]])
        self.geom = np.concatenate([self.geom[:lo], new_geom, self.geom[tail]])
        self.incident = np.concatenate([self.incident[:lo], new_dir, self.incident[tail]])
        self.tau = np.concatenate([self.tau[:lo], np.zeros(new_total, np.float32), self.tau[tail]])
        self.pdf = np.concatenate([self.pdf[:lo], np.zeros(new_total, np.float32), self.pdf[tail]])
        self.slot = np.concatenate([self.slot[:lo], new_slot, self.slot[tail]])
        self.path_count = np.concatenate([self.path_count[:a], counts.astype(np.int32),
                                          self.path_count[ptail]])
        self.path_light = np.concatenate([self.path_light[:a], lights.astype(np.int32),
                                          self.path_light[ptail]])
        self.path_created = np.concatenate([self.path_created[:a],
                                            np.full(take, self.batches, np.int64),
                                            self.path_created[ptail]])
        self.batches += 1
        self.frontier = b
        if done:
            self.complete = True
        self._upload()

        # Optical depths and frozen densities of the new VLs, then their AVSMs.
        d = self.dev
        if new_total:
            segment_depths(env.medium, env.lights, d["position"], d["vertex"], d["light_of"],
                           d["tau"], env.depth_step, self.device, first=lo, count=new_total)
            freeze_densities(env.medium, env.scales[0], env.scales[1], d["position"], d["geom"],
                             d["tau"], d["pdf"], self.device, first=lo, count=new_total)
            self.tau = d["tau"].numpy()[: self.n_vls].copy()
            self.pdf = d["pdf"].numpy()[: self.n_vls].copy()
        built = 0
        if self.pool is not None and new_total:
            build = lo + np.flatnonzero(~same)
            if len(build):
                self.pool.build(env.medium, d["position"], build, self.slot[build],
                                env.avsm_step, env.epoch, env.avsm_stop)
            built = len(build)
        return {"vls": new_total, "avsms": built, "reused": int(same.sum())}

    def _upload(self) -> None:
        """Device mirrors of the host arrays (outputs ``power``/``direction`` sized to match)."""
        dev = self.device
        n = max(self.n_vls, 1)

        def arr(values, dtype):
            values = np.asarray(values)
            if len(values) == 0:  # kernels never read it, but warp wants a real array
                return wp.zeros(1, dtype=dtype, device=dev)
            return wp.array(np.ascontiguousarray(values), dtype=dtype, device=dev)

        self.dev = {
            "position": arr(self.position, wp.vec3),
            "geom": arr(self.geom, wp.float32),
            "incident": arr(self.incident, wp.vec3),
            "tau": arr(self.tau, wp.float32),
            "pdf": arr(self.pdf, wp.float32),
            "slot": arr(self.slot, wp.int32),
            "vertex": arr(self.vl_vertex, wp.int32),
            "light_of": arr(self.path_light[self.vl_path] if self.n_vls else [], wp.int32),
            "path_offset": arr(self.path_offset[:-1].astype(np.int32), wp.int32),
            "path_count": arr(self.path_count, wp.int32),
            "path_light": arr(self.path_light, wp.int32),
            "power": wp.zeros(n, dtype=wp.vec3, device=dev),
            "direction": wp.zeros(n, dtype=wp.vec3, device=dev),
            "extinction": wp.zeros(n, dtype=wp.float32, device=dev),
        }
