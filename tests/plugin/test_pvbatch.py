"""The ParaView plugin in Debian's ParaView 5.11, driven through pvbatch.

``pvbatch_filters.py`` runs once per session under ``xvfb-run -a pvbatch`` with
only ``warp``, ``vtkillum`` and the ``getargspec`` shim on ParaView's PYTHONPATH
(``paraview_plugin/pvbatch_env.py``) and records screenshots and numbers; the
tests here judge them. Skipped, with the reason, where pvbatch or xvfb-run is
missing.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "paraview_plugin"))
import pvbatch_env


SCRIPT = Path(__file__).with_name("pvbatch_filters.py")
ILLUMINATION = ("vtkIllum Light Transmittance", "vtkIllum Convection-Diffusion Light",
                "vtkIllum Ambient Extinction", "vtkIllum Photon Density", "vtkIllum Many Lights")
#: Least mean change (of 255) of the picture when the light moves to the other side; the
#: ambient radiance cache spreads the light over its sphere, so it changes least.
LIGHT_CHANGE = {"vtkIllum Ambient Extinction": 0.3}


@pytest.fixture(scope="module")
def run(pvbatch_summary):
    """Run the pvbatch script once; returns (output directory, summary)."""
    return pvbatch_summary(SCRIPT, "pvbatch", timeout=300)[:2]


def image(out, name) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(out / name).convert("RGB")).astype(np.float64)


def test_paraview_version(run):
    _, summary = run
    assert summary["paraview"] >= [5, 11]


def test_every_library_filter_has_a_plugin_entry(run):
    _, summary = run
    assert summary["library_filters"], "no illumination filters found in vtkillum.filters"
    assert summary["library_filters_covered"] == summary["library_filters"]
    assert {"OpticalProperties", "LightTransmittance", "ConvectionDiffusionLight",
            "AmbientExtinction"} <= set(summary["plugin_classes"])


def test_filters_default_to_a_volume_that_is_not_blank(run):
    out, summary = run
    for label, record in summary["filters"].items():
        assert record["representation"].strip("'") == "Volume", label
        shot = image(out, record["screenshots"][0])
        covered = (shot.max(axis=-1) > 20).mean()  # the background is black
        assert 0.02 < covered < 0.6, f"{label}: {covered:.3f} of the image shows the volume"
        assert shot.std() > 5.0, label


def test_illumination_filters_output_rgba_and_fluence(run):
    _, summary = run
    for label in ILLUMINATION[:2]:
        arrays = summary["filters"][label]["arrays"]
        assert {"illuminated_rgba", "fluence", "transmittance", "scattered_fluence",
                "density"} <= set(arrays)
    arrays = summary["filters"]["vtkIllum Ambient Extinction"]["arrays"]
    assert {"illuminated_rgba", "ambient_extinction", "ambient_radiance"} <= set(arrays)
    assert "sigma_t" in summary["filters"]["vtkIllum Optical Properties"]["arrays"]


def test_moving_the_light_changes_illuminated_images_only(run):
    out, summary = run
    for label, record in summary["filters"].items():
        a, b = (image(out, name) for name in record["screenshots"])
        change = np.abs(a - b).mean()
        if label in ILLUMINATION:
            least = LIGHT_CHANGE.get(label, 1.0)
            assert change > least, f"{label}: moving the light changed the image by {change:.2f}"
        else:  # the control: optical properties do not depend on the light
            assert change == 0.0, label


def test_rgba_volume_matches_paraviews_own_rendering(run):
    """Unshadowed RGBA at exposure 4 pi composites exactly like the transfer function.

    This checks the RGBA convention end to end in ParaView: colour, raw component
    lookup with the declared nominal range, and the opacity unit distance encoded
    in the display's opacity function.
    """
    out, _ = run
    plain = image(out, "plain_volume.png")
    assert (plain.max(axis=-1) > 20).mean() > 0.02
    for kind in ("uint8", "float32"):
        difference = np.abs(image(out, f"rgba_{kind}.png") - plain).mean()
        assert difference < 2.0, f"{kind}: mean difference {difference:.2f} / 255"


def test_time_series_animation_and_cache(run):
    out, summary = run
    series = summary["series"]
    assert series["times"] == [0.0, 0.5, 1.0]
    first, replay = series["passes"]
    for step in first + replay:
        assert step["data_time"] == pytest.approx(step["time"])
    shots = [image(out, step["screenshot"]) for step in first]
    for a, b in zip(shots[:-1], shots[1:]):
        assert np.abs(a - b).mean() > 1.0, "consecutive time steps look the same"
    for step, again in zip(first, replay):
        assert np.array_equal(image(out, step["screenshot"]), image(out, again["screenshot"]))
    # Every step computed once, then served from the per-time-step cache.
    assert [s["misses"] for s in first] == [1, 2, 3]
    assert [s["hits"] for s in replay] == [1, 2, 3]
    assert [s["misses"] for s in replay] == [3, 3, 3]


def test_segment_planes_property(run):
    """Light Transmittance's advanced SegmentPlanes: 16 (chained segments) by default; 4
    planes change the exact grid a little (a blur at shadow edges); back to 0 gives the
    exact arrays again."""
    _, summary = run
    record = summary["segment_planes"]
    assert record["default"] == 16
    assert 0 < record["mean_change"] < 0.05 and record["max_change"] < 0.5
    assert record["back_to_exact"] == 0.0


def test_view_recovers_after_a_bad_value(run):
    """A bad property value is an error naming the property; corrected, and with the light
    moved to the other side, the view shows the new illumination (a failed request once
    left ParaView's representation on its last data for good)."""
    out, summary = run
    record = summary["segment_planes"]
    assert "SegmentPlanes must be >= 0" in record["bad_value_error"]
    before, after = (image(out, name) for name in record["recover_screenshots"])
    assert np.abs(before - after).mean() > 1.0


def test_cache_statistics_information_property(run):
    _, summary = run
    for label, record in summary["filters"].items():
        hits, misses, entries, megabytes = record["cache_property"]
        cache = record["cache"]
        assert (hits, misses, entries) == (cache["hits"], cache["misses"], cache["entries"]), label
        assert megabytes == pytest.approx(cache["bytes"] / 2**20), label
        assert record["cache_attribute"] == record["cache_property"], label


def _picture(record) -> np.ndarray:
    return np.asarray(record["rgb"], dtype=np.float64).reshape(record["dims"][1],
                                                               record["dims"][0], 3)


def test_refraction_render_is_a_picture_that_follows_eta_and_the_colour_map(run):
    """vtkIllum Refraction Render on a stemmed glass ("beer"): the tables set in pvbatch,
    the view's camera copied in; eta = 1 and a colour-map edit change the picture."""
    out, summary = run
    record = summary["refraction"]
    assert record["camera"]["position"] == pytest.approx(record["expected_camera"]["position"])
    assert record["camera"]["view_angle"] == pytest.approx(24.0)
    beer = record["beer"]
    assert beer["dims"] == [64, 72, 1]
    assert beer["active"] == "refraction_rgb"
    assert {"radiance", "alpha"} <= set(beer["arrays"])
    picture = _picture(beer)
    assert picture.std() > 20.0 and (picture.max(axis=-1) > 30).mean() > 0.3  # not blank
    straight = _picture(record["eta_one"])
    assert np.abs(picture - straight).mean() > 5.0, "eta = 1 did not change the picture"
    assert record["lookup_table_is_the_density_colour_map"]
    assert record["recomputed_after_colour_edit"] == 1
    assert np.abs(_picture(record["after_colour_edit"]) - straight).mean() > 5.0
    # Shown as a picture: a slice coloured directly by its RGB.
    assert record["representation"].strip("'") == "Slice"
    assert record["map_scalars"] == 0
    assert record["color_array"] == ["POINTS", "refraction_rgb"]
    # Shown the GUI's way (Show, then the used scalar bars shown): the same, no scalar bar.
    gui = record["gui_like"]
    assert gui["representation"].strip("'") == "Slice" and gui["map_scalars"] == 0
    assert gui["scalar_bar"] == 0
    shot = image(out, "refraction_beer.png")
    assert shot.std() > 20.0
    assert np.abs(shot - image(out, "refraction_eta_one.png")).mean() > 3.0


def test_refraction_render_bad_eta_names_the_property_and_gives_no_picture(run):
    _, summary = run
    record = summary["refraction"]
    assert record["bad_eta"] is None
    assert record["bad_eta_error"].startswith(
        "RefractiveIndex: eta must be > 0 at every control point")
    assert "value 1 has eta -1.5" in record["bad_eta_error"]
    assert record["fixed"]


def test_shim_environment_exposes_only_warp_and_vtkillum(tmp_path):
    shim = pvbatch_env.make_shim_dir(tmp_path / "shim")
    assert sorted(p.name for p in shim.iterdir()) == ["sitecustomize.py", "vtkillum", "warp"]
    env = pvbatch_env.pvbatch_environment(shim, {"PYTHONPATH": "/venv/site-packages",
                                                 "VIRTUAL_ENV": "/venv", "PATH": "/usr/bin"})
    assert env["PYTHONPATH"] == str(shim) and "VIRTUAL_ENV" not in env
    # Debian's Python (ParaView's) imports warp through the shim.
    python = Path("/usr/bin/python3")
    if python.exists():
        proc = subprocess.run([str(python), "-c", "import warp, numpy, inspect; "
                               "print(warp.__version__, numpy.__version__, "
                               "hasattr(inspect, 'getargspec'))"],
                              env=env, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert proc.stdout.split()[-1] == "True"  # sitecustomize ran
