"""The photon method's device tables: the same σt and colour as the host's transfer-function
evaluation (float32 rounding), and the same query Historygrams as the host's comparison."""

import numpy as np
import pytest

from vtkillum.core.photon.historygram import ALL_BITS, query_masks
from vtkillum.core.photon.tables import DeviceTables
from vtkillum.core.photon.tracing import photon_tables
from vtkillum.core.transfer_function import TransferFunction

U = 2.0
RANGE = (0.0, 1000.0)
WHITE, RED, GREEN, BLUE = (1, 1, 1), (1, 0, 0), (0, 1, 0), (0, 0, 1)


def tf(points=(0, 200, 400, 700, 1000), opacity=(0, 0.1, 0.0, 0.6, 0.9),
       colors=(WHITE, RED, GREEN, BLUE, WHITE)):
    return TransferFunction(list(points), list(opacity), [list(c) for c in colors])


def same_as_host(tables, transfer_function, value_range):
    sigma, color, lo, hi = photon_tables(transfer_function, U, value_range)
    ds, dc = tables.numpy()
    # A device may fuse a * b + c into one rounding in float64: at most one float32 step.
    np.testing.assert_array_max_ulp(ds, sigma, maxulp=1)
    np.testing.assert_array_max_ulp(dc, color, maxulp=1)
    assert (tables.lo, tables.hi) == (lo, hi)
    assert tables.peak == pytest.approx(float(sigma.max()), rel=1e-6)


@pytest.mark.parametrize("case", ["plain", "huge points", "one point", "constant data",
                                  "opaque"])
def test_tables_equal_the_host_evaluation(device, case):
    value_range = RANGE
    function = tf()
    if case == "huge points":  # the halved interpolation keeps ±1e308 exact
        function = tf((-1e308, 0.0, 1e308), (0.0, 0.5, 1.0), (WHITE, RED, (0.5, 0.5, 0.5)))
        value_range = (-1e30, 1e30)
    elif case == "one point":
        function = tf((3.0,), (0.4,), ((0.2, 0.3, 0.4),))
    elif case == "constant data":
        value_range = (500.0, 500.0)
    elif case == "opaque":  # alpha 1 is capped (MAX_ALPHA): finite σt
        function = tf((0, 1000), (1.0, 1.0), (WHITE, WHITE))
    tables = DeviceTables(function, U, value_range, device)
    assert tables.sigma_bins == tables.color_bins == ALL_BITS  # no previous: all changed
    same_as_host(tables, function, value_range)
    assert np.all(np.isfinite(tables.numpy()[0]))


EDITS = {
    "colour of one point": tf(colors=(WHITE, RED, GREEN, (0.0, 0.5, 1.0), WHITE)),
    "opacity of one point": tf(opacity=(0, 0.1, 0.0, 0.3, 0.9)),
    "a point moved": tf(points=(0, 200, 450, 700, 1000)),
    "a point added": TransferFunction([0, 200, 400, 550, 700, 1000],
                                      [0, 0.1, 0.0, 0.3, 0.6, 0.9],
                                      [WHITE, RED, GREEN, GREEN, BLUE, WHITE]),
    "nothing": tf(),
}


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_query_masks_equal_the_host_comparison(device, edit):
    before = DeviceTables(tf(), U, RANGE, device)
    after = DeviceTables(EDITS[edit], U, RANGE, device, previous=before)
    host = query_masks(photon_tables(tf(), U, RANGE)[:2],
                       photon_tables(EDITS[edit], U, RANGE)[:2], RANGE)
    assert (after.sigma_bins, after.color_bins) == host
    assert after.sigma_changed == bool(host[0])
    assert after.color_changed == bool(host[1])
    if edit == "colour of one point":  # only the bins around 700 (bins of 15.625)
        assert host == (0, sum(1 << b for b in range(25, 64)))
    if edit == "nothing":
        assert host == (0, 0)
    same_as_host(after, EDITS[edit], RANGE)


def test_an_incomparable_previous_changes_everything(device):
    before = DeviceTables(tf(), U, RANGE, device)
    other = DeviceTables(tf(), U, (0.0, 999.0), device, previous=before)
    assert (other.sigma_bins, other.color_bins) == (ALL_BITS, ALL_BITS)
    assert other.sigma_changed and other.color_changed


def test_a_chain_of_edits_with_more_points_than_the_buffers_held(device):
    """Each edit reuses the buffers of the one before, or makes larger ones."""
    x = np.linspace(0.0, 1000.0, 40)
    many = TransferFunction(x, 0.5 + 0.4 * np.sin(x / 90.0),
                            np.stack([np.full(40, 0.2), x / 1000.0, 1.0 - x / 1000.0], 1))
    chain = [tf(), many, EDITS["a point moved"], tf()]
    tables = None
    for before, after in zip(chain, chain[1:]):
        tables = DeviceTables(before, U, RANGE, device, previous=tables)
        edited = DeviceTables(after, U, RANGE, device, previous=tables)
        host = query_masks(photon_tables(before, U, RANGE)[:2],
                           photon_tables(after, U, RANGE)[:2], RANGE)
        assert (edited.sigma_bins, edited.color_bins) == host != (0, 0)
        same_as_host(tables, before, RANGE)  # read after the next launch: still its own
        same_as_host(edited, after, RANGE)
        tables = edited
