"""The README runs as written: its code blocks, in order, from a fresh clone, headless.

How the blocks are run (documented in the README's first lines and its "Headless /
servers / GPUs" section):

* ``bash`` blocks run with ``bash -euo pipefail`` and ``python`` blocks with this
  interpreter, all in one temporary directory laid out as the root of a fresh clone
  (links to the repository's tracked top-level files and folders, nothing else: later
  blocks read what earlier ones wrote), with ``VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow``,
  ``PYVISTA_OFF_SCREEN=true`` and no ``DISPLAY``: the snippets end in a screenshot
  (``vtkillum.mappers.window.show``, pyvista's ``show(screenshot=...)``) and open no window.
  ``vtkillum`` is this checkout's command line (``python -m vtkillum.cli``).
* Set-up commands are not run again, the test already runs in that environment: the
  parts of a command chain that create or activate a virtual environment, ``pip install``
  and ``bash .ci/run`` (which runs this test). What they would install must be there:
  ``pip install .`` needs the clone's ``pyproject.toml``.
* ParaView blocks (``LoadPlugin``, ``paraview_plugin/pvbatch_env.py``) need Debian's
  ParaView: the pvpython block runs under pvbatch from a fresh clone of its own (slow;
  also ``tests/plugin``).
* ``json`` blocks must be valid scene files.
* A block must not warn (``vtkillum: warning``: e.g. a scene whose camera is inside the
  data).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

SETUP = re.compile(r"^\s*(python3? -m venv\b|\. \.venv/bin/activate|source \.venv/bin/activate"
                   r"|(python3? -m )?pip install\b|bash \.ci/run\b)")
#: ``pip install PATH`` (a local project, e.g. ``.``) in a set-up command.
PIP_LOCAL = re.compile(r"pip install\s+(?:-e\s+)?((?:\.|/)[^\s\[]*)")
PARAVIEW = ("LoadPlugin(", "pvbatch_env.py", "pvpython", "pvbatch ")

#: What the README's blocks must have written (file -> it is a picture to look at).
OUTPUTS = {"demo.png": True, "head.nii.gz": False, "head.png": True, "head.json": False,
           "head_exposure1.png": True, "plume.png": True, "head.npy": False,
           "head.alpha.npy": False, "vtk.png": True, "head.vti": False, "pyvista.png": True,
           "head_scene.json": False, "head_scene.png": True, "pyvista_computed.png": True}


def blocks(text: str):
    """``(language, code)`` of every fenced block, in order."""
    return [(m.group(1), m.group(2)) for m in
            re.finditer(r"^```(\w*)\n(.*?)^```", text, flags=re.DOTALL | re.MULTILINE)]


def fresh_clone(where: Path) -> Path:
    """``where`` laid out as the root of a fresh clone: links to the repository's tracked
    top-level entries (``git ls-files``; without git, everything but hidden and build
    folders)."""
    where.mkdir()
    try:
        listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.split()
        names = sorted({name.split("/")[0] for name in listed})
    except (OSError, subprocess.CalledProcessError):
        names = sorted(p.name for p in ROOT.iterdir()
                       if not p.name.startswith(".") and not p.name.endswith(".egg-info"))
    for name in names:
        if (ROOT / name).exists():
            (where / name).symlink_to(ROOT / name)
    return where


def runnable_bash(code: str) -> str:
    """The block without its set-up commands (see the module docstring)."""
    lines = []
    for line in code.splitlines():
        parts = [p for p in line.split("&&") if not SETUP.match(p)]
        if parts:
            lines.append("&&".join(parts).strip())
    return "\n".join(lines)


def test_readme_has_no_paths_outside_the_repository():
    text = README.read_text()
    assert "../" not in text
    for target in re.findall(r"\]\(([^)#][^)]*)\)", text):  # markdown links and images
        if "://" not in target:
            assert (ROOT / target).exists(), f"README links to {target}, which does not exist"


def test_readme_blocks_run_as_written(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "vtkillum"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m vtkillum.cli "$@"\n')
    shim.chmod(0o755)
    work = fresh_clone(tmp_path / "clone")
    env = dict(os.environ)
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "VTKILLUM_DEVICE"):
        env.pop(name, None)
    env.update(PATH=f"{bin_dir}{os.pathsep}{env.get('PATH', '')}",
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""),
               VTK_DEFAULT_OPENGL_WINDOW="vtkOSOpenGLRenderWindow",
               PYVISTA_OFF_SCREEN="true", VTKILLUM_CACHE_DIR=str(tmp_path / "cache"))
    ran = 0
    for n, (language, code) in enumerate(blocks(README.read_text())):
        if any(marker in code for marker in PARAVIEW):
            continue
        if language == "json":
            from vtkillum.core.scene import Scene

            Scene.from_dict(json.loads(code))
            continue
        if language == "bash":
            for project in PIP_LOCAL.findall(code):  # what the set-up would install is there
                assert (work / project / "pyproject.toml").exists(), (
                    f"README block {n} runs 'pip install {project}', which needs "
                    f"{project}/pyproject.toml where the README says to run it")
            command = ["bash", "-euo", "pipefail", "-c", runnable_bash(code)]
        elif language == "python":
            script = tmp_path / f"block{n}.py"
            script.write_text(code)
            command = [sys.executable, str(script)]
        else:
            continue
        done = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True,
                              timeout=600, check=False)
        assert done.returncode == 0, (f"README block {n} ({language}) failed:\n{code}\n"
                                      f"--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}")
        for alarming in ("Warp CUDA warning", "bad X server", "Traceback", "vtkillum: warning"):
            assert alarming not in done.stderr, f"block {n} printed {alarming!r}:\n{done.stderr}"
        ran += 1
    assert ran >= 8
    from vtkillum.core.tonemap import read_png

    for name, picture in OUTPUTS.items():
        path = work / name
        assert path.exists() and path.stat().st_size > 0, f"the README did not write {name}"
        if picture:
            rgb = read_png(path).astype(int)
            assert (np.abs(rgb - rgb[0, 0]).max(-1) > 10).mean() > 0.05, f"{name} is blank"


@pytest.mark.parametrize("line, expected", [
    ("python3 -m venv .venv && . .venv/bin/activate && pip install . && vtkillum demo",
     "vtkillum demo"),
    ("bash .ci/run", ""),
    ("vtkillum render a.vti -o b.png", "vtkillum render a.vti -o b.png"),
])
def test_setup_commands_are_left_out(line, expected):
    assert runnable_bash(line) == expected


@pytest.mark.slow
def test_readme_pvpython_block_runs_from_a_fresh_clone(tmp_path):
    """The pvpython block makes its own data: it runs first thing in a fresh clone."""
    import shutil

    if not (shutil.which("pvbatch") and shutil.which("xvfb-run")):
        pytest.skip("needs Debian's ParaView (pvbatch) and xvfb-run")
    sys.path.insert(0, str(ROOT / "paraview_plugin"))
    import pvbatch_env

    (code,) = [c for lang, c in blocks(README.read_text()) if lang == "python"
               and "LoadPlugin(" in c]
    work = fresh_clone(tmp_path / "clone")
    script = tmp_path / "block.py"
    script.write_text(code)
    proc = pvbatch_env.run_pvbatch(script, shim_dir=tmp_path / "shim", timeout=600,
                                   capture_output=True, text=True, cwd=work)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Traceback" not in log, log[-4000:]
    from vtkillum.core.tonemap import read_png

    rgb = read_png(work / "paraview.png").astype(int)
    assert (np.abs(rgb - rgb[0, 0]).max(-1) > 10).mean() > 0.02, "paraview.png is blank"
