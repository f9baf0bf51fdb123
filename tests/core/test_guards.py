"""Loops that user parameters can make long: a step cap with a clear error, and Ctrl-C.

Issue 15, row 2: ``LightTransmittanceFilter.SetStepSize(1e-9)`` ran one kernel for more
than ten minutes and ignored Ctrl-C. Also: ``single`` marches a shadow ray at every sample
(quadratic in 1 / step_size: step 2e-5 on a 12³ volume did not finish at 8×8 in 40 s);
the path tracer's delta tracking grows with majorant × length (``opacity_unit_distance``
1e-7 did not finish; near 1e30 ``t + step == t`` never ends); VTK swallowed a Ctrl-C in a
filter's ``RequestData`` and ``execute()`` said "pipeline update failed".
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

from vtkillum.core.camera import Camera
from vtkillum.core.light_transmittance import (
    CHUNK_SAMPLES,
    light_transmittance,
    max_steps_per_ray,
)
from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.pathtrace import MAX_OPTICAL_DEPTH, PathTracer
from vtkillum.core.raycast import (
    BAND_SAMPLES,
    MAX_SAMPLES_PER_PIXEL,
    band_pixels,
    check_samples_per_pixel,
    samples_per_pixel,
)
from vtkillum.core.raymarch import MAX_STEPS_PER_RAY
from vtkillum.core.render import render
from vtkillum.core.scene import Scene
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


def interrupt_child(code, delay=1.0):
    """Run ``code`` in a child, send SIGINT ``delay`` s after it prints "ready".

    Returns ``(seconds from the signal to the child's exit, stdout, stderr)``; the child
    must exit with 42 (its ``except KeyboardInterrupt``).
    """
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               VTKILLUM_DEVICE="cpu")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        assert child.stdout.readline().strip() == "ready", child.stderr.read()
        time.sleep(delay)  # well inside the long part
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
    return waited, out, err


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT")
def test_ctrl_c_stops_a_long_march_within_a_second():
    waited, _, _ = interrupt_child(CHILD)
    # About 0.1 s of samples per launch; generous for a loaded CI machine (interpreter exit
    # included).
    assert waited < 3.0, waited


# --- single scattering: a shadow ray per sample ----------------------------------------------------
def small_blob():
    return blob(12)  # spacing 1: extent 11, diagonal 19.05


def single_scene(lights=1):
    all_lights = [DirectionalLight((1, -1, -1)), PointLight((5.0, 14.0, -3.0), (40, 40, 40)),
                  DirectionalLight((0, 0, -1))]
    return Scene(transfer_function=TF, lights=all_lights[:lights])


def test_single_refuses_quadratic_work_naming_the_smallest_step():
    volume = small_blob()
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"step_size 2e-05 needs up to 9\.08e\+11 samples per "
                                         r"pixel with method 'single' \(952628 along the ray, "
                                         r"each with 1 shadow ray\(s\) of up to 952628\); .* "
                                         r"use a step_size of at least 0\.00233 world units"):
        render(volume, single_scene(), "single", 8, 8, device="cpu", step_size=2e-5)
    assert time.perf_counter() - start < 10
    # The printed step is usable, a slightly smaller one is not.
    check_samples_per_pixel(volume, 0.00233, 1, np.inf, "single")
    with pytest.raises(ValueError, match="at least 0.00233"):
        check_samples_per_pixel(volume, 0.00232, 1, np.inf, "single")
    # More lights: more work per sample, a larger smallest step, and the hint.
    with pytest.raises(ValueError, match=r"at least 0\.00403 world units \(or fewer lights\)"):
        render(volume, single_scene(3), "single", 8, 8, device="cpu", step_size=2e-3)
    check_samples_per_pixel(volume, 0.00403, 3, np.inf, "single")
    # Emission has no shadow rays: only the per-ray cap applies.
    assert samples_per_pixel(volume, 2e-5) == 952628
    assert MAX_SAMPLES_PER_PIXEL < 952628**2


def test_illumination_near_march_counts_as_shadow_rays():
    """``illumination`` marches ``near_cells`` of each light exactly at every sample."""
    from vtkillum.core.illumination import IlluminationVolume

    volume = small_blob()
    grid = IlluminationVolume(transmittance=np.ones((1, 12, 12, 12)), extent=volume.extent)
    scene = single_scene()
    with pytest.raises(ValueError, match="method 'illumination'.*use a step_size of at least"):
        render(volume, scene, "illumination", 8, 8, device="cpu", step_size=2e-5,
               illumination=grid)
    # The same step with the grid read at the sample (no near march) is only primary work.
    out = render(volume, scene, "illumination", 2, 2, device="cpu", step_size=2e-3,
                 illumination=grid, near_cells=0.0)
    assert np.isfinite(out.radiance).all()


@pytest.mark.parametrize("method", ["single", "illumination", "emission"])
def test_bands_of_parts_of_rows_give_the_same_image(monkeypatch, method):
    volume = Volume(blob(10).scalars[:, :7, :9], spacing=(0.5, 0.7, 0.4))
    scene = single_scene(2)
    options = {"step_size": 0.05, "jitter": method != "emission"}
    if method == "illumination":
        from vtkillum.core.illumination import IlluminationVolume

        rng = np.random.default_rng(1)
        options["illumination"] = IlluminationVolume(
            transmittance=rng.random((2, 5, 4, 5)), scattered=rng.random((5, 4, 5, 3)),
            extent=volume.extent)
    whole = render(volume, scene, method, 7, 5, device="cpu", **options)
    n_lights, length = {"single": (2, np.inf), "emission": (0, 0.0)}.get(method, (2, 0.0))
    if method == "illumination":
        length = 2.0 * float(np.max(volume.extent / (np.array([5, 4, 5]) - 1)))
    work = samples_per_pixel(volume, 0.05, n_lights, length)
    monkeypatch.setitem(BAND_SAMPLES, "cpu", 3 * work)  # 3 pixels per launch
    calls = []
    banded = render(volume, scene, method, 7, 5, device="cpu", progress=calls.append, **options)
    assert banded.info["tiles"] == 5 * 3
    assert calls[-1] == 1.0 and np.all(np.diff(calls) > 0)
    np.testing.assert_array_equal(banded.radiance, whole.radiance)
    np.testing.assert_array_equal(banded.alpha, whole.alpha)
    assert whole.alpha.max() > 0.1


def test_bands_shrink_with_the_work_per_pixel():
    for work in (1, 1000, 10**5, 2**22, MAX_SAMPLES_PER_PIXEL):
        pixels = band_pixels("cpu", work)
        assert pixels >= 1 and (pixels == 1 or pixels * work <= BAND_SAMPLES["cpu"])
    assert band_pixels("cpu", MAX_SAMPLES_PER_PIXEL) == 1
    assert band_pixels("cuda", MAX_SAMPLES_PER_PIXEL) >= 1 << 16


SINGLE_CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    from vtkillum.core.lights import DirectionalLight
    from vtkillum.core.render import render
    from vtkillum.core.scene import Scene
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume

    x = np.linspace(-1, 1, 12)
    v = Volume(np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2
                            + x[None, None, :] ** 2)))
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.5]),
                  lights=[DirectionalLight((1, -1, -1))])
    render(v, scene, "single", 2, 2, device="cpu")  # compile outside the timed part
    print("ready", flush=True)
    try:
        # The smallest accepted step: about 15 s of one CPU core at 8 x 8.
        render(v, scene, "single", 8, 8, device="cpu", step_size=0.00233)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(42)
    print("finished", flush=True)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT")
def test_ctrl_c_stops_single_scattering_within_a_second():
    waited, _, _ = interrupt_child(SINGLE_CHILD)
    assert waited < 3.0, waited  # one pixel per launch here: about 0.25 s


# --- path tracing: delta tracking grows with the majorant ------------------------------------------
def path_scene(u, **fields):
    return Scene(transfer_function=TF, opacity_unit_distance=u, **fields)


@pytest.mark.parametrize("u", [1e-7, 1e-30])
def test_path_refuses_a_huge_majorant_naming_the_smallest_unit_distance(u):
    volume = small_blob()
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"opacity_unit_distance .* mean free paths deep .* use "
                                         r"an opacity_unit_distance of at least 1\.14e-05 world"):
        render(volume, path_scene(u), "path", 8, 8, device="cpu", spp=1)
    assert time.perf_counter() - start < 10
    assert PathTracer(volume, path_scene(1.14e-5), 2, 2, device="cpu").optical_depth \
        <= MAX_OPTICAL_DEPTH
    with pytest.raises(ValueError, match="at least 1.14e-05"):
        PathTracer(volume, path_scene(1.13e-5), 2, 2, device="cpu")


def test_path_refuses_a_camera_too_far_for_float32_free_paths():
    volume = small_blob()
    far = Camera(position=(5.5, 5.5, 1e5), focal_point=(5.5, 5.5, 5.5), view_angle=0.01)
    with pytest.raises(ValueError, match="move the camera closer"):
        render(volume, path_scene(1e-3, camera=far), "path", 4, 4, device="cpu", spp=1)
    tracer = PathTracer(volume, path_scene(1e-3), 4, 4, device="cpu")
    with pytest.raises(ValueError, match="move the camera closer"):
        tracer.reset(far)
    # A thin medium may be seen from there.
    PathTracer(volume, path_scene(10.0, camera=far), 4, 4, device="cpu").run(1)


def test_path_bands_give_the_same_image(monkeypatch):
    import vtkillum.core.pathtrace as pt

    volume = Volume(blob(10).scalars[:, :7, :9], spacing=(0.5, 0.7, 0.4))
    scene = Scene(transfer_function=TF, lights=[DirectionalLight((1, -1, -0.5)),
                                                PointLight((1.0, 9.0, -2.0), (5, 5, 5))])
    whole = render(volume, scene, "path", 7, 5, device="cpu", spp=3, seed=2)
    tracer = PathTracer(volume, scene, 7, 5, device="cpu")
    events = 4 * (1 + tracer.optical_depth)
    monkeypatch.setitem(pt.BAND_EVENTS, "cpu", 3 * events)  # 3 pixels per launch
    assert tracer.bands()[:3] == [(0, 0, 1, 3), (0, 3, 1, 3), (0, 6, 1, 1)]
    banded = render(volume, scene, "path", 7, 5, device="cpu", spp=3, seed=2)
    np.testing.assert_array_equal(banded.radiance, whole.radiance)
    np.testing.assert_array_equal(banded.alpha, whole.alpha)
    np.testing.assert_array_equal(banded.info["radiance_variance"],
                                  whole.info["radiance_variance"])
    monkeypatch.setitem(pt.BAND_EVENTS, "cpu", 15 * events)  # two rows per launch
    assert [b[2] for b in PathTracer(volume, scene, 7, 5, device="cpu").bands()] == [2, 2, 1]
    assert whole.radiance.max() > 0


def test_an_interrupted_path_pass_is_not_counted(monkeypatch):
    import vtkillum.core.pathtrace as pt

    volume = small_blob()
    monkeypatch.setitem(pt.BAND_EVENTS, "cpu", 1)  # one pixel per launch
    tracer = PathTracer(volume, path_scene(1.0), 3, 2, device="cpu")
    tracer.run(1)
    launch, calls = pt.wp.launch, []

    def interrupted_launch(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return launch(*args, **kwargs)

    monkeypatch.setattr(pt.wp, "launch", interrupted_launch)
    with pytest.raises(KeyboardInterrupt):
        tracer.run(1)
    monkeypatch.setattr(pt.wp, "launch", launch)
    assert tracer.passes == 1
    with pytest.raises(RuntimeError, match="interrupted part-way.*reset"):
        tracer.run(1)
    with pytest.raises(RuntimeError, match="interrupted part-way"):
        tracer.result()
    tracer.reset()
    assert tracer.run(2).result().info["spp"] == 2


PATH_CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    from vtkillum.core.render import render
    from vtkillum.core.scene import Scene
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume

    x = np.linspace(-1, 1, 12)
    v = Volume(np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2
                            + x[None, None, :] ** 2)))
    tf = TransferFunction([0.0, 1.0], [0.0, 0.5])
    render(v, Scene(transfer_function=tf), "path", 2, 2, device="cpu", spp=1)  # compile
    print("ready", flush=True)
    try:
        # Near the smallest accepted unit distance: about 15 s per pass at 24 x 24.
        render(v, Scene(transfer_function=tf, opacity_unit_distance=1.2e-5), "path", 24, 24,
               device="cpu", spp=4)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(42)
    print("finished", flush=True)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT")
def test_ctrl_c_stops_a_dense_path_trace_within_a_second():
    waited, _, _ = interrupt_child(PATH_CHILD, delay=1.5)
    assert waited < 3.0, waited


# --- filters: VTK swallows exceptions raised in RequestData ----------------------------------------
def blob_image(n=24):
    vtk = pytest.importorskip("vtk")
    from vtkmodules.util.numpy_support import numpy_to_vtk

    volume = blob(n)
    image = vtk.vtkImageData()
    image.SetDimensions(*volume.dims)
    array = numpy_to_vtk(volume.scalars.ravel(order="F"), deep=True)
    array.SetName("s")
    image.GetPointData().SetScalars(array)
    return image


def test_filters_reraise_a_keyboard_interrupt_from_request_data():
    vtk = pytest.importorskip("vtk")
    from vtkillum.filters.light_transmittance import LightTransmittanceFilter

    calls = []

    class Interrupted(LightTransmittanceFilter):
        reuses_results = False  # every update computes (no memo of the arrays)

        def compute(self, volume, params):
            calls.append(1)
            if len(calls) in (1, 3, 4, 5, 6):
                raise KeyboardInterrupt
            return super().compute(volume, params)

    image = blob_image(8)
    f = Interrupted()
    f.SetDevice("cpu")
    errors = []
    f.AddObserver("ErrorEvent", lambda caller, event: errors.append(event))
    with pytest.raises(KeyboardInterrupt):  # not RuntimeError("pipeline update failed")
        f.execute(image)
    assert "interrupted" in f.GetLastError() and errors
    # The next update executes again.
    assert f.execute(image).GetNumberOfPoints() == 8**3 and len(calls) == 2
    assert f.GetLastError() is None
    for update in (f.Update, lambda: f.UpdateTimeStep(0.0), f.UpdateWholeExtent):
        f.Modified()
        with pytest.raises(KeyboardInterrupt):
            update()
    assert len(calls) == 5
    # Driven from downstream, VTK gives no way through: a failed update, and the filter says so.
    f.Modified()
    downstream = vtk.vtkImageShiftScale()
    downstream.SetInputConnection(f.GetOutputPort())
    downstream.GetExecutive().AddObserver("ErrorEvent", lambda *a: None)
    downstream.Update()
    assert len(calls) == 6 and "interrupted" in f.GetLastError()
    assert downstream.GetOutput().GetNumberOfPoints() == 0
    downstream.Update()  # and the next update executes again
    assert len(calls) == 7 and f.GetLastError() is None
    assert downstream.GetOutput().GetNumberOfPoints() == 8**3


FILTER_CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    import vtk
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkillum.filters.light_transmittance import LightTransmittanceFilter

    x = np.linspace(-1, 1, 24)
    values = np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2))
    image = vtk.vtkImageData()
    image.SetDimensions(24, 24, 24)
    array = numpy_to_vtk(values.ravel(order="F"), deep=True)
    array.SetName("s")
    image.GetPointData().SetScalars(array)
    f = LightTransmittanceFilter()
    f.SetDevice("cpu")
    f.execute(image)  # compile outside the timed part
    print("ready", flush=True)
    f.SetStepSize(4e-5)  # the smallest accepted step: about a minute
    try:
        f.execute(image)
    except KeyboardInterrupt:
        print("interrupted", f.GetLastError(), flush=True)
        sys.exit(42)
    print("finished", flush=True)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT")
def test_ctrl_c_in_a_filter_raises_keyboard_interrupt_from_execute():
    waited, out, err = interrupt_child(FILTER_CHILD)
    assert "interrupted (KeyboardInterrupt)" in out
    assert "pipeline update failed" not in err
    assert waited < 3.0, waited


# --- photon tracing: flights marched in steps of photon_step -----------------------------------------
def test_photon_step_is_capped_naming_the_smallest_step():
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"photon_step 1e-09 needs \d+ samples per photon flight "
                                         r".* use at least 1\.82e-05 world units"):
        render(small_blob(), Scene(transfer_function=TF), "photon", 4, 4, device="cpu",
               photon_step=1e-9, photons=100)
    assert time.perf_counter() - start < 10


def test_chunked_photon_tracing_gives_the_same_image(monkeypatch):
    from vtkillum.core.photon import tracing

    volume, scene = small_blob(), Scene(transfer_function=TF)
    options = {"photons": 500, "max_order": 3, "device": "cpu"}
    whole = render(volume, scene, "photon", 6, 5, **options)
    flight = int(np.ceil(np.linalg.norm(volume.extent) / 0.5))
    monkeypatch.setitem(tracing.TRACE_CHUNK_SAMPLES, "cpu", 7 * tracing.FLIGHTS_PER_PHOTON * flight)
    launches = []
    launch = tracing.wp.launch

    def counting_launch(kernel, *args, **kwargs):
        launches.append(kernel is tracing.trace_kernel)
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(tracing.wp, "launch", counting_launch)
    chunked = render(small_blob(), scene, "photon", 6, 5, **options)  # a new map
    assert sum(launches) >= 500 // 7
    np.testing.assert_array_equal(chunked.radiance, whole.radiance)
    np.testing.assert_array_equal(chunked.alpha, whole.alpha)
    assert whole.radiance.max() > 0


PHOTON_CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from vtkillum.core.render import render
    from vtkillum.core.scene import Scene
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.core.volume import Volume

    x = np.linspace(-1, 1, 12)
    v = Volume(np.exp(-3 * (x[:, None, None] ** 2 + x[None, :, None] ** 2
                            + x[None, None, :] ** 2)))
    scene = Scene(transfer_function=TransferFunction([0.0, 1.0], [0.0, 0.5]))
    render(v, scene, "photon", 2, 2, device="cpu", photons=100)  # compile
    print("ready", flush=True)
    try:
        # 95000 samples per flight for 200000 photons: minutes in one launch before.
        render(v, scene, "photon", 4, 4, device="cpu", photon_step=2e-4)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(42)
    print("finished", flush=True)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT")
def test_ctrl_c_stops_photon_tracing_within_a_second():
    waited, _, _ = interrupt_child(PHOTON_CHILD)
    assert waited < 3.0, waited
