"""Inputs the core refuses clearly (issue 33): bounded scene JSON, scene files read once,
NaN/inf and masked values in transfer functions, numpy masked arrays as volumes."""

from __future__ import annotations

import json
import os
import threading

import numpy as np
import pytest

from vtkillum.core.scene import (
    MAX_JSON_DEPTH,
    JSONLimitError,
    Scene,
    load_scene,
    parse_json,
    read_scene_data,
    shorten_message,
)
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume


# --- bounded JSON ---------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["[" * 5000 + "]" * 5000, '{"a": ' + "{\"b\": " * 3000 + "1"
                                  + "}" * 3001])
def test_deep_json_is_refused_before_parsing(text):
    """Was: RecursionError from the json module."""
    with pytest.raises(JSONLimitError, match=f"nested more than {MAX_JSON_DEPTH} levels"):
        parse_json(text, "s.json")


def test_nesting_within_the_bound_and_brackets_in_strings_are_fine():
    text = "[" * MAX_JSON_DEPTH + "]" * MAX_JSON_DEPTH
    assert parse_json(text) == json.loads(text)
    assert parse_json('{"a": "[[[[{{{{' + "[" * 500 + '", "b": "\\"]]"}') == {
        "a": "[[[[{{{{" + "[" * 500, "b": '"]]'}


@pytest.mark.parametrize("digits", [31, 400, 5000])
def test_long_integers_are_refused_before_conversion(digits):
    """Was: Python's "Exceeds the limit (4300 digits) for integer string conversion"."""
    text = '{"albedo": 0.5,\n "seed": -' + "9" * digits + "}"
    with pytest.raises(JSONLimitError) as caught:
        parse_json(text, "s.json")
    message = str(caught.value)
    assert f"an integer of {digits} digits" in message and "line 2, column 10" in message
    assert len(message) < 200 and "set_int_max_str_digits" not in message


def test_integers_up_to_the_bound_parse():
    assert parse_json("[" + "9" * 30 + "]") == [int("9" * 30)]


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e400", "-2.5E+999"])
def test_non_finite_numbers_are_refused(literal):
    with pytest.raises(JSONLimitError, match="line 1"):
        parse_json('{"opacity": [0, %s]}' % literal, "s.json")


def test_very_long_number_literals_are_refused():
    with pytest.raises(JSONLimitError, match="a number of 205 characters"):
        parse_json("[0." + "1" * 203 + "]")


def test_invalid_json_is_still_a_decode_error():
    with pytest.raises(json.JSONDecodeError):
        parse_json('{"a": }')


# --- scene values beyond 64 bits, deep Python values, long messages ----------------------------
def test_integers_beyond_64_bits_give_the_field_s_message():
    """Was: numpy's "ufunc 'isfinite' not supported for the input types"."""
    with pytest.raises(ValueError, match=r"path.spp must be a positive integer below 2\*\*63"):
        Scene.from_dict({"path": {"spp": 10**25}})
    with pytest.raises(ValueError, match="albedo must lie in"):
        Scene.from_dict({"albedo": 10**25})
    scene = Scene.from_dict({"opacity_unit_distance": 10**25, "step_size": 10**20})
    assert scene.opacity_unit_distance == 1e25 and scene.step_size == 1e20


def test_deeply_nested_light_values_from_python_are_a_value_error():
    deep = [0.0]
    for _ in range(5000):
        deep = [deep]
    with pytest.raises(ValueError, match=r"lights\[0\].direction"):
        Scene.from_dict({"lights": [{"type": "directional", "direction": deep}]})


def test_a_100_kb_key_is_cut_in_the_message(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"k" * 100_000: 1, "path": {"q" * 100_000: 1}}))
    with pytest.raises(ValueError) as caught:
        load_scene(path)
    assert len(str(caught.value)) < 700
    path.write_text(json.dumps({"lights": [{"type": "t" * 100_000}]}))
    with pytest.raises(ValueError) as caught:
        load_scene(path)
    assert len(str(caught.value)) < 1200 and "(100002 characters)" in str(caught.value)


def test_shorten_message_keeps_short_messages_and_cuts_long_runs():
    assert shorten_message("a short message") == "a short message"
    cut = shorten_message("key " + "x" * 5000 + " is unknown")
    assert cut.startswith("key xxx") and cut.endswith("xxx is unknown")
    assert "(5000 characters)" in cut and len(cut) < 400


