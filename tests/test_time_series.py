"""Time series (issue 34): a 4-D NIfTI's time axis, file series and ``.pvd`` files, in the
readers, the VTK source, the filters' time cache and ``vtkillum render``; and (issue 35)
reading steps ahead on a background thread (``StepPrefetcher``, ``--prefetch``).

The data are written here: a ball that moves along +x by two voxels per step, as a
4-D NIfTI (VTK's writer, 2.5 s between volumes), as ``step_<k>.vti`` files (numbered
without padding, so that natural order matters: ``step_10`` after ``step_9``), and as a
``.pvd`` collection and a ParaView ``.series`` file over those files.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkIOImage import vtkNIFTIImageWriter
from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

import vtkillum.core.render as core_render
from vtkillum.cli import main, numbered_output
from vtkillum.core.volume import Volume
from vtkillum.io.convert import add_point_array, image_data_from_volume
from vtkillum.io.readers import TimeStepWarning, read_volume, time_steps
from vtkillum.io.time_series import (
    PREFETCH_THREAD_NAME,
    StepPrefetcher,
    TimeSeries,
    TimeSeriesSource,
    open_time_series,
    step_at,
)

SHAPE = (16, 12, 10)
STEPS = 4
SPACING = (1.0, 1.25, 1.5)
DT = 2.5
#: A scene that fixes what the defaults would fit to the data (so pictures compare).
SCENE = {
    "transfer_function": {"scalars": [0, 200, 1000], "opacity": [0, 0.2, 0.9],
                          "colors": [[1, 1, 1], [1, 0.8, 0.6], [1, 1, 1]]},
    "camera": {"position": [7.5, 6.9, 60.0], "focal_point": [7.5, 6.9, 6.75],
               "view_up": [0, 1, 0], "view_angle": 30},
    "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": [1, 1, 1]}],
}
RENDER = ["--method", "emission", "--size", "32", "24", "--device", "cpu", "--quiet"]


def ball(step: int) -> np.ndarray:
    """Step ``step``: a ball of radius 3 voxels at x = 4 + 2 * step, whole values 0 .. 1000
    (the NIfTI holds them exactly as int16)."""
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in SHAPE), indexing="ij")
    r = np.sqrt((i - 4.0 - 2.0 * step) ** 2 + (j - 6.0) ** 2 + (k - 5.0) ** 2)
    return np.round(np.clip(1000.0 * (4.0 - r) / 2.0, 0.0, 1000.0)).astype(np.float32)


def write_vti(path, values) -> None:
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(image_data_from_volume(Volume(values, SPACING), "density"))
    writer.Write()


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Paths of the 4-D NIfTI, the step files, the .pvd and the .series file."""
    root = tmp_path_factory.mktemp("series")
    image = vtkImageData()
    image.SetDimensions(*SHAPE)
    image.SetSpacing(*SPACING)
    add_point_array(image, "ball", np.stack([ball(t) for t in range(STEPS)], -1).astype(np.int16),
                    set_active=True)
    writer = vtkNIFTIImageWriter()
    writer.SetInputData(image)
    writer.SetTimeDimension(STEPS)
    writer.SetTimeSpacing(DT)
    writer.SetFileName(str(root / "moving.nii.gz"))
    writer.Write()
    steps = root / "steps"
    steps.mkdir()
    for t in range(STEPS):
        write_vti(steps / f"step_{t}.vti", ball(t))
    entries = "\n".join(f'    <DataSet timestep="{DT * t}" part="0" file="steps/step_{t}.vti"/>'
                        for t in range(STEPS))
    (root / "moving.pvd").write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" '
                                     f'version="0.1">\n  <Collection>\n{entries}\n'
                                     "  </Collection>\n</VTKFile>\n")
    (root / "moving.vti.series").write_text(json.dumps({
        "file-series-version": "1.0",
        "files": [{"name": f"steps/step_{t}.vti", "time": DT * t} for t in range(STEPS)]}))
    return {"nifti": root / "moving.nii.gz", "steps": steps, "pvd": root / "moving.pvd",
            "series": root / "moving.vti.series", "root": root}


