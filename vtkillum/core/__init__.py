"""Compute core of vtkillum: numpy + warp only (no vtk, pyvista or paraview imports).

This package must import on a machine that has only numpy and warp-lang, such as
the GPU machine the kernels are benchmarked on.
"""
