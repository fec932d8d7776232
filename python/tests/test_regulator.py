"""The NDR queue through the bindings: FIFO order, pre-fill, counters."""

import numpy as np
import pytest

import ndr


def test_prefill_then_fifo_one_release_per_tick():
    r = ndr.Regulator(2, 3)
    assert (r.ns, r.width, r.capacity, len(r)) == (2, 3, 64, 0)
    assert r.last_tick is None and r.phase == "prefilling"
    r.push([1.0, 1.5, 1.75])
    r.push(np.array([2.0, 2.5, 2.75]))
    assert r.tick() is None
    assert r.last_tick == "prefilling"
    r.push((3, 3, 3))  # integers are converted to float64
    out = r.tick()
    assert out.dtype == np.float64 and out.shape == (3,)
    np.testing.assert_array_equal(out, [1.0, 1.5, 1.75])
    assert r.last_tick == "released" and r.phase == "running"
    np.testing.assert_array_equal(r.front(), [2.0, 2.5, 2.75])
    np.testing.assert_array_equal(r.samples(), [[2.0, 2.5, 2.75], [3.0, 3.0, 3.0]])
    np.testing.assert_array_equal(r.tick(), [2.0, 2.5, 2.75])
    np.testing.assert_array_equal(r.tick(), [3.0, 3.0, 3.0])
    assert r.tick() is None
    assert r.last_tick == "underflow"
    assert r.counters == {
        "arrived": 3,
        "released": 3,
        "rejected": 0,
        "discarded": 0,
        "underflows": 1,
        "ticks": 4,
    }
    # Occupancy just before each running tick: 3, 2, 1, 0.
    assert r.occupancy == {"min": 0, "max": 3, "mean": 1.5, "ticks": 4}


def test_scalar_samples_when_width_is_one():
    r = ndr.Regulator(0)
    r.push(0.25)
    r.push(np.float64(0.5))
    np.testing.assert_array_equal(r.tick(), [0.25])
    np.testing.assert_array_equal(r.tick(), [0.5])


def test_full_queue_hands_the_sample_back_and_counts_it():
    r = ndr.Regulator(1, 2, capacity=3)
    for k in range(3):
        r.push([k, -k])
    with pytest.raises(ndr.RegulatorFull) as info:
        r.push([7.0, 8.0])
    assert isinstance(info.value, OverflowError)
    np.testing.assert_array_equal(info.value.sample, [7.0, 8.0])
    assert "full" in str(info.value)
    assert len(r) == 3 and r.rejected == 1 and r.arrived == 4
    # Nothing queued was lost, and the ring keeps working past its end.
    for k in range(3):
        np.testing.assert_array_equal(r.tick(), [k, -k])
        r.push([10 + k, 0])
    for k in range(3):
        np.testing.assert_array_equal(r.tick(), [10 + k, 0])


def test_the_counters_always_balance():
    rng = np.random.default_rng(7)
    r = ndr.Regulator(3, 1, capacity=8)
    for _ in range(2000):
        action = rng.integers(0, 6)
        if action < 3:
            try:
                r.push(rng.normal())
            except ndr.RegulatorFull:
                pass
        elif action < 5:
            r.tick()
        elif rng.integers(0, 10) == 0:
            r.discard_front()
    c = r.counters
    assert c["arrived"] == c["released"] + len(r) + c["rejected"] + c["discarded"]
    assert c["rejected"] > 0 and c["underflows"] > 0


def test_discard_clear_and_restart():
    r = ndr.Regulator(1)
    for k in range(5):
        r.push(k)
    np.testing.assert_array_equal(r.discard_front(), [0.0])
    assert r.clear() == 4
    assert r.discarded == 5 and len(r) == 0
    assert r.discard_front() is None
    r.ns = 0
    r.push(1.0)
    np.testing.assert_array_equal(r.tick(), [1.0])
    r.ns = 1
    r.restart_prefill()
    r.push(2.0)
    assert r.tick() is None and r.last_tick == "prefilling"
    r.reset_occupancy()
    assert r.occupancy is None


def test_nominal_size_must_leave_room():
    with pytest.raises(ValueError, match="capacity 4"):
        ndr.Regulator(4, capacity=4)
    r = ndr.Regulator(2, capacity=4)
    with pytest.raises(ValueError, match="capacity"):
        r.ns = 4
    assert r.ns == 2
    assert "Regulator(ns=2" in repr(r)
