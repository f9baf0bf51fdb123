"""The light volume's grid and the extinction resampled onto it (Zhang & Ma 2013, §5.2, §7).

The light volume is a regular grid of *points* covering the data's box
``[0, extent]`` in the volume's local frame, like the data but at its own
resolution (the paper's default: half the data's). Its extinction
``sigma_t`` (1/world units, ``DESIGN.md``) is the "opacity volume" that the
convection step attenuates with.

Better than point sampling when the light grid is coarser than the data:
each light-grid point gets the *mean* extinction over its footprint (a box of
one light-grid spacing centred on it, clipped to the volume), estimated with
``ceil(h_light / h_data)`` sub-samples per axis. The data are sampled
trilinearly and classified after interpolation, as everywhere in the project.
Averaging ``sigma_t`` keeps the optical depth of thin opaque structures that a
point sample between them would miss (a one-voxel wall still casts a shadow on a
half-resolution light grid). At the data's resolution there is one sub-sample,
exactly at the point.

The physically based diffusion (:mod:`~vtkillum.core.convection_diffusion.radiative`)
also needs the scattering coefficient, ``sigma_s,c = albedo * color_c(s) *
sigma_t(s)``: :func:`light_grid_optics` averages ``color_c * sigma_t`` over the same
footprint (the albedo multiplies it later, so that an albedo edit does not
resample). Its ratio to the mean ``sigma_t`` is the cell's scattering colour.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vtkillum.core.device import resolve_device
from vtkillum.core.warp_common import (
    Medium,
    cell_trilinear,
    grid_point,
    lookup_color,
    lookup_sigma_t,
    make_medium,
    sample_scalar,
    trilinear_index,
)

#: At most this many sub-samples per axis when averaging a footprint.
MAX_SUBSAMPLES = 8


def light_grid_shape(volume, scale: float = 0.5, shape=None) -> tuple[int, int, int]:
    """Number of light-volume points along x, y, z.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scale : float
        Resolution relative to the data, ``round(scale * n)`` points per axis (at least 2).
    shape : (3,) int, optional
        Explicit shape; overrides ``scale``.
    """
    if shape is not None:
        s = np.asarray(shape).reshape(-1)
        if s.shape != (3,) or not np.all(np.equal(np.mod(s, 1), 0)) or np.any(s < 2):
            raise ValueError(f"light volume shape must be three integers >= 2, got {shape!r}")
        return tuple(int(v) for v in s)
    if not (isinstance(scale, (int, float, np.floating)) and np.isfinite(scale) and 0 < scale <= 4):
        raise ValueError(
            f"light_volume_scale must lie in (0, 4] (1 = the data's resolution), got {scale!r}"
        )
    return tuple(max(2, int(round(float(scale) * n))) for n in volume.dims)


def light_grid_spacing(extent, shape) -> np.ndarray:
    """Distance between light-grid points along each axis (world units)."""
    return np.asarray(extent, dtype=np.float64) / (np.asarray(shape) - 1)


def footprint_samples(volume, shape):
    """Light-grid spacing ``h`` (world units) and the sub-samples per axis of a point's
    footprint mean: ``ceil(h / h_data)``, 1 to :data:`MAX_SUBSAMPLES`."""
    h = light_grid_spacing(volume.extent, shape)
    return h, np.clip(np.ceil(h / volume.spacing - 1e-6), 1, MAX_SUBSAMPLES).astype(int)


def light_grid_sigma(volume, transfer_function, unit_distance: float, shape,
                     device: str | None = None, medium: Medium | None = None) -> wp.array3d:
    """Mean extinction over each light-grid point's footprint.

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    transfer_function : vtkillum.core.transfer_function.TransferFunction
    unit_distance : float
        Opacity unit distance ``u``: ``sigma_t = -ln(1 - alpha) / u``.
    shape : (3,) int
        Light-grid points along x, y, z (see :func:`light_grid_shape`).
    device : str, optional
        Warp device.
    medium : Medium, optional
        An already uploaded medium for ``volume`` (saves the upload).

    Returns
    -------
    warp.array3d of float32, shape ``shape``
        ``sigma_t`` in 1/world units at each light-grid point ``[i, j, k]``.
    """
    device = resolve_device(device)
    if medium is None:
        medium = make_medium(volume, transfer_function, unit_distance, device=device)
    h, sub = footprint_samples(volume, shape)
    sigma = wp.empty(tuple(shape), dtype=wp.float32, device=device)
    wp.launch(light_grid_sigma_kernel, dim=tuple(shape), device=device,
              inputs=[medium, wp.vec3(*h.astype(np.float32)), wp.vec3i(*sub), sigma])
    return sigma


def light_grid_optics(volume, transfer_function, unit_distance: float, shape,
                      device: str | None = None, medium: Medium | None = None, out=None):
    """Mean extinction and mean ``color * sigma_t`` over each light-grid point's footprint.

    Parameters are those of :func:`light_grid_sigma` (the transfer function's colours
    matter here); ``out``, optional, is a ``(sigma, color_sigma)`` pair to overwrite
    (kept across edits, so that captured launches that read them stay valid).

    Returns
    -------
    sigma : warp.array3d of float32, shape ``shape``
        ``sigma_t`` (1/world units), as :func:`light_grid_sigma`.
    color_sigma : warp.array3d of vec3, shape ``shape``
        Footprint mean of ``color_c(s) sigma_t(s)`` per RGB channel (1/world units):
        ``albedo * color_sigma`` is the scattering coefficient ``sigma_s``.
    """
    device = resolve_device(device)
    if medium is None:
        medium = make_medium(volume, transfer_function, unit_distance, device=device)
    h, sub = footprint_samples(volume, shape)
    if out is not None and tuple(out[0].shape) == tuple(shape):
        sigma, color_sigma = out
    else:
        sigma = wp.empty(tuple(shape), dtype=wp.float32, device=device)
        color_sigma = wp.empty(tuple(shape), dtype=wp.vec3, device=device)
    wp.launch(light_grid_optics_kernel, dim=tuple(shape), device=device,
              inputs=[medium, wp.vec3(*h.astype(np.float32)), wp.vec3i(*sub), sigma,
                      color_sigma])
    return sigma, color_sigma


class LightGridOptics:
    """:func:`light_grid_optics` repeated for transfer-function edits of one light grid:
    the output arrays and the recorded launch are kept (a launch from Python packs every
    argument again; the record only takes the new medium).

    Parameters
    ----------
    device : str
        Warp device.
    """

    def __init__(self, device: str) -> None:
        self.device = device
        self._key = None
        self._launch = None
        self.out = None

    def __call__(self, volume, medium: Medium, shape):
        """``(sigma, color_sigma)`` of :func:`light_grid_optics` for ``medium`` (the output
        arrays are the same from call to call while the grid stays)."""
        h, sub = footprint_samples(volume, shape)
        key = (tuple(shape), h.tobytes(), sub.tobytes())
        if key != self._key:
            if self.out is None or tuple(self.out[0].shape) != tuple(shape):
                self.out = (wp.empty(tuple(shape), dtype=wp.float32, device=self.device),
                            wp.empty(tuple(shape), dtype=wp.vec3, device=self.device))
            self._launch = wp.launch(light_grid_optics_kernel, dim=tuple(shape),
                                     device=self.device, record_cmd=True,
                                     inputs=[medium, wp.vec3(*h.astype(np.float32)),
                                             wp.vec3i(*sub), *self.out])
            self._key = key
        else:
            self._launch.set_param_at_index(0, medium)
        self._launch.launch()
        return self.out


@wp.func
def footprint_sample(m: Medium, p: wp.vec3, h: wp.vec3, sub: wp.vec3i, a: int, b: int, c: int):
    """Sub-sample ``(a, b, c)`` of the footprint box ``h`` around light-grid point ``p``: the
    centre of that cell of a regular ``sub`` split, clamped into the volume."""
    off = wp.vec3(
        ((float(a) + 0.5) / float(sub[0]) - 0.5) * h[0],
        ((float(b) + 0.5) / float(sub[1]) - 0.5) * h[1],
        ((float(c) + 0.5) / float(sub[2]) - 0.5) * h[2],
    )
    q = p + off
    return wp.vec3(wp.clamp(q[0], 0.0, m.extent[0]), wp.clamp(q[1], 0.0, m.extent[1]),
                   wp.clamp(q[2], 0.0, m.extent[2]))


@wp.func
def piece_sample(a: wp.array3d(dtype=wp.float32), start: wp.vec3i, dims: wp.vec3i,
                 inv_spacing: wp.vec3, p: wp.vec3):
    """:func:`~vtkillum.core.warp_common.trilinear` of the whole data (``dims`` points) at
    ``p``, read from the piece ``a`` whose ``[0, 0, 0]`` is global point ``start`` (the
    whole volume: ``start`` 0, ``dims`` its shape; the same operations)."""
    idx, f = trilinear_index(p, inv_spacing, dims)
    return cell_trilinear(a, idx - start, f)


@wp.func
def footprint_optics(m: Medium, data: wp.array3d(dtype=wp.float32), start: wp.vec3i,
                     dims: wp.vec3i, h: wp.vec3, sub: wp.vec3i, p: wp.vec3):
    """Footprint means of ``sigma_t`` and ``color * sigma_t`` around light-grid point ``p``
    (1/world units), the data read by :func:`piece_sample` (the whole volume or a piece)."""
    acc = float(0.0)
    acc_c = wp.vec3(0.0)
    for a in range(sub[0]):
        for b in range(sub[1]):
            for c in range(sub[2]):
                s = piece_sample(data, start, dims, m.inv_spacing,
                                 footprint_sample(m, p, h, sub, a, b, c))
                st = lookup_sigma_t(m, s)
                acc += st
                acc_c += st * lookup_color(m, s)
    n = float(sub[0] * sub[1] * sub[2])
    return acc / n, acc_c / n


@wp.kernel
def light_grid_sigma_kernel(m: Medium, h: wp.vec3, sub: wp.vec3i,
                            sigma: wp.array3d(dtype=wp.float32)):
    """Average ``sigma_t`` over the footprint of light-grid point ``wp.tid() = (i, j, k)``.

    The point sits at ``(i, j, k) * h`` in the local frame (world units); the
    ``sub[0] * sub[1] * sub[2]`` sub-samples are the centres of a regular split of
    the footprint box, clamped into the volume (:func:`footprint_sample`). Output in
    1/world units.
    """
    i, j, k = wp.tid()
    p = grid_point(i, j, k, h)
    acc = float(0.0)
    for a in range(sub[0]):
        for b in range(sub[1]):
            for c in range(sub[2]):
                q = footprint_sample(m, p, h, sub, a, b, c)
                acc += lookup_sigma_t(m, sample_scalar(m.scalars, m.inv_spacing, q))
    sigma[i, j, k] = acc / float(sub[0] * sub[1] * sub[2])


@wp.kernel
def light_grid_optics_kernel(m: Medium, h: wp.vec3, sub: wp.vec3i,
                             sigma: wp.array3d(dtype=wp.float32),
                             color_sigma: wp.array3d(dtype=wp.vec3)):
    """Footprint means of ``sigma_t`` and ``color * sigma_t`` at point ``wp.tid() = (i, j, k)``.

    Same sub-samples as :func:`light_grid_sigma_kernel`; both outputs in 1/world units.
    """
    i, j, k = wp.tid()
    shape = wp.vec3i(m.scalars.shape[0], m.scalars.shape[1], m.scalars.shape[2])
    st, cs = footprint_optics(m, m.scalars, wp.vec3i(0, 0, 0), shape, h, sub,
                              grid_point(i, j, k, h))
    sigma[i, j, k] = st
    color_sigma[i, j, k] = cs
