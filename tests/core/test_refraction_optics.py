"""The refractive optical model (η_tf, m_tf), its scene-file form and the pre-integration tables."""

import numpy as np
import pytest

from vtkillum.core.refraction.optics import RefractiveOptics, split_transfer_function
from vtkillum.core.refraction.preintegration import preintegration_tables, running_integral
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


def test_defaults_are_the_identity():
    optics = RefractiveOptics.identity()
    assert optics.is_identity and optics.eta_constant and optics.medium_white
    assert np.all(optics.kappa(np.linspace(-5, 5, 11), 0.7) == 0.0)  # exactly zero absorption
    assert np.all(optics.eta_at([-1e9, 0.0, 1e9]) == 1.0)


def test_piecewise_linear_and_constant_outside():
    optics = RefractiveOptics([0.0, 2.0], [1.0, 1.5], [1.0, 3.0], [[1, 1, 1], [0.5, 0.25, 1.0]])
    assert optics.eta_at(1.0) == pytest.approx(1.25)
    assert optics.eta_at(-4.0) == 1.0 and optics.eta_at(9.0) == 1.5
    np.testing.assert_allclose(optics.medium_at(2.0), [0.75, 0.625, 1.0])
    # m per unit distance u: a path of length u transmits m.
    u = 0.4
    np.testing.assert_allclose(np.exp(-optics.kappa(3.0, u) * u), [0.5, 0.25, 1.0])
    assert not optics.is_identity


@pytest.mark.parametrize("kw, match", [
    ({"eta_scalars": [0, 1], "eta": [1.0, 0.0]}, "> 0"),
    ({"eta_scalars": [0, 1], "eta": [1.0, -1.5]}, "> 0"),
    ({"eta_scalars": [1, 0], "eta": [1.0, 1.5]}, "increasing"),
    ({"eta_scalars": [0, 1], "eta": [1.0]}, "values"),
    ({"medium_scalars": [0], "medium_color": [[1.2, 1, 1]]}, r"\[0, 1\]"),
    ({"eta_scalars": [0, 1], "eta": [1.0, float("nan")]}, "finite"),
])
def test_bad_optics_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        RefractiveOptics(**kw)


def test_scene_file_forms_round_trip():
    d = {"scalars": [0.0, 1.0, 2.0], "opacity": [0.0, 0.1, 0.2],
         "refractive_index": [1.0, 1.5, 1.33],
         "medium_color": {"scalars": [0.0, 2.0], "colors": [[1, 1, 1], [0.9, 0.5, 0.2]]}}
    rest, optics = split_transfer_function(d)
    assert set(rest) == {"scalars", "opacity"}
    TransferFunction.from_dict(rest)  # what is left is an ordinary transfer function
    assert optics.eta_at(1.0) == pytest.approx(1.5)
    np.testing.assert_allclose(optics.medium_at(1.0), [0.95, 0.75, 0.6])
    again = RefractiveOptics.from_dict(optics.to_dict())
    assert again.key() == optics.key()
    assert split_transfer_function({"scalars": [0], "opacity": [0]})[1] is None


def test_scene_file_errors_name_the_field():
    with pytest.raises(ValueError, match="refractive_index"):
        split_transfer_function({"scalars": [0, 1], "opacity": [0, 0], "refractive_index": [1.0]})
    with pytest.raises(ValueError, match="refractive_index"):
        split_transfer_function({"scalars": [0, 1], "opacity": [0, 0],
                                 "refractive_index": [1.0, -2.0]})
    with pytest.raises(ValueError, match="medium_color.colors"):
        split_transfer_function({"scalars": [0], "opacity": [0],
                                 "medium_color": {"scalars": [0]}})
    with pytest.raises(ValueError, match="medium_color"):
        split_transfer_function({"scalars": [0], "opacity": [0], "medium_color": 3})


def test_running_integral_is_trapezoids():
    """The running integral of a piecewise-linear table (entry units)."""
    v = np.array([0.0, 1.0, 4.0, 2.0])
    integral = running_integral(v)
    assert integral.tolist() == [0.0, 0.5, 3.0, 6.0]


def test_preintegration_tables_cover_both_domains():
    vol = Volume(np.linspace(0, 1, 8).reshape(2, 2, 2))
    tf = TransferFunction([0.0, 1.0], [0.0, 0.5])
    optics = RefractiveOptics([-1.0, 3.0], [1.0, 2.0], [0.0], [[0.5, 1.0, 1.0]])
    t = preintegration_tables(vol, tf, optics, 1.0, size=64)
    assert t["lo"] == -1.0 and t["hi"] == 3.0
    np.testing.assert_allclose(t["extinction"][:, 1], np.log(2.0), rtol=1e-6)
    np.testing.assert_allclose(t["extinction"][:, 2:], 0.0)
    assert t["eta_outside"] == pytest.approx(optics.eta_at(0.5))  # median over the faces


def test_scene_file_carries_the_optics(tmp_path):
    """The scene file's transfer_function holds refractive_index / medium_color; they round-trip
    and reach the refraction method; without them the scene has no optics (η ≡ 1, m white)."""
    from vtkillum.core.scene import Scene, load_scene, save_scene

    d = {"transfer_function": {"scalars": [0.0, 1.0], "opacity": [0.0, 0.1],
                               "refractive_index": [1.0, 1.4],
                               "medium_color": [[1, 1, 1], [0.8, 0.9, 1.0]]}}
    scene = Scene.from_dict(d)
    assert scene.optics.eta_at(1.0) == pytest.approx(1.4)
    save_scene(scene, tmp_path / "s.json")
    again = load_scene(tmp_path / "s.json")
    assert again.optics.key() == scene.optics.key()
    assert again.transfer_function.to_dict() == scene.transfer_function.to_dict()
    assert Scene.from_dict({"transfer_function": {"scalars": [0], "opacity": [0]}}).optics is None
    with pytest.raises(ValueError, match="refractive_index"):
        Scene.from_dict({"transfer_function": {"scalars": [0, 1], "opacity": [0, 0],
                                               "refractive_index": [1.0, 0.0]}})
    with pytest.raises(ValueError, match="RefractiveOptics"):
        Scene(optics="glass")
