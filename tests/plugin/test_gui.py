"""The plugin in the real ParaView GUI (Debian's ParaView 5.11 under xvfb-run).

``gui_session.py`` runs inside ``paraview --script`` and plays the steps a user
takes (see its docstring); this module runs it once and judges what it left:
ParaView must exit with status 0 through its normal shutdown (a crash while the
Properties panel is built gives SIGSEGV, status 139), the script must reach its
end (the marker file), and the pictures must show what they should.
"""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "paraview_plugin"))
import pvbatch_env

MISSING = [tool for tool in ("paraview", "xvfb-run") if __import__("shutil").which(tool) is None]
pytestmark = [
    pytest.mark.plugin,
    pytest.mark.skipif(bool(MISSING), reason=f"{', '.join(MISSING)} not found: the GUI test "
                       "needs Debian's ParaView and xvfb-run"),
]

SCRIPT = Path(__file__).with_name("gui_session.py")
MENU_CLICKS = Path(__file__).with_name("gui_menu.xml")
LABELS = ["vtkIllum Optical Properties", "vtkIllum Light Transmittance",
          "vtkIllum Convection-Diffusion Light", "vtkIllum Ambient Extinction",
          "vtkIllum Photon Density", "vtkIllum Many Lights"]


def run_gui(out: Path, shim: Path, timeout: float = 420.0, script: Path = SCRIPT,
            test_script: Path | None = MENU_CLICKS):
    """Run a GUI session (``script``, and ParaView's test player on ``test_script``);
    returns (exit status, stdout + stderr). On a timeout the whole process group
    (xvfb-run, Xvfb, paraview) is killed and the status is None."""
    env = pvbatch_env.pvbatch_environment(pvbatch_env.make_shim_dir(shim))
    env["VTKILLUM_GUI_OUT"] = str(out)
    env["VTKILLUM_ROOT"] = str(ROOT)
    env["XDG_CONFIG_HOME"] = str(out / "config")  # a fresh ParaView configuration
    env.setdefault("QT_QPA_PLATFORM", "xcb")
    command = ["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24", "paraview", "--dr",
               f"--script={script}"] + ([f"--test-script={test_script}"] if test_script else [])
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        log, _ = proc.communicate(timeout=timeout)
        return proc.returncode, log
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        log, _ = proc.communicate()
        return None, log + f"\n[killed after {timeout} s]"


@pytest.fixture(scope="module")
def gui(tmp_path_factory):
    out = tmp_path_factory.mktemp("gui")
    shim = tmp_path_factory.mktemp("pvshim")
    for attempt in range(2):
        status, log = run_gui(out, shim)
        # xvfb-run -a occasionally loses the race for a display number: try once more.
        if "bad X server connection" not in log and "cannot open display" not in log.lower():
            break
    (out / "paraview.log").write_text(log)
    return out, status, log


def image(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB")).astype(np.float64)


def finished_summary(out: Path, status: int, log: str) -> dict:
    """The summary of a GUI session that ran to its end and exited cleanly (asserted)."""
    progress = (out / "progress.txt").read_text() if (out / "progress.txt").exists() else ""
    assert status == 0, f"ParaView exited with {status}\n{progress}\n{log[-3000:]}"
    assert (out / "done").exists(), f"the GUI script did not reach its end:\n{progress}"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["errors"] == [], summary["errors"]
    return summary


def test_gui_exits_cleanly_after_the_whole_session(gui):
    finished_summary(*gui)


def test_every_filter_is_created_selected_edited_and_shown_as_a_volume(gui):
    out, _, _ = gui
    summary = json.loads((out / "summary.json").read_text())
    assert sorted(summary["filters"]) == sorted(LABELS)
    for label, record in summary["filters"].items():
        assert record["representation"].strip("'") == "Volume", label
    for label in LABELS[1:]:
        assert summary["filters"][label]["albedo_after_edit"] == pytest.approx(0.6)
        # The display colours by the data array: one colour map, the data's.
        assert summary["filters"][label]["color_array"] == ["POINTS", "RTData"], label


def test_state_saved_deleted_and_loaded_again(gui):
    out, _, _ = gui
    summary = json.loads((out / "summary.json").read_text())
    assert summary["after_delete"] == []
    assert len(summary["after_load"]) == len(LABELS) + 1  # and the refraction render
    assert "vtkIllumRefractionRender1" in summary["after_load"]
    assert "vtkIllum" in (out / "session.pvsm").read_text()
    assert summary["illuminated_volumes_after_load"] >= 1  # lit again after the state load


def test_a_wrong_light_names_the_row_and_column_without_a_traceback(gui):
    out, _, log = gui
    summary = json.loads((out / "summary.json").read_text())
    assert summary["bad_light_error"] == \
        "Lights row 1: Type must be 0 (directional) or 1 (point), got 2"
    assert summary["good_light_error"] is None
    assert "Traceback" not in log, log[log.find("Traceback") - 200:][:3000]


def test_window_grabs_show_the_gui(gui):
    out, _, _ = gui
    for name in ("window_refraction.png", "window_filters.png", "window_after_load.png",
                 "window_ct.png"):
        shot = image(out / name)
        assert shot.shape[0] > 400 and shot.shape[1] > 600, name
        assert shot.std() > 20.0, f"{name} looks blank"


def test_editing_the_colour_map_changes_the_illumination_in_the_gui(gui):
    out, _, _ = gui
    summary = json.loads((out / "summary.json").read_text())
    assert summary["illuminated_volumes_in_view"] == 1  # drawn by the plugin, per sample
    assert summary["recomputed_after_colour_edit"] >= 1  # the filter followed the edit
    before = image(out / "view_before_colour_edit.png")
    after = image(out / "view_after_colour_edit.png")
    assert np.abs(after - before).mean() > 5.0
    assert summary["ct"]["color_array"] == ["POINTS", "density"]
    assert summary["ct"]["illuminated_volumes_in_view"] == 1


def test_the_menu_entry_creates_an_illuminated_volume(gui):
    """Filters -> vtkIllum -> vtkIllum Light Transmittance, Apply: clicked by ParaView's
    test player (the path that crashed 5.11, issue 12)."""
    out, _, log = gui
    summary = json.loads((out / "summary.json").read_text())
    assert "Success =  true" in log or "Success = true" in log, log[-2000:]
    assert summary["menu_created"] == "vtkIllum Light Transmittance"
    assert summary["menu_display"]["representation"] == "Volume"
    assert summary["menu_display"]["color_array"] == ["POINTS", "RTData"]
    assert summary["menu_display"]["illuminated_volumes"] == 1


def test_the_refraction_render_menu_entry_renders_a_picture(gui):
    """Filters -> vtkIllum -> vtkIllum Refraction Render, Apply (ParaView's test player):
    an image shown as a picture; the tables and the view's camera set from the script
    change it; no error, no traceback."""
    out, _, log = gui
    summary = json.loads((out / "summary.json").read_text())
    record = summary["refraction"]
    assert record["created"] == "vtkIllum Refraction Render"
    assert record["default_error"] is None
    assert record["default_dims"] == [0, 255, 0, 255, 0, 0]
    assert record["representation"] == "Slice"
    assert record["color_array"] == ["POINTS", "refraction_rgb"] and record["map_scalars"] == 0
    assert record["camera_position"] == pytest.approx([30.0, -50.0, 60.0])
    pictures = record["pictures"]
    assert pictures is not None and pictures["pixels"] == 96 * 80
    assert pictures["straight_std"] > 5.0 and pictures["bent_std"] > 5.0
    assert pictures["difference"] > 2.0, "eta did not change the picture"
    assert "Traceback" not in log
