"""Issue 34: command-line progress says what a render is doing and how long is left.

* A first run compiles warp's kernels (seconds to a minute on a CPU): that phase is named
  and its time kept out of the estimates, which come only from work measured after it.
* Every render says something within 2 s, for every method, also while one kernel runs
  for long or a method reports no fractions (a heartbeat with the stage's name).

Time is faked where it can be (a clock the test advances), so that the tests are fast
and do not depend on the machine's load.
"""

from __future__ import annotations

import io
import re
import threading
import time

import numpy as np
import pytest
import warp as wp

from vtkillum import cli, progress as progress_module
from vtkillum.core.device import init_warp
from vtkillum.core.render import METHODS
from vtkillum.progress import COMPILING, KernelWatch, ProgressReporter, stage_name

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")
init_warp()  # quietly, as the command line does


class FakeClock:
    """Seconds that pass only when the test says so."""

    def __init__(self):
        self.now = 0.0
        self.lock = threading.Lock()

    def __call__(self) -> float:
        with self.lock:
            return self.now

    def advance(self, seconds: float) -> None:
        with self.lock:
            self.now += seconds


def _launch():
    """One small launch of a kernel the renders use anyway (compiled once per cache)."""
    from vtkillum.core.empty_space import block_range_kernel

    scalars = wp.zeros((2, 2, 2), dtype=wp.float32, device="cpu")
    out = wp.zeros((2, 2, 2, 2), dtype=wp.float32, device="cpu")
    wp.launch(block_range_kernel, dim=(2, 2, 2), inputs=[scalars, 1, out], device="cpu")


def _seconds(text: str) -> float | None:
    """The estimate a line states ("about 1 min 05 s left"), in seconds."""
    m = re.search(r"about (?:(\d+) h )?(?:(\d+) min )?(?:(\d+) s)? ?left", text)
    if m is None:
        return None
    h, minutes, s = (int(x) if x else 0 for x in m.groups())
    return 3600.0 * h + 60.0 * minutes + s


def _check_estimates(printed, end):
    """Every stated estimate within 5x of the true time left (a second of rounding)."""
    stated = 0
    for at, text, left in printed:
        if left is None:
            assert "left" not in text
            continue
        stated += 1
        assert _seconds(text) == pytest.approx(left, abs=0.5)
        true = end - at
        assert true / 5 - 1 <= left <= 5 * true + 1, (text, f"true time left {true:.1f} s")
    return stated


def _fake_render(clock, progress, steps=20, step_seconds=2.0, first_extra=0.0, launch=None):
    """A render of ``steps`` equal passes reporting after each; the first pass takes
    ``first_extra`` longer (a compile warp does not report, or set-up)."""
    for k in range(1, steps + 1):
        if launch is not None:
            launch()
        clock.advance(step_seconds + (first_extra if k == 1 else 0.0))
        progress(k / steps, f"{k}/{steps} passes")


def test_slow_first_pass_never_gives_an_estimate_5x_off():
    """The issue's '0 %, 12 s spent, about 210 h 47 min left' (done at 17 s): the first
    pass holds a compile the reporter cannot see; the rate is measured after it."""
    clock = FakeClock()
    reporter = ProgressReporter(False, "single 384x384", stream=io.StringIO(), mode="lines",
                                interval=0.0, first_line=0.0, clock=clock, heartbeat=False)
    with reporter as progress:
        # the first fraction is tiny (an empty band of rows) after a 12 s compile
        clock.advance(12.0)
        progress(1e-5)
        _fake_render(clock, progress, steps=10, step_seconds=0.5)
    assert _check_estimates(reporter.printed, clock()) >= 5
    assert "h " not in reporter.stream.getvalue()


