"""Loops that user parameters can make long: a step cap with a clear error, and Ctrl-C.

Issue 15, row 2: ``LightTransmittanceFilter.SetStepSize(1e-9)`` ran one kernel for more
than ten minutes and ignored Ctrl-C.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from vtkillum.core.light_transmittance import (
    CHUNK_SAMPLES,
    light_transmittance,
    max_steps_per_ray,
)
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.raymarch import MAX_STEPS_PER_RAY
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

ROOT = Path(__file__).resolve().parents[2]


def blob(n=24):
    x = np.linspace(-1, 1, n)
    return Volume(np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2
                               + x[None, None, :] ** 2)))


TF = TransferFunction([0.0, 1.0], [0.0, 0.5])


def test_tiny_step_is_refused_naming_the_smallest_usable_step():
    volume = blob()
    diagonal = float(np.linalg.norm(volume.extent))
    with pytest.raises(ValueError, match=r"step_size 1e-09 .* use at least 3\.8e-05 world units"):
        light_transmittance(volume, TF, 1.0, [DirectionalLight((1, -1, -1))], step_size=1e-9,
                            device="cpu")
    smallest = diagonal / MAX_STEPS_PER_RAY
    assert max_steps_per_ray(volume, smallest * 1.001) <= MAX_STEPS_PER_RAY
    with pytest.raises(ValueError, match="use at least"):
        max_steps_per_ray(volume, smallest * 0.999)


def test_filter_reports_the_tiny_step():
    vtk = pytest.importorskip("vtk")
    from vtkmodules.util.numpy_support import numpy_to_vtk

    from vtkillum.filters.light_transmittance import LightTransmittanceFilter

    volume = blob()
    image = vtk.vtkImageData()
    image.SetDimensions(*volume.dims)
    array = numpy_to_vtk(volume.scalars.ravel(order="F"), deep=True)
    array.SetName("s")
    image.GetPointData().SetScalars(array)
    f = LightTransmittanceFilter()
    f.AddObserver("ErrorEvent", lambda *a: None)  # keep VTK's error dump off the log
    f.SetStepSize(1e-9)
    start = time.perf_counter()
    with pytest.raises(ValueError, match="use at least"):
        f.execute(image)
    assert time.perf_counter() - start < 10


def test_chunked_launches_give_the_same_transmittance(monkeypatch):
    """Chunks of a few grid points (odd sizes, several lights) = one launch per light."""
    volume = Volume(blob(10).scalars[:, :7, :9], spacing=(0.5, 0.7, 0.4))
    lights = [DirectionalLight((1, -1, -0.5)), PointLight((1.0, 9.0, -2.0), (5, 5, 5))]
    whole, phi_whole = light_transmittance(volume, TF, 1.0, lights, step_size=0.05,
                                           device="cpu")
    calls = []
    monkeypatch.setitem(CHUNK_SAMPLES, "cpu", 13 * max_steps_per_ray(volume, 0.05))
    chunked, phi_chunked = light_transmittance(volume, TF, 1.0, lights, step_size=0.05,
                                               device="cpu", progress=calls.append)
    n_points = 10 * 7 * 9
    assert len(calls) == 2 * -(-n_points // 13)
    assert calls[-1] == 1.0 and np.all(np.diff(calls) > 0)
    np.testing.assert_array_equal(chunked, whole)
    np.testing.assert_array_equal(phi_chunked, phi_whole)
    assert whole.min() < 0.9  # the blob shadows something


CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    from vtkillum.core.light_transmittance import light_transmittance
    from vtkillum.core.lights import DirectionalLight
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume

    x = np.linspace(-1, 1, 24)
    v = Volume(np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2
                            + x[None, None, :] ** 2)))
    tf = TransferFunction([0.0, 1.0], [0.0, 0.5])
    light = [DirectionalLight((1, -1, -1))]
    light_transmittance(v, tf, 1.0, light, device="cpu")  # compile outside the timed part
    print("ready", flush=True)
    try:
        # The smallest accepted step: about a minute of one CPU core.
        light_transmittance(v, tf, 1.0, light, step_size=4e-5, device="cpu")
    except KeyboardInterrupt:
        print("interrupted", time.perf_counter(), flush=True)
        sys.exit(42)
    print("finished", flush=True)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT")
def test_ctrl_c_stops_a_long_march_within_a_second():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               VTKILLUM_DEVICE="cpu")
    child = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        assert child.stdout.readline().strip() == "ready", child.stderr.read()
        time.sleep(1.0)  # well inside the march
        sent = time.perf_counter()
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=20)
        waited = time.perf_counter() - sent
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 42, (out, err)
    assert "interrupted" in out
    # About 0.1 s of samples per launch; generous for a loaded CI machine (interpreter exit
    # included).
    assert waited < 3.0, waited
