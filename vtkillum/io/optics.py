"""Refractive index and medium colour between VTK functions and :class:`RefractiveOptics`.

The refraction method's two extra transfer functions (Magnus & Bruckner 2017,
section 4.1) as VTK objects, the way the colour and opacity are given to VTK's
volume property:

* refractive index ``η_tf``: a ``vtkPiecewiseFunction`` (values > 0);
* medium colour ``m_tf``: a ``vtkColorTransferFunction`` (RGB in [0, 1]).

:func:`optics_from_vtk` samples both like
:func:`vtkillum.io.convert.transfer_function_from_vtk` does (nodes, plus dense
samples where VTK does not interpolate linearly: midpoints/sharpness, non-RGB
colour spaces); :func:`optics_to_vtk` goes the other way. The result is passed as
``optics=`` to the ``refraction`` method, e.g. through
:class:`~vtkillum.mappers.compute_mapper.ComputeVolumeRenderer`::

    optics = optics_from_vtk(eta_function, medium_function)
    ComputeVolumeRenderer(renderer, image, scene, method="refraction", optics=optics)
"""

from __future__ import annotations

import numpy as np
from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

from vtkillum.core.refraction.optics import RefractiveOptics
from vtkillum.io.convert import _node, check_finite_nodes

#: Samples per interval where VTK's interpolation is not piecewise linear.
DENSE_SAMPLES = 32


def optics_from_vtk(refractive_index=None, medium_color=None) -> RefractiveOptics:
    """:class:`RefractiveOptics` from VTK functions (``None`` or empty: η ≡ 1 / m ≡ white).

    Parameters
    ----------
    refractive_index : vtkPiecewiseFunction, optional
        η per data value (> 0).
    medium_color : vtkColorTransferFunction, optional
        Medium colour per data value (RGB in [0, 1], per opacity unit distance).
    """
    kw = {}
    if refractive_index is not None:
        if not isinstance(refractive_index, vtkPiecewiseFunction):
            raise TypeError("refractive_index must be a vtkPiecewiseFunction")
        if refractive_index.GetSize() > 0:
            check_finite_nodes([_node(refractive_index, i, 4)
                                for i in range(refractive_index.GetSize())],
                               "the refractive index function (vtkPiecewiseFunction)",
                               ("x", "refractive index", "midpoint", "sharpness"))
            xs = _nodes(refractive_index, 4)
            kw["eta_scalars"] = xs
            kw["eta"] = [refractive_index.GetValue(x) for x in xs]
    if medium_color is not None:
        if not isinstance(medium_color, vtkColorTransferFunction):
            raise TypeError("medium_color must be a vtkColorTransferFunction")
        if medium_color.GetSize() > 0:
            check_finite_nodes([_node(medium_color, i, 6) for i in range(medium_color.GetSize())],
                               "the medium colour function (vtkColorTransferFunction)",
                               ("x", "red", "green", "blue", "midpoint", "sharpness"))
            xs = _nodes(medium_color, 6, nonlinear=medium_color.GetColorSpace() != 0
                        or medium_color.GetScale() != 0)
            rgb = []
            for x in xs:
                c = [0.0, 0.0, 0.0]
                medium_color.GetColor(x, c)
                rgb.append(c)
            kw["medium_scalars"] = xs
            kw["medium_color"] = np.clip(rgb, 0.0, 1.0)
    return RefractiveOptics(**kw)


def optics_to_vtk(optics: RefractiveOptics):
    """``(vtkPiecewiseFunction, vtkColorTransferFunction)`` with ``optics``' control points."""
    eta = vtkPiecewiseFunction()
    for x, v in zip(optics.eta_scalars, optics.eta):
        eta.AddPoint(float(x), float(v))
    medium = vtkColorTransferFunction()
    for x, c in zip(optics.medium_scalars, optics.medium_color):
        medium.AddRGBPoint(float(x), *(float(v) for v in c))
    return eta, medium


def _nodes(function, size: int, nonlinear: bool = False) -> np.ndarray:
    """Node positions, plus dense samples in intervals VTK does not interpolate linearly."""
    nodes = []
    for i in range(function.GetSize()):
        values = [0.0] * size
        function.GetNodeValue(i, values)
        nodes.append(values)
    xs = {n[0] for n in nodes}
    for a, b in zip(nodes[:-1], nodes[1:]):
        midpoint, sharpness = a[size - 2], a[size - 1]
        if nonlinear or abs(midpoint - 0.5) > 1e-9 or abs(sharpness) > 1e-9:
            xs.update(np.linspace(a[0], b[0], DENSE_SAMPLES + 1)[1:-1].tolist())
    return np.array(sorted(xs), dtype=np.float64)