@pytest.fixture
def renders(monkeypatch):
    """Counts the frames the core renders (the CLI's series loop calls core.render), with an
    empty frame cache (the .pvd names the same files as the pattern: its frames are the
    pattern's, rightly cached across tests otherwise)."""
    import vtkillum.cli

    monkeypatch.setattr(vtkillum.cli, "_FRAME_CACHE", None)
    calls = []
    original = core_render.render

    def counting(volume, scene, method, *args, **kwargs):
        calls.append(method)
        return original(volume, scene, method, *args, **kwargs)

    monkeypatch.setattr(core_render, "render", counting)
    return calls


def grey(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("L"), dtype=np.float64)


# --- readers ----------------------------------------------------------------------------------
def test_4d_nifti_time_axis(data):
    path = data["nifti"]
    assert time_steps(path) == [DT * t for t in range(STEPS)]
    for t in range(STEPS):
        volume = read_volume(path, time_step=t)
        np.testing.assert_array_equal(volume.scalars, ball(t))
    np.testing.assert_array_equal(read_volume(path, time_step=-1).scalars,
                                  read_volume(path, time_step=STEPS - 1).scalars)
    first = read_volume(path, time_step=0)
    with pytest.warns(TimeStepWarning, match=f"holds {STEPS} time steps"):
        np.testing.assert_array_equal(read_volume(path).scalars, first.scalars)
    with pytest.raises(ValueError, match=f"time step {STEPS} does not exist.*0..{STEPS - 1}"):
        read_volume(path, time_step=STEPS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TimeStepWarning)
        with pytest.raises(ValueError, match="time steps, not components.*--time-step"):
            read_volume(path, component=2)


def test_3d_file_has_no_time_axis(data):
    path = data["steps"] / "step_0.vti"
    assert time_steps(path) == []
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one volume: no warning
        read_volume(path)
    read_volume(path, time_step=0)
    with pytest.raises(ValueError, match="one volume, not a time series"):
        read_volume(path, time_step=1)


@pytest.mark.parametrize("kind", ["pvd", "series"])
def test_listed_series_read_their_files(data, kind):
    path = data[kind]
    assert time_steps(path) == [DT * t for t in range(STEPS)]
    np.testing.assert_array_equal(read_volume(path, time_step=2).scalars, ball(2))
    series = open_time_series(path)
    assert (series.kind, len(series)) == (kind, STEPS)
    assert [f.name for f in series.files] == [f"step_{t}.vti" for t in range(STEPS)]


@pytest.mark.parametrize("spec", ["pattern", "directory", "files"])
def test_file_series_in_natural_order(data, tmp_path, spec):
    """A pattern, a directory and a list of files give one step per file, step_10 after
    step_9 (the shell would sort step_10 before step_2)."""
    for t in range(11):
        write_vti(tmp_path / f"step_{t}.vti", ball(t % STEPS))
    given = {"pattern": str(tmp_path / "step_*.vti"), "directory": tmp_path,
             "files": sorted(str(p) for p in tmp_path.glob("step_*.vti"))}[spec]
    series = open_time_series(given)
    assert series.kind == "files" and series.times == [float(t) for t in range(11)]
    assert [f.name for f in series.files] == [f"step_{t}.vti" for t in range(11)]
    np.testing.assert_array_equal(series.read(10).scalars, ball(10 % STEPS))
    assert series.array_name == "step"


def test_series_errors_name_the_problem(data, tmp_path):
    with pytest.raises(FileNotFoundError, match="no file matches"):
        open_time_series(str(tmp_path / "nothing_*.vti"))
    (tmp_path / "a.vti").write_bytes((data["steps"] / "step_0.vti").read_bytes())
    (tmp_path / "b.mha").write_text("")
    with pytest.raises(ValueError, match="several kinds"):
        open_time_series(tmp_path)
    pvd = tmp_path / "two_parts.pvd"
    pvd.write_text('<VTKFile type="Collection"><Collection>'
                   '<DataSet timestep="0" part="0" file="a.vti"/>'
                   '<DataSet timestep="0" part="1" file="a.vti"/></Collection></VTKFile>')
    with pytest.raises(ValueError, match="2 parts per time step"):
        open_time_series(pvd)
    pvd.write_text('<VTKFile type="Collection"><Collection>'
                   '<DataSet timestep="0" file="missing.vti"/></Collection></VTKFile>')
    with pytest.raises(FileNotFoundError, match="missing.vti does not exist"):
        open_time_series(pvd)
    pvd.write_text("<VTKFile")
    with pytest.raises(ValueError, match="not a readable .pvd"):
        open_time_series(pvd)


