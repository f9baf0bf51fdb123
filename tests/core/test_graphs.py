"""Captured launch sequences (:mod:`vtkillum.core.graphs`) replay what they recorded."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from vtkillum.core.convection_diffusion.diffusion import DiffusionSolver
from vtkillum.core.graphs import ENV, LaunchGraphs, array_key, graphs_enabled


@wp.kernel
def _axpy(x: wp.array(dtype=float), y: wp.array(dtype=float), a: float):
    i = wp.tid()
    y[i] = y[i] + a * x[i]


def test_replay_runs_the_recorded_sequence_each_call(device):
    x = wp.array(np.arange(8, dtype=np.float32), device=device)
    y = wp.zeros(8, dtype=float, device=device)
    graphs = LaunchGraphs(device, enabled=True)

    def record():
        y.zero_()
        for _ in range(3):
            wp.launch(_axpy, dim=8, inputs=[x, y, 2.0], device=device)

    for _ in range(3):
        y.fill_(100.0)
        graphs.run(("axpy",) + array_key(x, y), record)
        np.testing.assert_allclose(y.numpy(), 6.0 * np.arange(8))
    assert graphs.captures == 1 and graphs.replays == 3 and len(graphs) == 1
    z = wp.zeros(8, dtype=float, device=device)  # other arrays: another key, another capture
    assert array_key(x, z) != array_key(x, y)


def test_disabled_graphs_launch_directly(device, monkeypatch):
    monkeypatch.setenv(ENV, "0")
    assert not graphs_enabled()
    graphs = LaunchGraphs(device)
    calls = []
    graphs.run("k", lambda: calls.append(1))
    graphs.run("k", lambda: calls.append(1))
    assert calls == [1, 1] and len(graphs) == 0


def test_a_failing_capture_falls_back_to_plain_launches(device):
    graphs = LaunchGraphs(device, enabled=True)
    runs = []

    def record():
        runs.append(1)
        if len(runs) == 1:
            raise RuntimeError("not capturable")

    with pytest.warns(RuntimeWarning, match="capture failed"):
        graphs.run("k", record)
    assert len(runs) == 2 and not graphs.enabled


@pytest.mark.parametrize("method", ["multigrid", "gauss-seidel"])
def test_paper_diffusion_replays_equal_launch_by_launch(device, method):
    shape, h, s = (12, 10, 9), (0.2, 0.25, 0.3), (0.3, 0.2, 0.1)
    b_host = np.random.default_rng(1).random(shape + (3,)).astype(np.float32)
    out = []
    for enabled in (True, False):
        solver = DiffusionSolver(shape, h, s, method=method, device=device)
        solver.graphs.enabled = enabled
        b = wp.array(b_host, dtype=wp.vec3, device=device)
        x = wp.clone(b)
        report = solver.solve(b, x, 40, 1e-5)
        out.append((report.iterations, x.numpy()))
    assert out[0][0] == out[1][0]
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-6, atol=1e-7)


def test_host_reader_sees_each_launch_and_keeps_earlier_reads(device):
    """:class:`~vtkillum.core.warp_common.HostReader`: every read waits for the work queued
    before it and returns its own copy (the pinned array behind it is reused on CUDA)."""
    from vtkillum.core.warp_common import HostReader

    x = wp.array(np.arange(6, dtype=np.float32), device=device)
    y = wp.zeros(6, dtype=float, device=device)
    reader = HostReader(y)
    reads = []
    for a in (1.0, 2.0, 3.0):
        wp.launch(_axpy, dim=6, inputs=[x, y, a], device=device)
        reads.append(reader.read())
    for total, got in zip((1.0, 3.0, 6.0), reads):
        np.testing.assert_array_equal(got, total * np.arange(6))


def test_host_reader_reads_the_first_entries(device):
    from vtkillum.core.warp_common import HostReader

    y = wp.array(np.arange(6, dtype=np.float32), device=device)
    got = HostReader(y).read(4)
    np.testing.assert_array_equal(got, np.arange(4))


def test_host_writer_lands_every_write_in_order(device):
    """:class:`~vtkillum.core.warp_common.HostWriter`: each write reaches the device array
    before the work queued after it, and a later write does not change what an earlier
    launch saw (the pinned staging array is reused on CUDA)."""
    from vtkillum.core.warp_common import HostWriter

    x = wp.zeros(6, dtype=float, device=device)
    y = wp.zeros(6, dtype=float, device=device)
    writer = HostWriter(x)
    for a in (1.0, 2.0, 3.0):
        writer.write(a * np.arange(6, dtype=np.float32))
        wp.launch(_axpy, dim=6, inputs=[x, y, 1.0], device=device)  # y += x
    np.testing.assert_array_equal(y.numpy(), 6.0 * np.arange(6))
    v = wp.zeros(4, dtype=wp.vec3, device=device)
    HostWriter(v).write(np.arange(12, dtype=np.float32).reshape(4, 3))
    np.testing.assert_array_equal(v.numpy(), np.arange(12).reshape(4, 3))


def test_medium_tables_follow_edits_like_a_new_medium(device):
    """The convection–diffusion opacity stage's reused medium and recorded launch
    (:class:`MediumTables`, whose tables a kernel rebuilds on the device, and
    :class:`LightGridOptics`) give the host's tables to within a float32 ulp and what a new
    medium and :func:`light_grid_optics` give, edit after edit, in the same arrays: a
    one-point function, control points beyond the data, at ±1e30, opacities near 0 and 1."""
    from vtkillum.core.convection_diffusion.opacity import LightGridOptics, light_grid_optics
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume
    from vtkillum.core.warp_common import MediumTables, device_scalars, make_medium

    rng = np.random.default_rng(3)
    volume = Volume(rng.random((9, 8, 7)).astype(np.float32), spacing=(0.5, 0.6, 0.7))
    white, warm, blue = [1, 1, 1], [1, 0.5, 0.2], [0.1, 0.4, 1]
    tfs = [TransferFunction([0.0, 0.5, 1.0], [0.0, a, 0.9], [white, warm, blue])
           for a in (0.1, 0.6)]
    tfs += [TransferFunction([0.4], [0.3], [warm]),
            TransferFunction([-3.0, 0.2, 0.21, 7.0], [1.0, 1e-7, 2e-5, 0.999999], [white, warm, blue, white]),
            TransferFunction([-1e30, 0.5, 1e30], [0.0, 0.5, 0.0], [blue, white, warm]),
            TransferFunction(np.linspace(0, 1, 90), rng.random(90), rng.random((90, 3)))]
    scalars = device_scalars(volume, device)
    tables, optics = MediumTables(device), LightGridOptics(device)
    first = None
    for tf in tfs:
        m = tables.medium(volume, tf, 0.8, scalars)
        got = optics(volume, m, (5, 4, 4))
        first = first or got
        assert got[0] is first[0] and got[1] is first[1]
        sig, col, lo, hi = tf.lookup_tables(0.8, volume.value_range)
        np.testing.assert_allclose(m.sigma_table.numpy(), sig, rtol=2.4e-7, atol=1e-30)
        np.testing.assert_allclose(m.color_table.numpy(), col, rtol=2.4e-7, atol=1e-30)
        assert (m.table_lo, m.table_scale) == (float(lo), float((sig.size - 1) / (hi - lo)))
        assert m.majorant >= sig.max()
        ref = light_grid_optics(volume, tf, 0.8, (5, 4, 4), device,
                                medium=make_medium(volume, tf, 0.8, device=device,
                                                   skip_empty=False))
        np.testing.assert_allclose(got[0].numpy(), ref[0].numpy(), rtol=1e-6)
        np.testing.assert_allclose(got[1].numpy(), ref[1].numpy(), rtol=1e-6, atol=1e-12)
