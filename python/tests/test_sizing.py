"""The paper's sizing laws, through the Python bindings."""

import math

import pytest

import ndr

PARIS_NEW_YORK = [0.180, 0.320, 1.980, 0.350, 0.610, 0.240, 0.800, 0.300, 0.760, 0.560]
LAN_75KM = [0.023, 0.019, 0.025, 0.022, 0.031, 0.021, 0.024, 0.020, 0.023, 0.022]


def test_version_is_the_crates():
    assert ndr.__version__.count(".") == 2


@pytest.mark.parametrize(("pattern", "expected"), [(PARIS_NEW_YORK, 13), (LAN_75KM, 2)])
def test_init_pattern_sizes_the_queue_like_the_paper(pattern, expected):
    nrtt_min, nrtt_max, nrtt_mean, mt = ndr.init_stats(pattern)
    assert mt == pytest.approx(max(pattern) - min(pattern), abs=1e-9)
    assert nrtt_mean == pytest.approx(sum(pattern) / len(pattern), abs=1e-9)
    assert ndr.nominal_size(mt, 0.2) == expected


def test_eta_is_a_keyword():
    assert ndr.nominal_size(1.0, 0.2, eta=1.0) == 7
    with pytest.raises(TypeError):
        ndr.nominal_size(1.0, 0.2, 1.0)


def test_period_law():
    assert ndr.period_law(0.023) == pytest.approx(0.05)
    assert ndr.period_law(0.610) == pytest.approx(0.610 / 3, abs=1e-9)
    assert ndr.period_law(0.030, min_period=0.001) == pytest.approx(0.010)


@pytest.mark.parametrize(
    "call",
    [
        lambda: ndr.nominal_size(-1.0, 0.2),
        lambda: ndr.nominal_size(math.nan, 0.2),
        lambda: ndr.nominal_size(0.1, 0.0),
        lambda: ndr.nominal_size(0.1, 0.2, eta=-1.0),
        lambda: ndr.period_law(math.inf),
        lambda: ndr.init_stats([]),
        lambda: ndr.init_stats([0.1] * (ndr.INIT_EXCHANGES + 1)),
    ],
)
def test_bad_input_raises_value_error(call):
    with pytest.raises(ValueError):
        call()
