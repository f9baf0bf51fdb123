"""Set up the environment in which Debian's ParaView 5.11 can load the vtkillum plugin.

ParaView ships its own Python 3.11, numpy 1.24 and VTK 9.2. Putting a virtual
environment's ``site-packages`` on its ``PYTHONPATH`` makes it import a second
VTK and crash, so only what the plugin needs is exposed: a *shim directory*
holding symbolic links to

* the ``warp`` package of the Python that runs this module (warp-lang wheels
  are pure Python plus a ``ctypes``-loaded library, so they work with
  ParaView's Python and numpy 1.24),
* the ``vtkillum`` package of this checkout,
* ``sitecustomize.py`` from this directory (restores ``inspect.getargspec``
  for ParaView 5.11's plugin loader under Python 3.11),

and nothing else. Run it from the project's virtual environment::

    python paraview_plugin/pvbatch_env.py                 # prints export lines
    eval "$(python paraview_plugin/pvbatch_env.py)"       # then:
    xvfb-run -a pvbatch my_script.py                       # or: paraview
    python paraview_plugin/pvbatch_env.py --run my_script.py arg ...

The functions below do the same for tests and examples.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: The ParaView plugin file to pass to ``LoadPlugin``.
PLUGIN_FILE = HERE / "vtkillum_plugin.py"
REPO_ROOT = HERE.parent

#: Environment variables that point ParaView's Python at the virtual environment.
_VENV_VARIABLES = ("PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP", "PYTHONUSERBASE")


def package_dir(name: str) -> Path:
    """Directory of an importable package of *this* Python (without importing it)."""
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(
            f"package {name!r} is not installed in {sys.executable}; run this from the "
            "vtkillum virtual environment (source .venv/bin/activate)"
        )
    return Path(list(spec.submodule_search_locations)[0]).resolve()


def make_shim_dir(path=None) -> Path:
    """Create (or refresh) the shim directory and return it.

    Parameters
    ----------
    path : path-like, optional
        Where to create it; default ``$XDG_CACHE_HOME/vtkillum/pvshim`` (``~/.cache/...``).
        Existing links in it are replaced.
    """
    if path is None:
        cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        path = cache / "vtkillum" / "pvshim"
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    links = {
        "warp": package_dir("warp"),
        "vtkillum": REPO_ROOT / "vtkillum",
        "sitecustomize.py": HERE / "sitecustomize.py",
    }
    for name, target in links.items():
        link = path / name
        if link.is_symlink() or link.is_file():
            link.unlink()
        elif link.is_dir():
            shutil.rmtree(link)
        link.symlink_to(target)
    return path


def pvbatch_environment(shim_dir, base=None) -> dict:
    """Environment for ``pvbatch``/``pvpython``/``paraview``: only ``shim_dir`` on PYTHONPATH.

    Parameters
    ----------
    shim_dir : path-like
        From :func:`make_shim_dir`.
    base : mapping, optional
        Environment to start from (default ``os.environ``); variables that would point
        ParaView's Python at a virtual environment are removed.
    """
    env = dict(os.environ if base is None else base)
    for key in _VENV_VARIABLES:
        env.pop(key, None)
    env["PYTHONPATH"] = str(Path(shim_dir))
    # Headless rendering inside pvbatch goes through the X server of xvfb-run.
    env.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
    return env


def missing_tools() -> list[str]:
    """Names of the programs needed to run pvbatch headless that are not on PATH."""
    return [tool for tool in ("pvbatch", "xvfb-run") if shutil.which(tool) is None]


def pvbatch_command(script, *args, ranks: int = 1) -> list[str]:
    """``xvfb-run -a pvbatch script args...`` (ParaView 5.11 needs an X server); with
    ``ranks`` > 1 pvbatch runs under ``mpirun -np ranks`` (ParaView's MPI engine), without
    ParaView's X display test."""
    xvfb = xvfb_command()
    if ranks > 1:
        mpi = ["mpirun", "-np", str(ranks), "--oversubscribe"]
        if os.geteuid() == 0:
            mpi.append("--allow-run-as-root")  # Open MPI refuses root otherwise (CI runs as root)
        # ParaView probes the X server from every rank at once and Xvfb refuses a few per
        # cent of simultaneous connections; one refusal turns remote rendering off on all
        # ranks, and ParaView 5.11's first volume render then never ends. xvfb-run's
        # display is known to work: skip the probe.
        return [*xvfb, *mpi, "pvbatch", "--disable-xdisplay-test", str(script),
                *map(str, args)]
    return [*xvfb, "pvbatch", str(script), *map(str, args)]


def xvfb_command() -> list[str]:
    """``xvfb-run -a -n N``: the search for a free display starts at a number drawn per call.

    ``xvfb-run -a`` alone starts every search at 99, so runs started together can pick the
    same number; the one whose Xvfb lost then draws on the other's, and dies with "bad X
    server connection" when that one ends, even mid-run.
    """
    import random

    return ["xvfb-run", "-a", "-n", str(random.SystemRandom().randrange(100, 900))]


def run_pvbatch(script, *args, shim_dir=None, timeout=None, ranks: int = 1,
                **kwargs) -> subprocess.CompletedProcess:
    """Run ``script`` under ``xvfb-run -a pvbatch`` with the shim environment.

    ``ranks`` > 1 runs it on that many MPI ranks (:func:`pvbatch_command`). Extra keyword
    arguments go to :func:`subprocess.run` (e.g. ``capture_output=True``). Raises
    ``RuntimeError`` naming the missing program when pvbatch or xvfb-run is absent.
    """
    missing = missing_tools() + (["mpirun"] if ranks > 1 and not shutil.which("mpirun") else [])
    if missing:
        raise RuntimeError(
            f"{', '.join(missing)} not found; install Debian's ParaView and xvfb "
            "(apt-get install paraview python3-paraview xvfb)"
        )
    shim = make_shim_dir(shim_dir)
    return _run_group(pvbatch_command(script, *args, ranks=ranks),
                      env=pvbatch_environment(shim), timeout=timeout, **kwargs)


def _run_group(command, timeout=None, capture_output=False, **kwargs):
    """:func:`subprocess.run` in a process group of its own, killed whole on a time-out.

    ``subprocess.run`` kills only ``xvfb-run`` when it times out: pvbatch (and, under MPI,
    every rank) would go on, spinning in an MPI wait, long after the test gave up.
    """
    import signal

    if capture_output:
        kwargs.setdefault("stdout", subprocess.PIPE)
        kwargs.setdefault("stderr", subprocess.PIPE)
    with subprocess.Popen(command, start_new_session=True, **kwargs) as proc:
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired as expired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise subprocess.TimeoutExpired(command, timeout, expired.output,
                                            expired.stderr) from None
    return subprocess.CompletedProcess(command, proc.returncode, stdout, stderr)


#: What an MPI pvbatch script prints (and exits 75) when ParaView found no remote rendering
#: on its ranks: a rank's X connection failed while ParaView probed it. Debian's ParaView
#: 5.11 would then wait forever in the first volume render (rank 0 redistributes the data
#: for ordered compositing, the other ranks do not render), so the scripts end at once.
NO_REMOTE_RENDERING = "vtkillum-tests: remote rendering is not available on the ranks"

#: Output of a run that lost a race for the X server, not a fault of the script: tried again.
X_RACES = ("bad X server connection", NO_REMOTE_RENDERING)


def run_pvbatch_logged(script, *args, shim_dir=None, timeout=None, attempts: int = 2,
                       ranks: int = 1) -> tuple[subprocess.CompletedProcess, str]:
    """:func:`run_pvbatch` with its output captured, tried again (up to ``attempts`` runs;
    on several MPI ranks at least 4) when it lost a race for the X server (:data:`X_RACES`:
    ``xvfb-run -a`` lost the display number, or Xvfb refused a rank's connection, which
    it does for a few per cent of simultaneous connections), or, once, on several MPI
    ranks, when the run timed out; returns the process and its stdout + stderr."""
    if ranks > 1:
        attempts = max(attempts, 4)  # one of 4 ranks misses the X server in ~1 of 5 runs
    timed_out = False
    for attempt in range(max(1, attempts)):
        try:
            proc = run_pvbatch(script, *args, shim_dir=shim_dir, timeout=timeout, ranks=ranks,
                               capture_output=True, text=True)
        except subprocess.TimeoutExpired:
            if ranks > 1 and attempt + 1 < attempts and not timed_out:
                timed_out = True  # once: a second hang is no race
                continue
            raise
        log = proc.stdout + proc.stderr
        if proc.returncode == 0 or not any(race in log for race in X_RACES):
            break
    return proc, log


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shim-dir", help="where to build the shim directory")
    parser.add_argument("--run", nargs=argparse.REMAINDER, metavar="SCRIPT ...",
                        help="run SCRIPT with its arguments under xvfb-run -a pvbatch")
    opts = parser.parse_args(argv)
    if opts.run:
        return run_pvbatch(*opts.run, shim_dir=opts.shim_dir).returncode
    shim = make_shim_dir(opts.shim_dir)
    print(f"export PYTHONPATH={shim}")
    for key in _VENV_VARIABLES:
        print(f"unset {key}")
    print(f"# plugin: LoadPlugin('{PLUGIN_FILE}', ns=globals())")
    return 0


if __name__ == "__main__":
    sys.exit(main())
