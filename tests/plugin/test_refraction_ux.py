"""vtkIllum Refraction Render as a new user meets it in pvpython (``pvbatch_refraction_ux.py``
under Debian's ParaView 5.11) and in the GUI (``gui_show_rendered.py``)."""

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "paraview_plugin"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SCRIPT = Path(__file__).with_name("pvbatch_refraction_ux.py")
GUI_SCRIPT = Path(__file__).with_name("gui_show_rendered.py")


@pytest.fixture(scope="module")
def run(pvbatch_summary):
    return pvbatch_summary(SCRIPT, "ux", timeout=300)


@pytest.mark.parametrize("case, message", [
    ("eta_odd", "vtkIllum Refraction Render: RefractiveIndex takes rows of 2 numbers (Value, "
                "Eta): got 3 numbers, which is not a whole number of rows. The previous value "
                "is kept: 37 1 276 1.3."),
    ("eta_one_number", "RefractiveIndex takes rows of 2 numbers (Value, Eta): got 1 number,"),
    ("medium_short", "vtkIllum Refraction Render: MediumColor takes rows of 4 numbers (Value, "
                     "R, G, B): got 3 numbers"),
    ("lights_nine", "vtkIllum Light Transmittance: Lights takes rows of 8 numbers (Type, X, Y, "
                    "Z, R, G, B, Radius): got 9 numbers"),
])
def test_a_table_value_that_is_not_whole_rows_is_refused_and_nothing_is_lost(run, case,
                                                                              message):
    _, summary, log = run
    record = summary[case]
    assert message in log
    assert record["after"] == record["before"]  # the property keeps its value
    assert record["rows_after"] == record["rows_before"]  # and so does the filter
    assert not record["filter_modified"]  # nothing executes again
    assert "Traceback" not in log


def test_good_table_values_still_go_in(run):
    _, summary, _ = run
    assert summary["eta_good"] == [[37.0, 1.0], [276.0, 1.5]]
    assert summary["eta_empty"] == []


def test_the_picture_faces_its_camera_in_the_3d_view(run):
    """Shown as Apply shows it (in the 3D view beside its input): a slice coloured by its
    RGB, on the plane through the focal point that faces the camera it was rendered from,
    about the data's size (not 48 x 40 world units in the xy plane at the origin)."""
    out, summary, _ = run
    shown = summary["shown"]
    assert shown["error"] is None
    assert shown["representation"] == "Slice" and shown["map_scalars"] == 0
    assert shown["place_facing_camera"] == 1
    direction = np.asarray(shown["view_direction"]) / np.linalg.norm(shown["view_direction"])
    assert np.dot(shown["normal"], -direction) == pytest.approx(1.0, abs=1e-6)
    assert np.dot(shown["up"], shown["view_up"]) > 0.5
    bounds = np.asarray(shown["bounds"]).reshape(3, 2)
    data = np.asarray(shown["data_bounds"]).reshape(3, 2)
    assert np.allclose(bounds.mean(axis=1), data.mean(axis=1), atol=1e-6)  # the focal point
    size = np.linalg.norm(bounds[:, 1] - bounds[:, 0]) / np.linalg.norm(data[:, 1] - data[:, 0])
    assert 0.5 < size < 4.0, size
    from PIL import Image

    shot = np.asarray(Image.open(out / "picture_in_3d_view.png").convert("RGB"), dtype=float)
    assert shot.std() > 10.0


def test_show_rendered_reuses_the_active_render_view_and_looks_at_the_picture(run):
    _, summary, _ = run
    record = summary["show_rendered"]
    assert record["views_after"] == record["views_before"] and record["same_view"]
    assert record["representation"] == "Slice" and record["map_scalars"] == 0
    assert record["input_visible"] == 0 and record["interaction_mode"] == "2D"
    direction = np.asarray(record["camera_direction"])
    normal = np.asarray(summary["shown"]["normal"])
    assert np.dot(direction / np.linalg.norm(direction), -normal) == pytest.approx(1.0, abs=1e-6)
    assert summary["picture_std"] > 5.0


@pytest.fixture(scope="module")
def gui(tmp_path_factory):
    import shutil

    if shutil.which("paraview") is None:
        pytest.skip("paraview not found: the GUI test needs Debian's ParaView")
    from test_gui import run_gui

    out = tmp_path_factory.mktemp("gui_show_rendered")
    shim = tmp_path_factory.mktemp("pvshim")
    for attempt in range(2):
        status, log = run_gui(out, shim, timeout=180, script=GUI_SCRIPT, test_script=None)
        if "bad X server connection" not in log and "cannot open display" not in log.lower():
            break
    (out / "paraview.log").write_text(log)
    return out, status, log


def test_show_rendered_without_a_view_after_a_screenshot_in_the_gui(gui):
    """In the GUI, after SaveScreenshot: ShowRendered(f) returns at once, in the active
    view (no new view, no layout change), and ParaView exits cleanly."""
    from test_gui import finished_summary

    out, _status, log = gui
    summary = finished_summary(*gui)
    record = summary["show_rendered"]
    assert record["views_after"] == record["views_before"] and record["same_view"]
    assert record["representation"] == "Slice" and record["map_scalars"] == 0
    assert record["seconds"] < 60.0
    from PIL import Image

    after = np.asarray(Image.open(out / "after.png").convert("RGB"), dtype=float)
    assert after.std() > 10.0
    assert "Traceback" not in log