def test_step_at_takes_the_step_at_or_before():
    times = [0.0, 2.5, 5.0]
    assert [step_at(times, t) for t in (-1.0, 0.0, 1.0, 2.5, 2.5 - 1e-12, 4.9, 5.0, 9.0)] == \
        [0, 0, 0, 1, 1, 1, 2, 2]


# --- the VTK source and the filters' time cache ----------------------------------------------
@pytest.mark.parametrize("kind", ["nifti", "pvd"])
def test_source_serves_steps_and_a_second_pass_is_served_by_the_filter_cache(data, kind):
    from vtkillum.core.lights import DirectionalLight
    from vtkillum.core.transfer_function import TransferFunction
    from vtkillum.filters import LightTransmittanceFilter

    source = TimeSeriesSource(data[kind])
    assert source.GetTimeSteps() == [DT * t for t in range(STEPS)]
    light = LightTransmittanceFilter()
    light.SetInputConnection(source.GetOutputPort())
    light.SetTransferFunction(TransferFunction([0.0, 1000.0], [0.0, 0.9]))
    light.SetLights([DirectionalLight((1.0, 0.0, 0.0))])
    light.SetDevice("cpu")
    computed = []
    original = light.compute
    light.compute = lambda volume, params: computed.append(1) or original(volume, params)
    first_pass = []
    for t in source.GetTimeSteps():
        out = light.execute(time=t)
        first_pass.append(np.array(out.GetPointData().GetArray("transmittance")))
        assert out.GetInformation().Get(out.DATA_TIME_STEP()) == t
    assert len(computed) == STEPS and source.reads == STEPS
    # The ball moves: so does its shadow.
    assert np.abs(first_pass[0] - first_pass[-1]).max() > 0.1
    for t, expected in zip(source.GetTimeSteps(), first_pass):
        out = light.execute(time=t)
        np.testing.assert_array_equal(np.array(out.GetPointData().GetArray("transmittance")),
                                      expected)
    stats = light.GetCacheStatistics()
    assert (stats.misses, stats.hits) == (STEPS, STEPS)
    assert len(computed) == STEPS and source.reads == STEPS  # nothing computed, nothing read
    # A time between steps gets the step at or before it.
    out = light.execute(time=DT * 1.5)
    assert out.GetInformation().Get(out.DATA_TIME_STEP()) == DT


def test_source_of_volumes_in_memory_and_a_step_of_another_grid():
    series = TimeSeries.from_volumes([(0.0, Volume(ball(0))), (1.0, Volume(ball(1)[:-1]))])
    source = TimeSeriesSource(series)
    source.UpdateTimeStep(0.0)
    assert source.GetOutputDataObject(0).GetDimensions() == SHAPE
    source.UpdateTimeStep(1.0)
    assert "must share one grid" in str(source.last_error)
    assert source.GetOutputDataObject(0).GetNumberOfPoints() == 0


# --- vtkillum render ---------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["nifti", "pattern", "pvd"])
def test_render_writes_a_picture_per_step_and_a_second_pass_uses_the_cache(data, tmp_path, kind,
                                                                           renders, capsys):
    spec = {"nifti": data["nifti"], "pattern": data["steps"] / "step_*.vti",
            "pvd": data["pvd"]}[kind]
    out = tmp_path / "frame.png"
    assert main(["render", str(spec), "-o", str(out), *RENDER]) == 0
    files = [numbered_output(out, t, STEPS) for t in range(STEPS)]
    assert [f.name for f in files] == [f"frame_{t:04d}.png" for t in range(STEPS)]
    assert all(f.is_file() for f in files) and not out.exists()
    pictures = [grey(f) for f in files]
    for a, b in zip(pictures, pictures[1:]):
        assert np.abs(a - b).mean() > 1.0, "consecutive steps look the same"
    assert len(renders) == STEPS
    # Again, as an animation: every frame from the cache (the same scene, size, method).
    assert main(["render", str(spec), "-o", str(tmp_path / "movie.gif"), *RENDER]) == 0
    assert len(renders) == STEPS
    gif = Image.open(tmp_path / "movie.gif")
    assert gif.n_frames == STEPS
    gif.seek(2)
    np.testing.assert_allclose(np.asarray(gif.convert("L"), dtype=np.float64), pictures[2],
                               atol=12)