def test_compile_in_the_first_launch_is_named_and_kept_out_of_the_estimate(monkeypatch):
    """A compile inside the first kernel launch (simulated: the module load takes 100 s)
    is announced as such, and the estimates use only the passes after it."""
    clock = FakeClock()
    real_load = wp.Module.load
    seen = {"compiling": [], "loads": 0}

    def slow_first_load(module, *args, **kwargs):
        seen["loads"] += 1
        if seen["loads"] == 1:
            clock.advance(100.0)  # the compile
            seen["compiling"].append(reporter.line()[0])  # what a heartbeat would say now
        return real_load(module, *args, **kwargs)

    monkeypatch.setattr(wp.Module, "load", slow_first_load)
    stream = io.StringIO()
    reporter = ProgressReporter(False, "transmittance 256x256", stream=stream, mode="lines",
                                interval=0.0, first_line=0.0, clock=clock, heartbeat=False)
    with reporter as progress:
        _fake_render(clock, progress, steps=20, step_seconds=2.0, launch=_launch)
    assert seen["compiling"] and COMPILING in seen["compiling"][0]
    assert reporter.watch.compiled == 1 and reporter.watch.compile_seconds == pytest.approx(100)
    assert _check_estimates(reporter.printed, clock()) >= 10
    # Measured from the passes: 2 s each, whatever the compile took.
    last = [left for _, _, left in reporter.printed if left is not None][-1]
    assert last == pytest.approx(2.0, abs=0.01)  # at 19/20, one pass left
    assert "(1 min 40 s compiling)" in stream.getvalue()
    assert wp.Module.load is slow_first_load and not hasattr(wp.launch, "__wrapped__")


def test_code_generation_marks_a_compile_however_short(monkeypatch):
    """warp generates code only when its kernel cache misses: that is a compile."""
    real_load = wp.Module.load

    def load_after_codegen(module, *args, **kwargs):
        module._run_codegen({}, True)
        return real_load(module, *args, **kwargs)

    monkeypatch.setattr(wp.Module, "_run_codegen", lambda module, options, is_cpu: None)
    monkeypatch.setattr(wp.Module, "load", load_after_codegen)
    with KernelWatch() as watch:
        _launch()
        assert not watch.compiling()
    assert watch.compiled == 1
    monkeypatch.setattr(wp.Module, "load", real_load)
    with KernelWatch() as watch:  # a load without code generation: from the cache
        _launch()
    assert watch.compiled == 0 and watch.stage == "empty-space skipping"


def test_the_heartbeat_speaks_while_one_kernel_runs_long(monkeypatch):
    """Real time: the rendering thread is stuck in a module load (a compile) for 0.6 s;
    the heartbeat thread says so after ``first_line`` (0.1 s here), not when it ends."""
    real_load = wp.Module.load
    said = {}

    def stuck_load(module, *args, **kwargs):
        time.sleep(0.6)
        said["during"] = stream.getvalue()
        return real_load(module, *args, **kwargs)

    monkeypatch.setattr(wp.Module, "load", stuck_load)
    monkeypatch.setattr(progress_module, "HEARTBEAT_POLL", 0.02)
    monkeypatch.setattr(progress_module, "COMPILE_GUESS_SECONDS", 0.05)
    stream = io.StringIO()
    with ProgressReporter(False, "ambient-scattering 64x64", stream=stream, mode="lines",
                          interval=10.0, first_line=0.1):
        _launch()
    assert said["during"].startswith(f"ambient-scattering 64x64: {COMPILING}, 0 s spent")


def test_bar_on_a_terminal_shows_the_phase_and_our_estimate(monkeypatch):
    clock = FakeClock()
    stream = io.StringIO()
    reporter = ProgressReporter(False, "path 64x64", stream=stream, mode="bar", clock=clock,
                                heartbeat=False)
    with reporter as progress:
        _fake_render(clock, progress, steps=10, step_seconds=1.0, first_extra=30.0)
        assert reporter.bar.n == 100
    text = stream.getvalue()
    assert "path 64x64" in text and "10/10 passes" in text and "left" in text
    assert "5 min" not in text  # tqdm's own estimate would count the slow first pass


def test_no_fractions_no_estimate_but_the_stage():
    clock = FakeClock()
    reporter = ProgressReporter(False, "many-lights 64x64", stream=io.StringIO(),
                                mode="lines", interval=5.0, clock=clock, heartbeat=False)
    with reporter:
        reporter.watch.stage = stage_name("vtkillum.core.many_lights.gather")
        clock.advance(6.0)
        reporter._on_launch()
    assert reporter.printed[0][1] == "many-lights 64x64: gathering virtual lights, 6 s spent"
    assert reporter.printed[0][2] is None


@pytest.mark.parametrize("module, stage", [
    ("vtkillum.core.raycast", "ray casting"),
    ("vtkillum.core.photon.tracing", "photon tracing"),
    ("vtkillum.core.convection_diffusion.multigrid", "diffusion"),
    ("vtkillum.core.some_new_stage", "some new stage"),
    ("vtkillum.core.warp_common", None),
    ("warp._src.utils", None),
    (None, None),
])
def test_stage_names(module, stage):
    assert stage_name(module) == stage


