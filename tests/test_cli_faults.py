"""The command line right under faults (issue 33): writes, signals, full disks, odd inputs.

Every output format is written under its final name (an exported ``ct.mhd`` names
``ct.raw``), nothing hidden survives an error, a full disk or a signal, SIGTERM during a
``path`` render keeps the samples, a scene file is read once (pipes work), and JSON,
numbers and long values are bounded with one clear line.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("vtk")

from vtkillum.cli import main  # noqa: E402
from vtkillum.io import writers  # noqa: E402
from vtkillum.io.readers import read_volume  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: Every format ``render`` writes, with the files it makes.
RENDER_FORMATS = {"a.png": ["a.png"], "a.npy": ["a.alpha.npy", "a.npy"], "a.npz": ["a.npz"]}
#: Every format ``export`` writes, with the files it makes.
EXPORT_FORMATS = {"ct.vti": ["ct.vti"], "ct.nii": ["ct.nii"], "ct.nii.gz": ["ct.nii.gz"],
                  "ct.mha": ["ct.mha"], "ct.mhd": ["ct.mhd", "ct.raw"]}


def run(capsys, *argv):
    """Run the CLI in-process; returns (exit status, stdout, stderr)."""
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def write_command(directory: Path, name: str) -> list[str]:
    """The command that writes ``name`` in ``directory`` (render, scene or export)."""
    out = str(directory / name)
    if name in EXPORT_FORMATS:
        return ["export", "builtin:ct:16", "-o", out]
    if name.endswith(".json"):
        return ["scene", "--dataset", "builtin:ct:16", "-o", out]
    return ["render", "builtin:ct:16", "-m", "emission", "--size", "12", "8", "--device", "cpu",
            "-q", "-o", out]


def expected_files(name: str) -> list[str]:
    return sorted({**RENDER_FORMATS, **EXPORT_FORMATS, "s.json": ["s.json"]}[name])


def listing(directory: Path) -> list[str]:
    """Every entry of ``directory``, hidden ones included."""
    return sorted(os.listdir(directory))


# --- files under their final names -------------------------------------------------------------
@pytest.mark.parametrize("name", sorted({**RENDER_FORMATS, **EXPORT_FORMATS, "s.json": 0}))
def test_every_format_is_written_under_its_final_names_and_nothing_hidden(tmp_path, capsys,
                                                                          name):
    """Writing twice (a new file, then over it) leaves exactly the output's files, no
    staging name inside them, and the output reads back."""
    for _ in range(2):
        status, _, err = run(capsys, *write_command(tmp_path, name))
        assert status == 0, err
        assert listing(tmp_path) == expected_files(name)
    for file in expected_files(name):
        assert f".{name}.".encode() not in (tmp_path / file).read_bytes()
    if name in EXPORT_FORMATS:
        assert read_volume(tmp_path / name).dims == (16, 16, 16)


def test_an_exported_mhd_names_its_final_raw_and_the_pair_can_be_copied(tmp_path, capsys):
    """Was: ``ElementDataFile = .ct.mhd.XXXX.raw`` (the hidden temporary), one more hidden
    .raw per export, and a copied ct.mhd was broken."""
    assert main(["export", "builtin:ct:16", "-o", str(tmp_path / "ct.mhd")]) == 0
    header = (tmp_path / "ct.mhd").read_text().splitlines()
    assert "ElementDataFile = ct.raw" in header
    elsewhere = tmp_path / "copy"
    elsewhere.mkdir()
    for name in ("ct.mhd", "ct.raw"):
        shutil.copy(tmp_path / name, elsewhere / name)
    original, copied = read_volume(tmp_path / "ct.mhd"), read_volume(elsewhere / "ct.mhd")
    np.testing.assert_array_equal(copied.scalars, original.scalars)
    np.testing.assert_allclose(copied.origin, original.origin)


def test_export_refuses_a_directory_in_the_way_of_the_mhd_data_file(tmp_path, capsys):
    (tmp_path / "ct.raw").mkdir()
    status, _, err = run(capsys, "export", "builtin:ct:16", "-o", tmp_path / "ct.mhd")
    assert status == 2 and "ct.raw" in err and "directory" in err
    assert listing(tmp_path) == ["ct.raw"]


# --- a full disk ------------------------------------------------------------------------------------
class FullDisk:
    """A file that takes ``room`` bytes, then fails as a full disk does (ENOSPC)."""

    def __init__(self, file, room: int) -> None:
        self._file, self._room = file, room

    def write(self, data) -> int:
        data = bytes(data)
        if len(data) > self._room:
            self._file.write(data[: self._room])
            self._room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= len(data)
        return self._file.write(data)

    def __getattr__(self, name):
        return getattr(self._file, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()


def fill_the_disk(monkeypatch) -> None:
    """Every write of :mod:`vtkillum.io.writers` runs out of space: file objects after a
    few bytes, VTK writers after writing their files."""
    real_open, real_run_writer = open, writers.run_writer

    def full_open(path, mode="r", *args, **kwargs):
        file = real_open(path, mode, *args, **kwargs)
        return FullDisk(file, 100) if "w" in mode else file

    def full_run_writer(writer, path):
        real_run_writer(writer, path)  # the staged files exist: they must go too
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(writers, "open", full_open, raising=False)
    monkeypatch.setattr(writers, "run_writer", full_run_writer)


@pytest.mark.parametrize("name", sorted({**RENDER_FORMATS, **EXPORT_FORMATS, "s.json": 0}))
def test_a_full_disk_is_one_line_keeps_the_old_output_and_leaves_nothing(tmp_path, capsys,
                                                                        monkeypatch, name):
    """Was: the old output kept, but a hidden .tmp/.raw left behind."""
    for file in expected_files(name):
        (tmp_path / file).write_text(f"old {file}")
    fill_the_disk(monkeypatch)
    status, _, err = run(capsys, *write_command(tmp_path, name))
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vtkillum: error: ")
    assert "no space left on device" in lines[0] and name in lines[0]
    assert listing(tmp_path) == expected_files(name)
    for file in expected_files(name):
        assert (tmp_path / file).read_text() == f"old {file}"


def test_vtk_s_out_of_disk_space_error_is_a_full_disk(tmp_path):
    """VTK writers report a full disk by an error code, not an exception."""
    from vtkmodules.vtkCommonMisc import vtkErrorCode

    class Writer:
        def Write(self):
            (tmp_path / "x.vti").write_bytes(b"partial")

        def GetErrorCode(self):
            return vtkErrorCode.OutOfDiskSpaceError

        def GetFileName(self):
            return str(tmp_path / "x.vti")

        def GetClassName(self):
            return "vtkXMLImageDataWriter"

    with pytest.raises(OSError) as caught:
        writers.run_writer(Writer(), tmp_path / "x.vti")
    assert caught.value.errno == errno.ENOSPC


# --- signals while writing -------------------------------------------------------------------------
#: Runs the CLI and, once every output file is written in its staging directory, says so
#: on stdout and waits for the test's signal.
STAGED_THEN_WAIT = textwrap.dedent("""
    import sys, time
    import vtkillum.io.writers as writers
    real = writers.file_mode
    def file_mode(path):
        print("staged", flush=True)
        time.sleep(60)
        return real(path)
    writers.file_mode = file_mode
    from vtkillum.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def default_sighup() -> None:
    """In the child: SIGHUP as a terminal gives it, even when the tests run under
    ``nohup`` (which ignores it, and an ignored SIGHUP stays ignored: tested below)."""
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def signal_while_writing(directory: Path, name: str, signum: int):
    """Run the command writing ``name`` and send ``signum`` once the files are staged."""
    process = subprocess.Popen([sys.executable, "-c", STAGED_THEN_WAIT,
                                *write_command(directory, name)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               cwd=ROOT, preexec_fn=default_sighup)
    try:
        line = process.stdout.readline()
        assert line.strip() == "staged", (line, process.stderr.read() if not line else "")
        staging = [n for n in os.listdir(directory) if n.startswith(".")]
        assert staging  # the staged files exist now, hidden next to the output
        process.send_signal(signum)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    return process.returncode, err


@pytest.mark.parametrize("name,signum", [
    *((name, signal.SIGTERM) for name in sorted({**RENDER_FORMATS, **EXPORT_FORMATS,
                                                 "s.json": 0})),
    ("a.npy", signal.SIGHUP), ("ct.mhd", signal.SIGHUP),
])
def test_sigterm_or_sighup_while_writing_leaves_the_old_output_and_nothing_hidden(
        tmp_path, name, signum):
    """Was: the old output kept, but a hidden .tmp/.raw left behind."""
    for file in expected_files(name):
        (tmp_path / file).write_text(f"old {file}")
    status, err = signal_while_writing(tmp_path, name, signum)
    assert status == 128 + signum, err  # the conventional status: 143, 129
    assert f"terminated ({signal.Signals(signum).name})" in err
    assert listing(tmp_path) == expected_files(name)
    for file in expected_files(name):
        assert (tmp_path / file).read_text() == f"old {file}"


def test_an_ignored_sighup_stays_ignored_while_writing(tmp_path):
    """``nohup vtkillum ...``: SIGHUP is ignored, and the write goes on to the end."""
    process = subprocess.Popen(
        [sys.executable, "-c", "import signal; signal.signal(signal.SIGHUP, signal.SIG_IGN)\n"
         + STAGED_THEN_WAIT.replace("time.sleep(60)", "time.sleep(2)"),
         *write_command(tmp_path, "a.png")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    assert process.stdout.readline().strip() == "staged"
    process.send_signal(signal.SIGHUP)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert listing(tmp_path) == ["a.png"]


# --- signals during a path render ------------------------------------------------------------------
#: A path render that says after each pass how many are done (and slows down, so that the
#: test's signal arrives during the render).
PATH_PASSES = textwrap.dedent("""
    import os, sys, time
    from vtkillum.core import pathtrace
    real = pathtrace.PathTracer.run
    pause = float(os.environ.get("PASS_PAUSE", "0.2"))
    def run(self, passes=1):
        real(self, passes)
        print(f"pass {self.passes}", flush=True)
        time.sleep(pause)
        return self
    pathtrace.PathTracer.run = run
    from vtkillum.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def path_render(output: Path, signals: list[int], after: int = 3, pause: float = 0.2,
                gap: float = 0.0):
    """Start a long path render (``pause`` s after each pass), send ``signals`` after
    ``after`` passes, ``gap`` s apart."""
    import os
    import time

    process = subprocess.Popen(
        [sys.executable, "-c", PATH_PASSES, "render", "builtin:ct:16", "-m", "path", "--spp",
         "100000", "--size", "12", "10", "--device", "cpu", "-o", str(output)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env={**os.environ, "PASS_PAUSE": str(pause)}, preexec_fn=default_sighup)
    try:
        while True:
            line = process.stdout.readline()
            assert line, process.stderr.read()
            if line.strip() == f"pass {after}":
                break
        for k, signum in enumerate(signals):
            if k and gap:
                time.sleep(gap)
            process.send_signal(signum)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    return process.returncode, err


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_during_a_path_render_writes_the_samples_taken(tmp_path, signum):
    """Was: SIGTERM (``timeout``, batch schedulers) discarded every sample, while SIGINT
    wrote the partial image."""
    out = tmp_path / "p.npz"
    status, err = path_render(out, [signum])
    assert status == 128 + signum, err
    assert f"terminated ({signal.Signals(signum).name}): wrote" in err
    done = int(err.split(" of 100000 samples per pixel")[0].split()[-1])
    assert 3 <= done < 100000
    with np.load(out) as f:
        assert f["radiance"].shape == (10, 12, 3) and np.isfinite(f["radiance"]).all()
        assert f["alpha"].max() > 0
    assert listing(tmp_path) == ["p.npz"]


def test_a_second_sigterm_stops_the_path_render_at_once(tmp_path):
    (tmp_path / "p.png").write_text("old")
    # Two signals sent back to back can reach a process that was not scheduled in between
    # as one (a pending signal is not queued twice): the second goes 0.3 s after the first,
    # while the pass under way still pauses (3 s), so it is a second signal within that pass.
    status, err = path_render(tmp_path / "p.png", [signal.SIGTERM, signal.SIGTERM],
                              pause=3.0, gap=0.3)
    assert status == 143, err
    assert "terminated (SIGTERM)" in err
    assert (tmp_path / "p.png").read_text() == "old"
    assert listing(tmp_path) == ["p.png"]


def test_path_render_restores_the_signal_handlers(tmp_path, capsys):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    assert main(["render", "builtin:ct:16", "-m", "path", "--spp", "2", "--size", "6", "6",
                 "--device", "cpu", "-q", "-o", str(tmp_path / "p.npz")]) == 0
    assert {s: signal.getsignal(s) for s in before} == before


# --- the scene file is read once ------------------------------------------------------------------
def test_a_scene_from_a_pipe_renders_as_the_same_file(tmp_path, capsys):
    """Was: ``--scene /dev/stdin`` read twice, the second read empty, and the render of a
    volume file silently used the default transfer function, camera and lights."""
    assert main(["export", "builtin:ct:16", "-o", str(tmp_path / "ct.nii.gz")]) == 0
    assert main(["scene", "--dataset", str(tmp_path / "ct.nii.gz"),
                 "-o", str(tmp_path / "s.json")]) == 0
    scene = json.loads((tmp_path / "s.json").read_text())
    scene["transfer_function"]["opacity"] = [min(1.0, 3 * a + 0.05)
                                             for a in scene["transfer_function"]["opacity"]]
    scene["camera"]["view_angle"] = 12.0
    scene["lights"] = [{"type": "directional", "direction": [0.3, 0.2, -1.0],
                        "irradiance": [3.0, 1.0, 0.5]}]
    scene["background"] = [0.25, 0.0, 0.0]
    text = json.dumps(scene)
    (tmp_path / "s.json").write_text(text)
    common = ["render", str(tmp_path / "ct.nii.gz"), "-m", "single", "--size", "16", "12",
              "--device", "cpu", "-q"]
    assert main(common + ["--scene", str(tmp_path / "s.json"), "-o",
                          str(tmp_path / "file.npz")]) == 0
    done = subprocess.run([sys.executable, "-m", "vtkillum.cli", *common, "--scene",
                           "/dev/stdin", "-o", str(tmp_path / "pipe.npz")],
                          input=text, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    with np.load(tmp_path / "file.npz") as a, np.load(tmp_path / "pipe.npz") as b:
        np.testing.assert_array_equal(b["background"], [0.25, 0.0, 0.0])
        np.testing.assert_array_equal(b["radiance"], a["radiance"])
        np.testing.assert_array_equal(b["alpha"], a["alpha"])


def test_the_scene_file_is_opened_once(tmp_path, capsys, monkeypatch):
    assert main(["export", "builtin:ct:16", "-o", str(tmp_path / "ct.vti")]) == 0
    (tmp_path / "s.json").write_text(json.dumps({"albedo": 0.5}))
    reads = []
    real = Path.read_text

    def read_text(self, *args, **kwargs):
        if self.name == "s.json":
            reads.append(self)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", read_text)
    status, _, err = run(capsys, "render", tmp_path / "ct.vti", "--scene", tmp_path / "s.json",
                         "-m", "emission", "--size", 8, 8, "--device", "cpu", "-q",
                         "-o", tmp_path / "a.png")
    assert status == 0, err
    assert len(reads) == 1


# --- bounded JSON, numbers and messages ------------------------------------------------------------
def one_error_line(status, err, *fragments, limit=700):
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vtkillum: error: "), err[:2000]
    assert len(lines[0]) <= limit, lines[0][:400]
    assert "Traceback" not in err and "RecursionError" not in err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.mark.parametrize("text", [
    "[" * 5000 + "]" * 5000,
    '{"lights": ' + "[" * 3000 + "]" * 3000 + "}",
    '{"camera": {"position": ' + "[" * 3000 + "]" * 3000 + "}}",
])
def test_deeply_nested_scene_json_is_one_line(tmp_path, capsys, text):
    """Was: a RecursionError traceback."""
    (tmp_path / "s.json").write_text(text)
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", tmp_path / "s.json",
                         "-o", tmp_path / "a.png", "--size", 8, 8)
    one_error_line(status, err, "s.json", "nested more than", "line 1")


def test_deeply_nested_option_is_one_line(tmp_path, capsys):
    status, _, err = run(capsys, "render", "builtin:ct:16", "--option",
                         "step_size=" + "[" * 3000 + "]" * 3000, "-o", tmp_path / "a.png")
    one_error_line(status, err, "--option 'step_size'", "nested more than")


@pytest.mark.parametrize("field", ['"albedo": {}', '"path": {{"spp": {}}}',
                                   '"lights": [{{"type": "directional", "direction": [0, {}, 1]}}]'])
@pytest.mark.parametrize("digits", [400, 5000])
def test_huge_integers_in_a_scene_are_one_clear_line(tmp_path, capsys, field, digits):
    """Was: Python's int-conversion message (5000 digits) or a numpy ufunc message (spp of
    400 digits)."""
    (tmp_path / "s.json").write_text("{" + field.format("7" * digits) + "}")
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", tmp_path / "s.json",
                         "-o", tmp_path / "a.png", "--size", 8, 8)
    one_error_line(status, err, f"an integer of {digits} digits", "at most 30 digits")
    assert "sys.set_int_max_str_digits" not in err and "ufunc" not in err


def test_large_integers_within_the_bound_give_the_field_s_message(tmp_path, capsys):
    (tmp_path / "s.json").write_text('{"path": {"spp": ' + "9" * 25 + "}}")
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", tmp_path / "s.json",
                         "-o", tmp_path / "a.png", "--size", 8, 8)
    one_error_line(status, err, "path.spp must be a positive integer below 2**63")
    # Was: a numpy ufunc message (np.isfinite of an integer beyond 64 bits).
    (tmp_path / "s.json").write_text('{"opacity_unit_distance": ' + "9" * 25 + "}")
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", tmp_path / "s.json",
                         "-m", "emission", "-o", tmp_path / "a.png", "--size", 8, 8, "-q",
                         "--device", "cpu")
    assert status == 0, err


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_nan_in_a_scene_transfer_function_is_refused(tmp_path, capsys, constant):
    (tmp_path / "s.json").write_text(
        '{"transfer_function": {"scalars": [0, 1], "opacity": [0, %s]}}' % constant)
    status, _, err = run(capsys, "render", "builtin:ct:16", "--scene", tmp_path / "s.json",
                         "-o", tmp_path / "a.png", "--size", 8, 8)
    one_error_line(status, err, "s.json", constant, "line 1, column")


@pytest.mark.parametrize("argv", [
    ["--size", "8", "1" * 5000], ["-m", "path", "--spp", "1" * 400],
    ["--option", "seed=" + "1" * 5000],
])
def test_huge_integer_arguments_are_one_clear_line(tmp_path, capsys, argv):
    status, _, err = run(capsys, "render", "builtin:ct:16", "-o", tmp_path / "a.png", *argv)
    one_error_line(status, err, "at most 30 digits")
    assert "sys.set_int_max_str_digits" not in err


def test_a_huge_component_is_one_clear_line(tmp_path, capsys):
    assert main(["export", "builtin:ct:16", "-o", str(tmp_path / "ct.vti")]) == 0
    status, _, err = run(capsys, "render", tmp_path / "ct.vti", "--component", "1" * 5000,
                         "-o", tmp_path / "a.png")
    one_error_line(status, err, "--component")


@pytest.mark.parametrize("where", ["scene key", "method section key", "light type", "option"])
def test_a_100_kb_value_is_cut_in_the_error_line(tmp_path, capsys, where):
    """Was: a 100 kB error line."""
    long = "k" * 100_000
    scene = {"scene key": {long: 1}, "method section key": {"path": {long: 1}},
             "light type": {"lights": [{"type": long}]}}.get(where)
    argv = ["render", "builtin:ct:16", "-o", tmp_path / "a.png", "--size", 8, 8]
    if scene is None:
        argv += ["--option", f"{long}=1"]
    else:
        (tmp_path / "s.json").write_text(json.dumps(scene))
        argv += ["--scene", tmp_path / "s.json"]
    status, _, err = run(capsys, *argv)
    one_error_line(status, err, "kkkk", limit=800)
    assert max(len(run_) for run_ in err.split()) <= 320  # no value shown past ~300 characters
