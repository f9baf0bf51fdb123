"""Coarse-grid operators of the physical diffusion from the fine grid's coefficients.

The multigrid of :mod:`~vtkillum.core.convection_diffusion.radiative` needs, on every
coarser level, face coefficients ``k = D / h^2`` and a boundary leakage. They are built
here from the next finer level's (a homogenization of its conductances), not by running
the flux limiter again on the restricted solution and medium (re-discretization).

Why
---
Re-discretization averages ``sigma_tr`` over a coarse cell before taking ``D = lambda /
sigma_tr``. Where a coarse cell holds a little dense medium and much thin medium or
vacuum -- the rule in the benchmark's data and in CT scans -- that mean is dominated by the
dense part and the coarse cell conducts like the medium, while its fine cells conduct
around it. A coarse operator that conducts too little over-corrects: with the
coefficients frozen (a linear problem), the V(2,2) cycle of the re-discretized hierarchy
*diverged* on the benchmark's Foot light grid (64³; error against the solution 1.7e-2 →
3.8e-1 in ten cycles), and the outer iteration converged only because every outer
iteration starts the coarse levels afresh and Anderson mixing damps what the cycles
amplify. With the operators below the same frozen problem converges (the solver's
relative correction 1 → 1.2e-6 in eleven cycles).

How
---
Per axis ``a`` and coarse face between coarse cells ``I`` and ``I + 1``, each fine
channel crossing it (one per fine cell of the cross-section, along the other two axes)
is a series of fine faces from the centre of ``I`` to the centre of ``I + 1``: the face
between the two coarse cells (weight 1) and, where the axis is coarsened, the face
inside each coarse cell that passes through its centre (weight 1/2 each; the last cell of
an odd grid has one child and no such face). The channel's conductance is
``1 / sum_i (w_i / k_i)`` (resistances in series), the channels are in parallel (their
conductances add), and per unit coarse volume::

    k_c = mean over channels of (1 / sum_i (w_i / k_i)) / r_a

with ``r_a`` the coarsening ratio (1 or 2) along ``a``. For a constant ``k`` this is
exactly the re-discretized ``D / H^2`` (``H = r_a h``); a blocking sheet inside a coarse
cell blocks its channels (series), and a thin gap between dense blocks still conducts
(parallel). The leakage through the box faces is the mean of the children's (Galerkin
with piecewise-constant transfer; equal to the re-discretized one where ``D >> h``, up to
twice it in a dense boundary cell), and so is the absorption (both are held in one
array, ``absorb``, the part of the diagonal that couples to no neighbour).

The fixed point of the outer iteration is the fine grid's equations: the coarse
operators change how fast it is reached, not where.
"""

from __future__ import annotations

import warp as wp

from vtkillum.core.convection_diffusion.multigrid import child_of, children_mean
from vtkillum.core.warp_common import axis_offset, component

#: Smallest face coefficient in a channel's resistance (1/world units): a zero coefficient
#: (a face that carries nothing) gives the channel a conductance of ~0, not a division by 0.
MIN_COEFFICIENT = 1.0e-30


def coarse_coefficients(fine, coarse, ratio: wp.vec3i, device) -> None:
    """Face coefficients and leakage of level ``coarse`` from those of level ``fine``.

    Parameters
    ----------
    fine, coarse : radiative.Level
        Adjacent levels; ``fine.kx, ky, kz, absorb`` are read and ``coarse.kx, ky, kz,
        absorb`` written (vec3, one value per RGB channel, 1/world units; ``absorb`` is
        the absorption plus the box faces' leakage).
    ratio : wp.vec3i
        Coarsening ratio per axis (1 or 2).
    device : str
        Warp device.
    """
    wp.launch(coarse_coefficients_kernel, dim=(4, *coarse.shape), device=device,
              inputs=[fine.kx, fine.ky, fine.kz, fine.absorb, coarse.kx, coarse.ky,
                      coarse.kz, coarse.absorb, ratio])


@wp.func
def face_k(kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
           kz: wp.array3d(dtype=wp.vec3), a: int, p: wp.vec3i):
    """Coefficient of the face between cell ``p`` and its ``+a`` neighbour."""
    if a == 0:
        return kx[p[0], p[1], p[2]]
    if a == 1:
        return ky[p[0], p[1], p[2]]
    return kz[p[0], p[1], p[2]]


@wp.func
def set_face_k(kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
               kz: wp.array3d(dtype=wp.vec3), a: int, p: wp.vec3i, value: wp.vec3):
    """Write the coefficient of the face between cell ``p`` and its ``+a`` neighbour."""
    if a == 0:
        kx[p[0], p[1], p[2]] = value
    elif a == 1:
        ky[p[0], p[1], p[2]] = value
    else:
        kz[p[0], p[1], p[2]] = value


@wp.func
def resistance(k: wp.vec3, w: float):
    """``w / k`` per channel (``k`` floored at :data:`MIN_COEFFICIENT`)."""
    return wp.vec3(w / wp.max(k[0], MIN_COEFFICIENT), w / wp.max(k[1], MIN_COEFFICIENT),
                   w / wp.max(k[2], MIN_COEFFICIENT))


@wp.kernel
def coarse_coefficients_kernel(kx: wp.array3d(dtype=wp.vec3), ky: wp.array3d(dtype=wp.vec3),
                               kz: wp.array3d(dtype=wp.vec3), absorb: wp.array3d(dtype=wp.vec3),
                               ckx: wp.array3d(dtype=wp.vec3), cky: wp.array3d(dtype=wp.vec3),
                               ckz: wp.array3d(dtype=wp.vec3),
                               cabsorb: wp.array3d(dtype=wp.vec3), ratio: wp.vec3i):
    """One coarse coefficient per thread, ``wp.tid() = (what, I, J, K)``: ``what`` 0-2 the
    coarse cell's ``+x, +y, +z`` face (where the neighbour exists), 3 its absorption plus
    leakage (the mean of its children's); see the
    module docstring. Fine arrays have the fine level's shapes (faces: one less along
    their axis), coarse arrays the coarse level's; all in 1/world units."""
    what, ci, cj, ck = wp.tid()
    nf = wp.vec3i(absorb.shape[0], absorb.shape[1], absorb.shape[2])
    if what == 3:
        cabsorb[ci, cj, ck] = children_mean(absorb, ci, cj, ck, ratio)
        return
    a = what  # a run-time axis: components by select (component, axis_offset)
    c = wp.vec3i(ci, cj, ck)
    ca = component(c, a)
    if ca >= component(wp.vec3i(cabsorb.shape[0], cabsorb.shape[1], cabsorb.shape[2]), a) - 1:
        return
    ra = component(ratio, a)
    nfa = component(nf, a)
    last = ca * ra + ra - 1  # the fine cell left of the interface, along a
    e = axis_offset(a, 1)
    g = wp.vec3(0.0)
    channels = float(0.0)
    for child in range(8):
        i, j, k, ok = child_of(ci, cj, ck, ratio, child, nf)
        p = wp.vec3i(i, j, k)
        pa = component(p, a)
        if ok and pa == last:
            r = resistance(face_k(kx, ky, kz, a, p), 1.0)
            if ra > 1:
                r += resistance(face_k(kx, ky, kz, a, p - e), 0.5)
                if pa + 2 < nfa:  # the right cell has two children
                    r += resistance(face_k(kx, ky, kz, a, p + e), 0.5)
            g += wp.vec3(1.0 / r[0], 1.0 / r[1], 1.0 / r[2])
            channels += 1.0
    set_face_k(ckx, cky, ckz, a, c, g / (channels * float(ra)))