def test_render_says_what_it_renders(data, tmp_path, capsys):
    status = main(["render", str(data["nifti"]), "-o", str(tmp_path / "f.png"),
                   *[a for a in RENDER if a != "--quiet"]])
    assert status == 0
    printed = capsys.readouterr().out
    assert f"a time series of {STEPS} steps (t = 0 .. {DT * (STEPS - 1):g})" in printed
    assert f"rendering all {STEPS} steps ('--time-step N' renders one)" in printed
    assert "f_0000.png" in printed and f"f_{STEPS - 1:04d}.png" in printed


def test_time_step_picks_one(data, tmp_path, renders):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(SCENE))
    common = ["--scene", str(scene), "--exposure", "1", *RENDER]
    assert main(["render", str(data["nifti"]), "-o", str(tmp_path / "all.png"), *common]) == 0
    assert main(["render", str(data["nifti"]), "--time-step", "2", "-o",
                 str(tmp_path / "two.png"), *common]) == 0
    assert sorted(p.name for p in tmp_path.glob("two*.png")) == ["two.png"]
    np.testing.assert_array_equal(grey(tmp_path / "two.png"), grey(tmp_path / "all_0002.png"))
    assert len(renders) == STEPS  # step 2 came from the cache
    assert main(["render", str(data["pvd"]), "--time-step", "-1", "-o",
                 str(tmp_path / "last.png"), *common]) == 0
    np.testing.assert_array_equal(grey(tmp_path / "last.png"),
                                  grey(tmp_path / f"all_{STEPS - 1:04d}.png"))


def test_render_time_step_errors(data, tmp_path, capsys):
    out = str(tmp_path / "x.png")
    assert main(["render", str(data["nifti"]), "--time-step", str(STEPS), "-o", out, *RENDER]) == 2
    assert f"time step {STEPS} does not exist: the series has {STEPS} steps" in \
        capsys.readouterr().err
    single = str(data["steps"] / "step_0.vti")
    assert main(["render", single, "--time-step", "0", "-o", out, *RENDER]) == 2
    assert "is one volume, not a time series" in capsys.readouterr().err
    assert main(["render", single, "-o", str(tmp_path / "x.gif"), *RENDER]) == 2
    assert "an animation needs a time series" in capsys.readouterr().err
    assert main(["render", str(data["nifti"]), "--component", "3", "-o", out, *RENDER]) == 2
    assert "time steps, not components" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_mp4_needs_the_animation_extra(data, tmp_path, renders, monkeypatch, capsys):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name.startswith("imageio") else find_spec(name, *a))
    status = main(["render", str(data["nifti"]), "-o", str(tmp_path / "m.mp4"), *RENDER])
    assert status == 2
    assert "pip install 'vtkillum[animation]'" in capsys.readouterr().err
    assert renders == [] and not list(tmp_path.iterdir())  # refused before any work


