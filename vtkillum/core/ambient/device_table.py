"""The preintegration table kept whole on a device, sliced at any ``g`` there.

A phase-function (``g``) edit needs the table slice ``L̃o(θ, σ̃t)`` and the front
transmittance ``T̃(σ̃t)`` at the new ``g``. :class:`DeviceTable` uploads all the
tabulated ``g`` once and builds both slices with one small kernel into arrays it
keeps, so a ``g`` edit does no host work and no allocation. The blend is the one of
:meth:`~vtkillum.core.ambient.table.PreintegrationTable.g_slice` (geometric in ``g``,
linear where an entry is 0; the host blends in double precision, the device as
``a (b/a)^w`` in single precision, within 6e-7 of the host's over the shipped table) and
:meth:`~vtkillum.core.ambient.table.PreintegrationTable.transmittance_slice` (linear,
single precision), so the slices equal the host's to float rounding. The scattered part
``M`` of the table (:attr:`~vtkillum.core.ambient.table.PreintegrationTable.scattered`), which
the centred gather reads instead of ``L̃o``, is sliced the same way, blended like ``L̃o``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.ambient.table import PreintegrationTable
from vtkillum.core.device import init_warp, resolve_device

init_warp()


class DeviceTable:
    """All slices of a :class:`~vtkillum.core.ambient.table.PreintegrationTable` on a device.

    Parameters
    ----------
    table : PreintegrationTable
    device : str, optional
        Warp device.

    Attributes
    ----------
    table : PreintegrationTable
        The host table (axes, ``sigma_max``).
    g_slice : wp.array2d(float32)
        ``L̃o(θ, r σ̃t)`` at the ``g`` of the last :meth:`set_g`, ``(n_theta, n_sigma)``.
    scattered_slice : wp.array2d(float32)
        The scattered part ``M(θ, r σ̃t)`` at that ``g``, ``(n_theta, n_sigma)``.
    transmittance_slice : wp.array(float32)
        ``T̃(r σ̃t)`` at that ``g``, ``(n_sigma,)``.
    g : float or None
        The ``g`` the slices hold (``None`` before the first :meth:`set_g`).

    The slice arrays are overwritten in place by every :meth:`set_g`.
    """

    def __init__(self, table: PreintegrationTable, device: str | None = None) -> None:
        self.table = table
        self.device = resolve_device(device)
        nt, ns, _ = table.shape
        self._radiance = wp.array(table.radiance, dtype=wp.float32, device=self.device)
        self._scattered = wp.array(table.scattered, dtype=wp.float32, device=self.device)
        self._transmittance = wp.array(table.transmittance, dtype=wp.float32, device=self.device)
        self.g_slice = wp.empty((nt, ns), dtype=wp.float32, device=self.device)
        self.scattered_slice = wp.empty((nt, ns), dtype=wp.float32, device=self.device)
        self.transmittance_slice = wp.empty(ns, dtype=wp.float32, device=self.device)
        self.g = None
        self._launch = None  # the slicing launch, recorded by the first set_g

    def set_g(self, g: float) -> None:
        """Fill :attr:`g_slice`, :attr:`scattered_slice` and :attr:`transmittance_slice` at
        anisotropy ``g`` (clamped)."""
        k, w = self.table.g_bracket(g)
        k1 = min(k + 1, self.table.g.size - 1)
        nt, ns, _ = self.table.shape
        blend = (int(k), int(k1), float(w), float(np.float32(1 - w)), float(np.float32(w)))
        # Both slices in one launch, recorded once and replayed with the new blend: at small
        # sizes an edit's cost is its launches and their argument packing.
        if self._launch is None:
            self._launch = wp.launch(
                g_slice_kernel, dim=(2, nt, ns),
                inputs=[self._radiance, self._scattered, self._transmittance, k, k1,
                        wp.float64(w), *blend[3:],
                        self.g_slice, self.scattered_slice, self.transmittance_slice],
                device=self.device, record_cmd=True)
        else:  # written into the packed parameters as they are (no conversion)
            for index, value in enumerate(blend, start=3):
                self._launch.set_param_at_index_from_ctype(index, value)
        self._launch.launch()
        self.g = float(g)


@wp.kernel
def g_slice_kernel(radiance: wp.array3d(dtype=wp.float32), scattered: wp.array3d(dtype=wp.float32),
                   transmittance: wp.array2d(dtype=wp.float32), k: int, k1: int,
                   w: wp.float64, wa: float, wb: float, out_radiance: wp.array2d(dtype=wp.float32),
                   out_scattered: wp.array2d(dtype=wp.float32),
                   out_transmittance: wp.array(dtype=wp.float32)):
    """``wp.tid()`` = ``(which, θ index, σ̃t index)``: blend tabulated slices ``k`` and ``k1``
    of ``L̃o`` (``which`` 0) or ``M`` (1).

    ``w`` is the fraction towards ``k1``; ``wa``, ``wb`` are ``1 - w`` and ``w`` rounded to
    float32 (the host's single-precision transmittance blend). Row 0 of ``L̃o`` also writes
    ``T̃``.
    """
    which, i, j = wp.tid()
    a = float(0.0)
    b = float(0.0)
    if which == 0:
        a = radiance[i, j, k]
        b = radiance[i, j, k1]
    else:
        a = scattered[i, j, k]
        b = scattered[i, j, k1]
    v = a
    if w >= wp.float64(1.0):
        v = b
    elif w > wp.float64(0.0):
        wf = float(w)
        if a > 0.0 and b > 0.0:
            # a^(1-w) b^w as a (b/a)^w: one log of a ratio near 1 and one exp of a small
            # exponent, so single precision stays within float32 rounding of the host's
            # double-precision blend (and the launch is several times shorter)
            v = a * wp.exp(wf * wp.log(b / a))
        else:
            v = (1.0 - wf) * a + wf * b
    if which == 0:
        out_radiance[i, j] = v
        if i == 0:
            t = transmittance[j, k]
            if k1 != k:
                t = wa * transmittance[j, k] + wb * transmittance[j, k1]
            out_transmittance[j] = t
    else:
        out_scattered[i, j] = v