# --- a scene file is read once ------------------------------------------------------------------
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_a_scene_from_a_named_pipe_is_read_once(tmp_path):
    fifo = tmp_path / "scene.fifo"
    os.mkfifo(fifo)
    text = json.dumps({"albedo": 0.25, "background": [0.5, 0.0, 0.0]})

    def feed():
        with open(fifo, "w") as f:
            f.write(text)

    writer = threading.Thread(target=feed)
    writer.start()
    data = read_scene_data(fifo)
    writer.join(timeout=10)
    assert data == json.loads(text)
    writer = threading.Thread(target=feed)
    writer.start()
    scene = load_scene(fifo)
    writer.join(timeout=10)
    assert scene.albedo == 0.25 and scene.background.tolist() == [0.5, 0.0, 0.0]


# --- transfer functions -----------------------------------------------------------------------
@pytest.mark.parametrize("field,args", [
    ("scalars", ([0.0, np.nan, 1.0], [0.0, 0.5, 1.0])),
    ("opacity", ([0.0, 0.5, 1.0], [0.0, np.nan, 1.0])),
    ("opacity", ([0.0, 0.5, 1.0], [0.0, 0.5, np.inf])),
    ("colors", ([0.0, 1.0], [0.0, 1.0], [[1, 1, 1], [np.nan, 0, 0]])),
])
def test_nan_in_a_transfer_function_names_the_field_and_control_point(field, args):
    with pytest.raises(ValueError, match=f"transfer_function.{field}: .* at control point"):
        TransferFunction(*args)


def test_nan_in_a_scene_transfer_function_from_python_is_refused():
    with pytest.raises(ValueError, match="transfer_function.opacity"):
        Scene.from_dict({"transfer_function": {"scalars": [0, 1], "opacity": [0, float("nan")]}})


def test_masked_transfer_function_values_are_refused():
    opacity = np.ma.masked_array([0.0, 0.5, 1.0], mask=[False, True, False])
    with pytest.raises(ValueError, match="masked array with 1 masked value"):
        TransferFunction([0.0, 0.5, 1.0], opacity)
    unmasked = np.ma.masked_array([0.0, 0.5, 1.0])  # a mask of nothing: fine
    np.testing.assert_array_equal(TransferFunction([0.0, 0.5, 1.0], unmasked).opacity,
                                  [0.0, 0.5, 1.0])


# --- masked volumes ----------------------------------------------------------------------------
def masked_volume_data(dtype=np.float32):
    data = np.arange(4 * 3 * 2, dtype=dtype).reshape(4, 3, 2) + 10
    mask = np.zeros(data.shape, bool)
    mask[1, 2, 0] = mask[3, 0, 1] = True
    return np.ma.masked_array(data, mask=mask)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16, np.uint8])
def test_masked_samples_raise_by_default(dtype):
    """Was: masked voxels rendered as data, no warning."""
    with pytest.raises(ValueError, match="2 sample\\(s\\) are masked"):
        Volume(masked_volume_data(dtype))


@pytest.mark.parametrize("dtype", [np.float32, np.int16])
def test_masked_samples_are_filled_like_nan(dtype):
    """nan_policy='fill': masked samples take the smallest unmasked value (transparent
    under a transfer function that starts at opacity 0), like NaN."""
    data = masked_volume_data(dtype)
    data.data[1, 2, 0] = 0  # under the mask: a value that must not be used
    before = data.data.copy()
    volume = Volume(data, nan_policy="fill")
    assert volume.scalars[1, 2, 0] == volume.scalars[3, 0, 1] == 10.0
    assert volume.value_range == (10.0, 33.0)
    unmasked = ~np.ma.getmaskarray(data)
    np.testing.assert_array_equal(volume.scalars[unmasked], data.data[unmasked])
    np.testing.assert_array_equal(data.data, before)  # the caller's array is untouched


def test_a_masked_array_without_masked_samples_is_plain_data():
    data = np.ma.masked_array(np.ones((2, 2, 2)), mask=np.ma.nomask)
    assert Volume(data).value_range == (1.0, 1.0)