def test_mp4(data, tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    import imageio.v2 as imageio

    out = tmp_path / "m.mp4"
    assert main(["render", str(data["series"]), "-o", str(out), "--fps", "4", *RENDER]) == 0
    reader = imageio.get_reader(out)
    assert reader.count_frames() == STEPS
    assert reader.get_meta_data()["size"] == (32, 24)
    assert reader.get_meta_data()["fps"] == pytest.approx(4.0)


def test_scene_and_export_of_a_series(data, tmp_path, capsys):
    scene = tmp_path / "s.json"
    assert main(["scene", "--dataset", str(data["nifti"]), "-o", str(scene)]) == 0
    assert json.loads(scene.read_text())["camera"] is not None
    assert main(["export", str(data["nifti"]), "-o", str(tmp_path / "x.vti")]) == 2
    assert f"time series of {STEPS} steps; export one with --time-step N" in \
        capsys.readouterr().err
    assert main(["export", str(data["nifti"]), "--time-step", "3", "-o",
                 str(tmp_path / "x.vti")]) == 0
    np.testing.assert_array_equal(read_volume(tmp_path / "x.vti").scalars, ball(3))


def test_one_file_is_a_volume_not_a_series(data, tmp_path):
    """A pattern matching one file, or a directory holding one, is that volume: rendered
    under the output name, served without time steps."""
    write_vti(tmp_path / "only_7.vti", ball(1))
    for spec in (str(tmp_path / "only_*.vti"), tmp_path):
        series = open_time_series(spec)
        assert (series.kind, series.is_series, len(series)) == ("volume", False, 1)
    source = TimeSeriesSource(tmp_path)
    source.UpdateInformation()
    info = source.GetOutputInformation(0)
    assert not info.Has(source.GetExecutive().TIME_STEPS())
    source.Update()
    assert source.GetOutputDataObject(0).GetDimensions() == SHAPE
    out = tmp_path / "one.png"
    assert main(["render", str(tmp_path / "only_*.vti"), "-o", str(out), *RENDER]) == 0
    assert out.is_file()


# --- reading ahead (issue 35) ------------------------------------------------------------------
def prefetch_threads() -> list:
    return [t for t in threading.enumerate() if t.name == PREFETCH_THREAD_NAME and t.is_alive()]


class Timeline:
    """Reads and computes that sleep, with the intervals they took (``time.monotonic``)."""

    def __init__(self, read_s=0.15, compute_s=0.15, fail=None):
        self.read_s, self.compute_s, self.fail = read_s, compute_s, fail
        self.reads, self.computes, self.read_order = {}, {}, []
        self.lock = threading.Lock()

    def read(self, step):
        with self.lock:
            self.read_order.append(step)
        start = time.monotonic()
        time.sleep(self.read_s)
        self.reads[step] = (start, time.monotonic())
        if step == self.fail:
            raise OSError(f"step_{step}.vti: not a readable VTK XML file (truncated)")
        return ("volume", step)

    def compute(self, step):
        start = time.monotonic()
        time.sleep(self.compute_s)
        self.computes[step] = (start, time.monotonic())

    def overlap(self) -> float:
        """Seconds during which a read and a compute ran at once."""
        return sum(max(0.0, min(r1, c1) - max(r0, c0))
                   for r0, r1 in self.reads.values() for c0, c1 in self.computes.values())


def play(timeline, steps, ahead):
    """Take ``steps`` in order from a prefetcher, computing each; what was handed over."""
    got = []
    with StepPrefetcher(timeline.read, ahead) as prefetcher:
        for n, k in enumerate(steps):
            got.append(prefetcher.take(k, then=steps[n + 1:n + 1 + ahead]))
            assert len(prefetcher.pending) <= ahead
            timeline.compute(k)
    return got


def test_prefetch_reads_the_next_step_while_this_one_computes():
    """Measured by the overlap of the intervals, not by wall time: without prefetching
    reads and computes never overlap; with it, every read after the first runs during the
    compute of the step before (ideally (n - 1) / n of the reading time)."""
    steps = list(range(5))
    serial = Timeline()
    assert play(serial, steps, ahead=0) == [("volume", k) for k in steps]
    assert serial.overlap() == 0.0
    ahead = Timeline()
    assert play(ahead, steps, ahead=1) == [("volume", k) for k in steps]
    reading = sum(b - a for a, b in ahead.reads.values())
    assert ahead.overlap() >= 0.5 * reading, (ahead.overlap(), reading)
    for k in steps[:-1]:  # step k + 1 was being read while step k computed
        (r0, r1), (c0, c1) = ahead.reads[k + 1], ahead.computes[k]
        assert r0 < c1 and c0 < r1, k
    assert ahead.read_order == steps  # read once each, in order
    assert not prefetch_threads()


@pytest.mark.parametrize("ahead", [1, 3])
def test_prefetch_is_bounded(ahead):
    """Fast reads, slow computes: while step k computes nothing past k + ahead is read."""
    timeline = Timeline(read_s=0.0, compute_s=0.05)
    furthest = {}
    original = timeline.compute

    def compute(step):
        wanted = min(step + ahead, steps[-1])
        deadline = time.monotonic() + 30
        while max(timeline.read_order) < wanted and time.monotonic() < deadline:
            time.sleep(0.005)  # the reads asked for are done ...
        time.sleep(0.05)  # ... and a runaway reader would have gone on meanwhile
        with timeline.lock:
            furthest[step] = max(timeline.read_order)
        original(step)

    timeline.compute = compute
    steps = list(range(8))
    play(timeline, steps, ahead)
    assert furthest == {k: min(k + ahead, steps[-1]) for k in steps}  # that far, no further
    assert timeline.read_order == steps


@pytest.mark.parametrize("ahead", [0, 1, 2])
def test_an_unreadable_step_is_the_same_error_at_the_same_step(ahead):
    timeline = Timeline(read_s=0.01, compute_s=0.01, fail=2)
    done = []
    with pytest.raises(OSError) as caught, StepPrefetcher(timeline.read, ahead) as prefetcher:
        steps = list(range(5))
        for n, k in enumerate(steps):
            prefetcher.take(k, then=steps[n + 1:n + 1 + ahead])
            timeline.compute(k)
            done.append(k)
    assert done == [0, 1]  # the steps before it, all of them
    assert str(caught.value) == "step_2.vti: not a readable VTK XML file (truncated)"
    assert timeline.read_order[:3] == [0, 1, 2] and max(timeline.read_order) <= 2 + ahead
    assert not prefetch_threads()


def test_cancelling_waits_for_the_read_under_way_and_drops_the_rest():
    """Ctrl-C while step 1 is being read and step 2 waits: leaving the block waits for
    step 1's read, never starts step 2's, and no thread is left."""
    timeline = Timeline(read_s=0.3)
    started = threading.Event()
    read = timeline.read

    def reading(step):
        if step == 1:
            started.set()
        return read(step)

    with pytest.raises(KeyboardInterrupt), StepPrefetcher(reading, ahead=2) as prefetcher:
        prefetcher.take(0, then=[1, 2])
        assert started.wait(30)
        raise KeyboardInterrupt
    assert not prefetch_threads()
    assert timeline.read_order == [0, 1] and 1 in timeline.reads  # finished, not abandoned
    with pytest.raises(RuntimeError, match="after close"):
        prefetcher.take(3)


def test_prefetch_option_errors():
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="whole number"):
            StepPrefetcher(lambda k: k, bad)
        with pytest.raises(ValueError, match="whole number"):
            TimeSeriesSource(prefetch=bad)