# --- every method, through the command line -------------------------------------------------------
#: Method -> options that keep its render small.
SMALL = {"path": ["--spp", "2"], "photon": ["--option", "photons=2000"],
         "many-lights": ["--option", "count=8", "--option", "sets=1"]}


@pytest.mark.parametrize("method", sorted(m for m in METHODS if m not in cli.HIDDEN_METHODS))
def test_every_method_says_what_it_does_within_two_seconds(method, tmp_path, monkeypatch,
                                                           capsys):
    """Fake time: each kernel launch takes 1 s. Every method's first line comes by 2 s,
    names a stage, and the render went through the reporter (it lasted over 2 s)."""
    clock = FakeClock()
    monkeypatch.setattr(progress_module, "DEFAULT_CLOCK", clock)
    real_launch = wp.launch

    def slow_launch(*args, **kwargs):
        clock.advance(1.0)
        return real_launch(*args, **kwargs)

    monkeypatch.setattr(wp, "launch", slow_launch)
    reporters = []

    class Recorded(ProgressReporter):
        def __init__(self, *args, **kwargs):
            kwargs["heartbeat"] = False  # the launches speak; the thread has its own test
            super().__init__(*args, **kwargs)
            reporters.append(self)

    monkeypatch.setattr(cli, "_progress_bar", Recorded)
    monkeypatch.setenv("VTKILLUM_PROGRESS_INTERVAL", "5")
    options = SMALL.get(method, [])
    if method == "refraction":  # one distant light in the camera's hemisphere
        options = ["--scene", _one_light_scene(tmp_path)]
    status = cli.main(["render", "builtin:ct:16", "-m", method, "--size", "12", "12",
                       "--device", "cpu", "-o", str(tmp_path / "out.npy"), *options])
    _, err = capsys.readouterr()
    assert status == 0, err
    (reporter,) = reporters
    assert clock() > 2.0, "the render must last over 2 s (fake) for the test to mean anything"
    first_at, first_line, _ = reporter.printed[0]
    assert first_at - reporter._start <= 2.0, first_line
    assert first_line.startswith(f"{method} 12x12: ") and first_line in err
    doing = first_line.split(": ", 1)[1].split(",")[0]
    assert doing not in ("rendering", COMPILING), first_line  # a stage's name


def _one_light_scene(tmp_path):
    import json

    from vtkillum.data.builtin import builtin_scene, load_builtin

    scene = builtin_scene("builtin:ct:16", load_builtin("builtin:ct:16")).to_dict()
    scene["lights"] = [{"type": "directional", "direction": [0.3, -0.5, -1.0],
                        "irradiance": [3, 3, 3]}]
    path = tmp_path / "one_light.json"
    path.write_text(json.dumps(scene))
    return str(path)


def test_path_estimate_skips_a_pass_that_compiled(monkeypatch, capsys):
    """The path tracer's estimate comes from the first pass without a compile."""
    from vtkillum.core import pathtrace
    from vtkillum.data.builtin import builtin_scene, load_builtin

    monkeypatch.setattr(cli, "LONG_RENDER_SECONDS", 0.0)
    real_run = pathtrace.PathTracer.run
    watch = KernelWatch()
    passes = []

    def run(self, n=1):
        start = time.perf_counter()
        if self.passes == 0:  # the first pass "compiles" for 3 s
            watch.compiled += 1
            watch.compile_seconds += 3.0
            time.sleep(0.2)
        real_run(self, n)
        passes.append(time.perf_counter() - start)
        return self

    monkeypatch.setattr(pathtrace.PathTracer, "run", run)
    volume = load_builtin("builtin:ct:16")
    scene = builtin_scene("builtin:ct:16", volume)
    result, interrupted = cli.render_path_with_estimate(volume, scene, 8, 6, "cpu", spp=4,
                                                        watch=watch)
    err = capsys.readouterr().err
    assert interrupted is None and np.isfinite(result.radiance).all()
    took = float(re.search(r"one sample per pixel took ([\d.]+) s", err).group(1))
    assert took == pytest.approx(passes[1], abs=0.01) and took < 0.2  # the second pass
    assert "after 3.0 s compiling kernels" in err
