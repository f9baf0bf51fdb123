"""The photon method's transfer-function tables, built on the device with the query
Historygrams of an edit.

An edit's update needs the new σt and colour tables on the device and the query masks
(:func:`~vtkillum.core.photon.historygram.query_masks`: the data bins whose σt or colour
changed). Sampling the transfer function into 4096 entries with numpy, comparing them
with the previous ones and uploading them costs about a millisecond of host time, as
much as the rest of a local edit's update; here one launch samples the control points
into the tables, compares each entry with the previous table and ORs the bins it
influences into the masks, and one small read brings the masks and the σt maximum back.

The kernel evaluates the same piecewise-linear functions as
:meth:`~vtkillum.core.transfer_function.TransferFunction.sigma_t_and_color` in float64
(halved control points, as ``_interp``, so control points at ±1e308 stay exact), then
rounds to float32; the entries agree with the host's
:func:`~vtkillum.core.photon.tracing.photon_tables` to float32 rounding (a device may
contract ``a * b + c`` into one rounding). The full trace and every incremental update
use these tables alike, so an update still equals a full recompute bit for bit.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import init_warp
from vtkillum.core.photon.historygram import ALL_BITS, BITS
from vtkillum.core.transfer_function import MAX_ALPHA, TABLE_SIZE

init_warp()

#: Slots of the result array: the σt bins and colour bins of the changed entries,
#: whether any σt / colour entry changed at all, and the largest σt (a float32 in the
#: slot's first four bytes).
SIGMA_BINS, COLOR_BINS, SIGMA_CHANGED, COLOR_CHANGED, PEAK = range(5)


@wp.func
def log1p64(x: wp.float64):
    """``log(1 + x)`` accurate for small ``x`` (Goldberg's correction of ``log(1 + x)``)."""
    u = wp.float64(1.0) + x
    if u == wp.float64(1.0):
        return x
    return wp.log(u) * x / (u - wp.float64(1.0))


@wp.func
def table_value(i: int, n: int, lo: wp.float64, step: wp.float64, hi: wp.float64):
    """Data value of entry ``i`` of ``n`` (as ``np.linspace(lo, hi, n)``: the last is ``hi``)."""
    if i == n - 1:
        return hi
    return lo + wp.float64(i) * step


@wp.func
def bins_between(a: wp.float64, b: wp.float64, lo: wp.float64, hi: wp.float64):
    """Data bins meeting ``[a, b]`` (:func:`~vtkillum.core.photon.historygram.interval_mask`)."""
    if hi <= lo:
        return wp.uint64(1)
    width = (hi - lo) / wp.float64(64.0)
    eps = wp.float64(1.0e-6) * (hi - lo)
    if b + eps < lo or a - eps > hi:
        return wp.uint64(0)
    i0 = wp.clamp(int(wp.floor((a - eps - lo) / width)), 0, 63)
    i1 = wp.clamp(int(wp.floor((b + eps - lo) / width)), 0, 63)
    top = wp.uint64(1) << wp.uint64(i1)
    upto = top | (top - wp.uint64(1))  # bits 0..i1
    below = (wp.uint64(1) << wp.uint64(i0)) - wp.uint64(1)  # bits 0..i0-1 (i0 <= i1)
    return upto - below


@wp.func
def interp_column(points: wp.array(dtype=wp.float64), k: int, c: int, j: int, j1: int,
                  t: wp.float64):
    """Column ``c`` of the ``k`` control points (rows of 5) interpolated between rows ``j``
    and ``j1``, kept within the column's range (as ``_interp``)."""
    f = (wp.float64(1.0) - t) * points[j * 5 + c] + t * points[j1 * 5 + c]
    fmin = points[c]
    fmax = points[c]
    for q in range(1, k):
        fmin = wp.min(fmin, points[q * 5 + c])
        fmax = wp.max(fmax, points[q * 5 + c])
    return wp.clamp(f, fmin, fmax)


@wp.kernel
def tf_tables_kernel(points: wp.array(dtype=wp.float64), k: int, lo: wp.float64, step: wp.float64,
                     hi: wp.float64, unit_distance: wp.float64, max_alpha: wp.float64,
                     sigma: wp.array(dtype=wp.float32), color: wp.array(dtype=wp.vec3),
                     old_sigma: wp.array(dtype=wp.float32), old_color: wp.array(dtype=wp.vec3),
                     compare: int, bin_lo: wp.float64, bin_hi: wp.float64,
                     result: wp.array(dtype=wp.uint64), peak: wp.array(dtype=wp.float32)):
    """``wp.tid()`` = table entry ``i``: σt and colour at its data value from the ``k``
    control points ``points`` (rows of 5: value, opacity, r, g, b); with ``compare``, ORs
    the bins the entry influences into ``result`` where it differs from the old table."""
    i = wp.tid()
    n = sigma.shape[0]
    v = table_value(i, n, lo, step, hi)
    # The control point left of v: the first with value > v, minus one, kept in [0, k-2].
    a = int(0)
    b = k
    while a < b:
        mid = (a + b) // 2
        if points[mid * 5] <= v:
            a = mid + 1
        else:
            b = mid
    j = wp.clamp(a - 1, 0, wp.max(k - 2, 0))
    t = wp.float64(0.0)
    j1 = j
    if k > 1:
        j1 = j + 1
        h0 = wp.float64(0.5) * points[j * 5]
        t = (wp.float64(0.5) * v - h0) / (wp.float64(0.5) * points[j1 * 5] - h0)
        t = wp.clamp(t, wp.float64(0.0), wp.float64(1.0))
    alpha = interp_column(points, k, 1, j, j1, t)
    s = wp.float32(-log1p64(-wp.min(alpha, max_alpha)) / unit_distance)
    col = wp.vec3(wp.float32(interp_column(points, k, 2, j, j1, t)),
                  wp.float32(interp_column(points, k, 3, j, j1, t)),
                  wp.float32(interp_column(points, k, 4, j, j1, t)))
    sigma[i] = s
    color[i] = col
    wp.atomic_max(peak, 0, s)
    if compare != 0:
        s_changed = old_sigma[i] != s
        oc = old_color[i]
        c_changed = oc[0] != col[0] or oc[1] != col[1] or oc[2] != col[2]
        if s_changed or c_changed:
            # An entry is interpolated for values between its neighbours.
            bins = bins_between(table_value(wp.max(i - 1, 0), n, lo, step, hi),
                                table_value(wp.min(i + 1, n - 1), n, lo, step, hi),
                                bin_lo, bin_hi)
            if s_changed:
                wp.atomic_or(result, SIGMA_BINS, bins)
                wp.atomic_or(result, SIGMA_CHANGED, wp.uint64(1))
            if c_changed:
                wp.atomic_or(result, COLOR_BINS, bins)
                wp.atomic_or(result, COLOR_CHANGED, wp.uint64(1))


def table_range(value_range) -> tuple[float, float]:
    """``(lo, hi)`` of the tables (here and in the host's
    :func:`~vtkillum.core.photon.tracing.photon_tables`): the data range, widened for
    constant data."""
    lo, hi = (float(v) for v in value_range)
    if not hi - lo > 0:  # constant data; lo + 1 == lo for |lo| > 2**53
        hi = lo + max(1.0, abs(lo) * 1e-6)
    return lo, hi


class DeviceTables:
    """σt and colour tables of a transfer function on the device, and what an edit changed.

    Parameters
    ----------
    transfer_function : TransferFunction
    unit_distance : float
        Opacity unit distance (world units).
    value_range : (float, float)
        The volume's data range: the tables span it (see :func:`table_range`), and it is
        the domain of the Historygram bins.
    device : str
    previous : DeviceTables, optional
        The tables before the edit (same size and range): the entries that differ set
        :attr:`sigma_bins` / :attr:`color_bins`.
    size : int
        Entries per table.

    Attributes
    ----------
    sigma : wp.array(float32) (size,)
    color : wp.array(vec3) (size,)
    lo, hi : float
        Data values of the first and last entries.
    peak : float
        Largest σt entry.
    sigma_bins, color_bins : int
        Query Historygrams of the edit (64-bit masks as Python ints): every bin when there
        is no comparable ``previous``.
    sigma_changed, color_changed : bool
        Whether any entry changed (every entry counts as changed without ``previous``).
    """

    def __init__(self, transfer_function, unit_distance: float, value_range, device: str,
                 previous: "DeviceTables | None" = None, size: int = TABLE_SIZE) -> None:
        self.lo, self.hi = table_range(value_range)
        self.device = device
        tf = transfer_function
        k = int(tf.scalars.size)
        comparable = (previous is not None and previous.sigma.shape[0] == size
                      and (previous.lo, previous.hi) == (self.lo, self.hi)
                      and previous.device == device)
        self._io = _TableIO.take(k, device)
        io = self._io
        points = io.stage[:k]
        points[:, 0] = tf.scalars
        points[:, 1] = tf.opacity
        points[:, 2:] = tf.colors
        io.upload(k)
        self.sigma = wp.empty(size, dtype=wp.float32, device=device)
        self.color = wp.empty(size, dtype=wp.vec3, device=device)
        io.result.zero_()
        old = previous if comparable else self
        bin_lo, bin_hi = (float(v) for v in value_range)
        wp.launch(tf_tables_kernel, dim=size,
                  inputs=[io.points, k, self.lo, (self.hi - self.lo) / max(size - 1, 1),
                          self.hi, float(unit_distance), MAX_ALPHA, self.sigma, self.color,
                          old.sigma, old.color, int(comparable), bin_lo, bin_hi, io.result,
                          io.peak],
                  device=device)
        io.download()
        self._comparable = comparable
        self._read = None

    def _results(self):
        """``(sigma_bins, color_bins, sigma_changed, color_changed, peak)``, read from the
        device at the first use (the one wait; host work may go on until then)."""
        if self._read is None:
            got = self._io.host_result()
            _TableIO.give_back(self._io)  # (read, and the upload done: free for another)
            self._io = None
            peak = float(got.view(np.float32)[2 * PEAK])  # (little-endian: the low half)
            if self._comparable:
                self._read = (int(got[SIGMA_BINS]), int(got[COLOR_BINS]),
                              bool(got[SIGMA_CHANGED]), bool(got[COLOR_CHANGED]), peak)
            else:
                self._read = (ALL_BITS, ALL_BITS, True, True, peak)
        return self._read

    sigma_bins = property(lambda self: self._results()[0])
    color_bins = property(lambda self: self._results()[1])
    sigma_changed = property(lambda self: self._results()[2])
    color_changed = property(lambda self: self._results()[3])
    peak = property(lambda self: self._results()[4])

    @property
    def scale(self) -> float:
        """Entries per data unit (the kernels' ``table_scale``)."""
        return (self.sigma.shape[0] - 1) / (self.hi - self.lo)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Host copies ``(sigma (n,), color (n, 3))``."""
        return self.sigma.numpy().copy(), self.color.numpy().copy()


class _TableIO:
    """The buffers of one :class:`DeviceTables` launch: the control points (page-locked
    staging on CUDA) and the result slots with their host copy. Page-locked allocations
    cost about a millisecond each, so the buffers are kept in a pool per device and handed
    from one set of tables to the next once its results are read."""

    #: Free buffers per device.
    _pool: dict = {}

    @classmethod
    def take(cls, k: int, device: str) -> "_TableIO":
        free = cls._pool.setdefault(str(device), [])
        for i, io in enumerate(free):
            if io.capacity >= k:
                return free.pop(i)
        return cls(k, device)

    @classmethod
    def give_back(cls, io: "_TableIO") -> None:
        free = cls._pool.setdefault(io.device, [])
        if len(free) < 4:
            free.append(io)

    def __init__(self, capacity: int, device: str) -> None:
        self.capacity = max(int(capacity), 64)
        self.device = str(device)
        self.cuda = wp.get_device(device).is_cuda
        self.points = wp.empty(self.capacity * 5, dtype=wp.float64, device=device)
        self.result = wp.zeros(5, dtype=wp.uint64, device=device)
        # The peak slot seen as a float32 (the kernel's atomic max); kept alive by result.
        self.peak = wp.array(ptr=self.result.ptr + 8 * PEAK, dtype=wp.float32, shape=(1,),
                             device=device)
        if self.cuda:
            self._stage = wp.empty(self.capacity * 5, dtype=wp.float64, device="cpu",
                                   pinned=True)
            self._host = wp.empty(5, dtype=wp.uint64, device="cpu", pinned=True)
            self.stage = self._stage.numpy().reshape(-1, 5)
        else:  # the CPU device reads the host arrays themselves
            self.stage = self.points.numpy().reshape(-1, 5)

    def upload(self, k: int) -> None:
        if self.cuda:
            wp.copy(self.points, self._stage, count=5 * k)

    def download(self) -> None:
        if self.cuda:
            wp.copy(self._host, self.result)

    def host_result(self) -> np.ndarray:
        if self.cuda:
            wp.synchronize_device(self.result.device)
            return self._host.numpy()
        return self.result.numpy()


assert BITS == 64  # bins_between is written for 64-bit masks