def test_source_prefetch_serves_the_same_images_and_rereads_a_rewritten_step(data, tmp_path):
    steps = tmp_path / "steps"
    steps.mkdir()
    for t in range(STEPS):
        write_vti(steps / f"step_{t}.vti", ball(t))
    plain = TimeSeriesSource(str(steps / "step_*.vti"))
    ahead = TimeSeriesSource(str(steps / "step_*.vti"), prefetch=1)
    assert ahead.GetPrefetch() == 1

    def scalars(source, t):
        source.UpdateTimeStep(t)
        out = source.GetOutputDataObject(0)
        return np.array(out.GetPointData().GetArray(0))

    np.testing.assert_array_equal(scalars(ahead, 0), scalars(plain, 0))
    assert ahead._prefetcher.pending == [1]  # step 1 is read while the pipeline works on 0
    ahead._prefetcher._futures[1].result(timeout=60)  # its read done, then:
    write_vti(steps / "step_1.vti", ball(3))  # rewritten after its read ahead
    stamp = (steps / "step_1.vti").stat().st_mtime_ns
    os.utime(steps / "step_1.vti", ns=(stamp + 10**9, stamp + 10**9))  # coarse clocks
    np.testing.assert_array_equal(scalars(ahead, 1), ball(3).ravel(order="F"))
    for t in (2.0, 3.0):
        np.testing.assert_array_equal(scalars(ahead, t), scalars(plain, t))
    assert ahead.reads == STEPS + 1  # one read ahead each, step 1 once more
    assert ahead._prefetcher.pending == []  # nothing past the last step
    ahead.SetPrefetch(0)
    assert ahead._prefetcher is None and not prefetch_threads()


def npy_frames(directory: Path) -> dict:
    return {p.name: np.load(p) for p in sorted(directory.glob("*.npy"))}


@pytest.mark.parametrize("method", ["emission", "convection-diffusion"])
def test_render_with_prefetch_writes_the_same_files_and_uploads_ahead(data, tmp_path,
                                                                      monkeypatch, method):
    """``--prefetch 0, 1, 3``: the same radiance and alpha, bit for bit; with prefetching
    every step reaches the render prepared on the thread (value range, and the content
    hash that convection-diffusion keys its light volume with), and no device copy made
    there (warp stays on the main thread)."""
    import vtkillum.cli

    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(SCENE))
    prepared = []
    original = core_render.render

    def spying(volume, *args, **kwargs):
        cached = {"value_range", "content_key"} & set(vars(volume))
        assert not any(name.startswith("scalars@") for name in volume._derived)
        prepared.append(cached)
        return original(volume, *args, **kwargs)

    monkeypatch.setattr(core_render, "render", spying)
    outputs = {}
    for ahead in (0, 1, 3):
        monkeypatch.setattr(vtkillum.cli, "_FRAME_CACHE", None)  # render every step again
        out = tmp_path / f"prefetch{ahead}"
        out.mkdir()
        args = ["render", str(data["steps"] / "step_*.vti"), "-o", str(out / "f.npy"),
                "--scene", str(scene), "--prefetch", str(ahead),
                *[a if a != "emission" else method for a in RENDER]]
        assert main(args) == 0
        outputs[ahead] = npy_frames(out)
        assert len(outputs[ahead]) == 2 * STEPS  # radiance and alpha per step
        keyed = {"value_range", "content_key"} if method == "convection-diffusion" else {
            "value_range"}
        assert prepared == [keyed if ahead else set()] * STEPS
        prepared.clear()
    for ahead in (1, 3):
        assert outputs[ahead].keys() == outputs[0].keys()
        for name, frame in outputs[0].items():
            np.testing.assert_array_equal(outputs[ahead][name], frame, err_msg=name)
    assert not prefetch_threads()


