"""vtkIllum Many Lights in Debian's ParaView: pvbatch (``pvbatch_many_lights.py``) and the
GUI (``gui_many_lights.py``, the menu clicked by ParaView's test player).

Applying it must not fill the Output Messages with warnings from the transfer-function
links, its virtual-light points must stay hidden until asked for, and a colour-only
edit of the colour map must re-evaluate the virtual lights' powers (eq. 6), not walk
anew. Skipped, with the reason, where pvbatch, paraview or xvfb-run is missing.
"""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "paraview_plugin"))
import pvbatch_env

pytestmark = pytest.mark.plugin

SCRIPT = Path(__file__).with_name("pvbatch_many_lights.py")
#: Kernels of a new walk: light paths, segment depths, frozen densities, shadow maps.
WALK = {"walk_kernel", "segment_depth_kernel", "freeze_kernel", "build_kernel__locals__build"}


@pytest.fixture(scope="module")
def run(pvbatch_summary):
    """(output directory, summary, log) of one pvbatch run."""
    return pvbatch_summary(SCRIPT, "many_lights_pv", timeout=300)


def stages(log: str) -> dict:
    """The log split at the script's ``=== stage`` markers (on stderr, like ParaView's
    warnings)."""
    parts, name = {}, "load"
    for line in log.splitlines():
        if line.startswith("=== "):
            name = line[4:]
            parts[name] = []
            continue
        parts.setdefault(name, []).append(line)
    return parts


def test_applying_and_editing_warn_nothing(run):
    log = run[2]
    assert "end" in stages(log)
    for name, lines in stages(log).items():
        warnings = [line for line in lines if "WARN|" in line or "ERR|" in line
                    or "Failed to locate property" in line
                    or "Could not determine array range" in line]
        assert warnings == [], f"{name}: " + "\n".join(warnings)


def test_virtual_lights_port_hidden_until_shown(run):
    _, summary, _ = run
    assert summary["displays_after_apply"] == [True, False]
    assert summary["virtual_lights_shown"]
    assert summary["virtual_lights_points"] >= 32


def test_colour_edit_reweights_without_a_new_walk(run):
    _, summary, _ = run
    launches = summary["launches"]
    assert WALK <= set(launches["apply"])  # (the counter sees the walk)
    colour = launches["colour"]
    assert colour.get("contribution_kernel") == 1 and colour.get("fluence_kernel", 0) >= 1
    assert not WALK & set(colour) and "transmittance_kernel" not in colour
    assert summary["state_kept_after_colour_edit"]
    ranges = summary["scattered_range"]
    assert ranges["colour"] != ranges["apply"]  # the edit reached the illumination
    assert launches["same colour"] == {}
    assert WALK <= set(launches["opacity"])  # an opacity edit walks anew


# --- the same in the GUI (paraview --script, the menu clicked by ParaView's test player) --------
GUI_MISSING = [tool for tool in ("paraview", "xvfb-run") if shutil.which(tool) is None]


@pytest.fixture(scope="module")
def gui(tmp_path_factory):
    """(summary, log) of one GUI session (``gui_many_lights.py``); fails unless ParaView
    exits with 0 after the script reached its end."""
    if GUI_MISSING:
        pytest.skip(f"{', '.join(GUI_MISSING)} not found: the GUI test needs Debian's ParaView")
    here = Path(__file__).resolve().parent
    out = tmp_path_factory.mktemp("many_lights_gui")
    env = pvbatch_env.pvbatch_environment(
        pvbatch_env.make_shim_dir(tmp_path_factory.mktemp("pvshim")))
    env.update(VTKILLUM_GUI_OUT=str(out), VTKILLUM_ROOT=str(here.parents[1]),
               XDG_CONFIG_HOME=str(out / "config"))  # a fresh ParaView configuration
    env.setdefault("QT_QPA_PLATFORM", "xcb")
    command = ["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24", "paraview", "--dr",
               f"--script={here / 'gui_many_lights.py'}",
               f"--test-script={here / 'gui_many_lights.xml'}"]
    for _ in range(2):  # xvfb-run -a occasionally loses the race for a display number
        proc = subprocess.run(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, timeout=400, check=False)
        if "bad X server connection" not in proc.stdout:
            break
    assert proc.returncode == 0 and (out / "done").exists(), proc.stdout[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["errors"] == [], summary["errors"]
    return summary, proc.stdout


def test_gui_apply_shows_no_warning_and_hides_the_virtual_lights(gui):
    summary, log = gui
    parts = stages(log)
    assert "end" in parts
    for name, lines in parts.items():
        warnings = [line for line in lines if "WARN|" in line or "ERR|" in line
                    or line.startswith("warning:")]
        assert warnings == [], f"{name}: " + "\n".join(warnings)
    assert summary["displays_after_apply"] == [True, False]
    assert summary["virtual_lights_shown"]
    colour = summary["launches"]["colour"]
    assert colour.get("contribution_kernel") == 1 and not WALK & set(colour)