def test_render_of_a_series_with_an_unreadable_step(data, tmp_path, capsys):
    """Step 2 is not a VTK file: with or without prefetching the steps before it are
    written and the run ends with the same one-line error."""
    steps = tmp_path / "steps"
    steps.mkdir()
    for t in range(STEPS):
        write_vti(steps / f"step_{t}.vti", ball(t))
    (steps / "step_2.vti").write_text("<VTKFile type=\"ImageData\"> truncated")
    scene = tmp_path / "scene.json"  # every field given: the scene reads step 0 only
    scene.write_text(json.dumps(SCENE))
    seen = {}
    for ahead in (0, 1, 2):
        out = tmp_path / f"out{ahead}"
        out.mkdir()
        status = main(["render", str(steps / "step_*.vti"), "-o", str(out / "f.npz"),
                       "--scene", str(scene), "--prefetch", str(ahead), *RENDER])
        err = capsys.readouterr().err
        seen[ahead] = (status, err.replace(str(out), "OUT"), sorted(os.listdir(out)))
    assert seen[0][0] == 2 and "step_2.vti" in seen[0][1], seen[0]
    assert seen[0][2] == ["f_0000.npz", "f_0001.npz"]
    assert seen[1] == seen[0] and seen[2] == seen[0]
    assert not prefetch_threads()


def test_render_prefetch_errors(data, tmp_path, capsys):
    assert main(["render", str(data["nifti"]), "-o", str(tmp_path / "f.png"), "--prefetch",
                 "-1", *RENDER]) == 2
    assert "--prefetch -1: the steps read ahead must be 0 or more" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


#: A series render whose steps each take a second, saying when each begins; its reads are
#: slow too (0.5 s), so that a read is under way when the test's Ctrl-C arrives.
SLOW_SERIES = textwrap.dedent("""
    import sys, time
    import vtkillum.core.render as core_render
    import vtkillum.io.time_series as ts
    real_read, real_render = ts.TimeSeries.read, core_render.render
    def read(self, step):
        time.sleep(0.5)
        return real_read(self, step)
    def render(volume, *args, **kwargs):
        print("rendering", flush=True)
        time.sleep(1.0)
        return real_render(volume, *args, **kwargs)
    ts.TimeSeries.read, core_render.render = read, render
    from vtkillum.cli import main
    status = main(sys.argv[1:])
    import threading
    print("threads", sorted(t.name for t in threading.enumerate()), flush=True)
    sys.exit(status)
""")


def test_ctrl_c_during_a_prefetched_series_render(data, tmp_path):
    """Ctrl-C while step 1 renders and step 2 is read: status 130, the finished step
    written, no partial file, no thread left when main returns."""
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(SCENE))
    out = tmp_path / "out"
    out.mkdir()
    process = subprocess.Popen(
        [sys.executable, "-c", SLOW_SERIES, "render", str(data["steps"] / "step_*.vti"),
         "-o", str(out / "f.npz"), "--scene", str(scene), *RENDER],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=Path(__file__).resolve().parents[1])
    try:
        for _ in range(2):  # step 0, then step 1 begins (step 2 is being read)
            line = process.stdout.readline()
            assert line.strip() == "rendering", (line, process.stderr.read() if not line else "")
        process.send_signal(signal.SIGINT)
        stdout, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, err
    assert "interrupted" in err
    threads = stdout.strip().splitlines()[-1]
    assert threads.startswith("threads") and PREFETCH_THREAD_NAME not in threads, threads
    assert sorted(os.listdir(out)) == ["f_0000.npz"]
