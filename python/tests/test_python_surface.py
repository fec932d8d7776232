"""The Python surface behaves like Python: None for what was not measured,
OSError with errno, ValueError naming the parameter, exact types."""

import copy
import errno
import logging
import pathlib
import socket
import subprocess
import sys
import typing

import numpy as np
import pytest

import ndr
import ndr.sim
from ndr import _native

LOOPBACK = ("127.0.0.1", 0)


# -- 1. the simulator's summary: None where nothing was measured -------------


def test_a_run_too_short_to_measure_reports_none_not_zero():
    s = ndr.sim.run("paris-newyork", duration=1.0, series=False).summary
    assert s["grtt_count"] == 0 and s["pred_count"] == 0 and s["samples_released"] == 0
    for key in (
        "grtt_mean_s",
        "grtt_std_s",
        "grtt_p99_s",
        "settled_grtt_mean_s",
        "settled_grtt_std_s",
        "pred_nrtt_mae_s",
        "pred_nrtt_rmse_s",
        "pred_mt_mae_s",
        "pred_mt_rmse_s",
        "e2e_fwd_mean_s",
        "e2e_fwd_std_s",
        "e2e_bwd_mean_s",
        "e2e_bwd_std_s",
        "queue_base_min",
        "queue_base_max",
        "queue_base_mean",
        "queue_remote_min",
        "queue_remote_max",
        "queue_remote_mean",
        "relation_grtt_s",
        "relation_error_s",
        "relation_mean_grtt_s",
        "relation_mean_error_s",
        "initial_ns",
    ):
        assert s[key] is None, key
    # Counts stay integers.
    assert s["grtt_count"] == 0 and isinstance(s["grtt_count"], int)


def test_a_run_long_enough_measures_everything():
    s = ndr.sim.run("lan-75km", duration=60, series=False).summary
    assert s["grtt_count"] > 0 and s["grtt_mean_s"] > 0 and s["settled_grtt_mean_s"] > 0
    assert s["initial_ns"] >= 2 and s["queue_base_max"] >= 1 and s["queue_remote_max"] >= 1
    assert isinstance(s["relation_error_s"], float)
    assert isinstance(s["e2e_fwd_mean_s"], float) and s["e2e_fwd_mean_s"] > 0
    assert s["pred_count"] > 0 and s["pred_nrtt_mae_s"] >= 0.0


def test_grtts_without_a_forecast_yet():
    # The forecasts look 50 periods (10 s) ahead: none is compared in 10 s.
    s = ndr.sim.run("constant:0", duration=10, series=False).summary
    assert s["grtt_count"] > 0 and s["grtt_mean_s"] > 0
    assert s["pred_count"] == 0 and s["pred_nrtt_mae_s"] is None and s["pred_mt_rmse_s"] is None


def _summary_types():
    return typing.get_type_hints(ndr.sim.SimSummary)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(profile="paris-newyork", duration=1.0),
        dict(profile="lan-75km", duration=60),
        dict(profile="lan-75km", regulation="paper-dynamic", duration=120),
    ],
)
def test_the_summary_matches_its_typed_dict(kwargs):
    s = ndr.sim.run(series=False, **kwargs).summary
    hints = _summary_types()
    assert set(s) == set(hints)
    for key, value in s.items():
        hint = hints[key]
        allowed = typing.get_args(hint) or (hint,)
        if value is None:
            assert type(None) in allowed, f"{key} is None but typed {hint}"
        elif type(value) is int and float in allowed and int not in allowed:
            pytest.fail(f"{key} is an int but typed {hint}")
        else:
            assert isinstance(value, tuple(a for a in allowed if a is not type(None))), (
                key,
                value,
                hint,
            )


def test_sim_result_summary_is_typed_precisely():
    hints = typing.get_type_hints(ndr.sim.SimResult)
    assert hints["summary"] is ndr.sim.SimSummary


# -- 2. socket errors are OSError subclasses with errno ------------------------


def test_listening_twice_on_a_port_is_eaddrinuse():
    with ndr.Link.listen(LOOPBACK) as first:
        with pytest.raises(OSError) as info:
            ndr.Link.listen(first.address)
    assert info.value.errno == errno.EADDRINUSE
    assert info.value.strerror and "in use" in info.value.strerror


def test_a_relay_on_a_port_in_use_is_eaddrinuse_and_names_the_address():
    with ndr.Relay(LOOPBACK, ("127.0.0.1", 9)) as relay:
        with pytest.raises(OSError) as info:
            ndr.Relay(relay.address, ("127.0.0.1", 9))
    assert info.value.errno == errno.EADDRINUSE
    assert f"{relay.address[0]}:{relay.address[1]}" in str(info.value)


def _closed_port():
    s = socket.socket()
    s.bind(LOOPBACK)
    port = s.getsockname()[1]
    s.close()
    return port


def test_connecting_to_a_closed_port_is_econnrefused():
    port = _closed_port()
    with pytest.raises(ConnectionRefusedError) as info:
        ndr.Link.connect(("127.0.0.1", port), connect_timeout=5)
    assert info.value.errno == errno.ECONNREFUSED
    assert f"cannot connect to 127.0.0.1:{port}" in info.value.strerror


# -- 3. negative integers are ValueErrors naming the parameter ---------------


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: ndr.sim.run(seed=-1, duration=1), "seed must be an integer from 0"),
        (lambda: ndr.sim.run(seed=2**64, duration=1), "seed must be an integer from 0"),
        (lambda: ndr.sim.run(axes=-1, duration=1), "axes must be an integer from 1 to 256"),
        (lambda: ndr.Signal("sine")(0.1, -1), "axis must be an integer from 0"),
        (lambda: ndr.Relay(LOOPBACK, ("127.0.0.1", 9), seed=-1), "seed must be an integer"),
        (lambda: ndr.Link.listen(("127.0.0.1", -1)), "port must be an integer from 0 to 65535"),
        (lambda: ndr.Link.listen(("127.0.0.1", 70000)), "port must be"),
    ],
)
def test_out_of_range_integers_are_value_errors_naming_the_parameter(call, words):
    with pytest.raises(ValueError, match=words):
        call()


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(axes=-1), "axes must be an integer from 1 to 256"),
        (dict(axes=2**70), "axes must be an integer from 1 to 256"),
        (dict(axes=0), "axes must be an integer from 1 to 256"),
        (dict(axes=257), "axes must be an integer from 1 to 256"),
        (dict(command_width=257), "command_width must be an integer from 1 to 256"),
        (dict(queue=-1), "queue must be an integer from 1 to 1048576"),
        (dict(queue=0), "queue must be an integer from 1"),
        (dict(queue=2**20 + 1), "queue must be an integer from 1"),
    ],
)
def test_link_settings_out_of_range_are_value_errors_naming_the_parameter(kwargs, words):
    with pytest.raises(ValueError, match=words):
        ndr.Link.listen(LOOPBACK, **kwargs)


def test_the_largest_seed_is_accepted():
    assert ndr.sim.run(seed=2**64 - 1, duration=1, series=False).summary["seed"] == 2**64 - 1


# -- 4. typing ----------------------------------------------------------------


def test_init_stats_takes_tuples_and_arrays_as_its_stub_says():
    expected = ndr.init_stats([0.1, 0.2])
    assert ndr.init_stats((0.1, 0.2)) == expected
    assert ndr.init_stats(np.array([0.1, 0.2])) == expected
    stub = pathlib.Path(ndr.__file__).with_name("_native.pyi").read_text(encoding="utf-8")
    assert "def init_stats(nrtt: list[float])" not in stub
    assert "Sequence[float]" in stub


def test_private_natives_are_not_in_all():
    assert [n for n in _native.__all__ if n.startswith("_") and not n.startswith("__")] == []
    # The names themselves stay (ndr.link uses them).
    for name in ("_Link", "_Listener", "_LinkSettings"):
        assert hasattr(_native, name), name


# -- 5. the regulations listed are the ones accepted -------------------------


@pytest.mark.parametrize("regulation", ndr.sim.REGULATIONS)
def test_every_listed_regulation_is_accepted_as_written(regulation):
    r = ndr.sim.run("lan-75km", regulation=regulation, duration=5, series=False)
    assert r.summary["regulation"].split(":")[0] == regulation.split(":")[0]


def test_the_regulation_list_names_adaptive_and_documents_the_parameterized_forms():
    assert "adaptive" in ndr.sim.REGULATIONS
    assert not any(":" in p for p in ndr.sim.REGULATIONS)
    source = pathlib.Path(ndr.sim.__file__).read_text(encoding="utf-8")
    for form in ('"fixed:MS"', '"constant:MS"', '"adaptive:PERCENT"'):
        assert form in source
    assert '"adaptive:PERCENT:QUANTUM_MS"' in source
    for example in ("fixed:150", "constant:120", "adaptive:0.5", "adaptive:0.1:10"):
        ndr.sim.run("lan-75km", regulation=example, duration=5, series=False)


# -- 6. smaller ---------------------------------------------------------------


def test_a_plain_link_off_loopback_is_refused_in_python_words():
    with pytest.raises(ValueError) as info:
        ndr.Link.listen(("0.0.0.0", 0))
    message = str(info.value)
    assert "insecure=True" in message and "tls=" in message
    assert "--cert" not in message and "--insecure" not in message


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    return ndr.keygen(tmp_path_factory.mktemp("certs"), "me")


def test_pins_may_be_one_str(pair):
    cert, key, fingerprint = pair
    assert ndr.TlsConfig(cert, key, pins=fingerprint).fingerprint == fingerprint
    assert ndr.TlsConfig(cert, key, pins=(fingerprint,)).fingerprint == fingerprint


def test_pins_of_another_type_are_a_type_error_saying_what_to_give(pair):
    cert, key, _ = pair
    with pytest.raises(TypeError, match="pins must be a list of SHA-256 fingerprints"):
        ndr.TlsConfig(cert, key, pins=3)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="pins must be a list"):
        ndr.TlsConfig(cert, key, pins=[3])  # type: ignore[list-item]


def test_a_bad_pin_is_named_once(pair):
    cert, key, _ = pair
    with pytest.raises(ValueError) as info:
        ndr.TlsConfig(cert, key, pins=["abc"])
    message = str(info.value)
    assert message.count("is not a SHA-256 fingerprint") == 1, message
    assert "`ndr keygen`" not in message


def test_keygen_refusing_to_overwrite_names_the_python_argument(tmp_path):
    ndr.keygen(tmp_path, "lab")
    with pytest.raises(ValueError) as info:
        ndr.keygen(tmp_path, "lab")
    assert "--name" not in str(info.value)


def test_an_empty_host_is_every_interface():
    with ndr.Link.listen(("", 0), insecure=True) as listener:
        assert listener.address[0] == "0.0.0.0"
    with ndr.Link.listen(":0", insecure=True) as listener:
        assert listener.address[0] == "0.0.0.0"


def test_a_tuple_of_three_is_refused_as_not_host_port():
    with pytest.raises(TypeError, match=r"\(host, port\)") as info:
        ndr.Link.listen(("127.0.0.1", 0, 0))
    assert "3 items" in str(info.value)
    assert "0..=65535" not in str(info.value)


@pytest.fixture
def restore_log_level():
    yield
    ndr.set_log_level("info")


@pytest.mark.parametrize(
    "level", [logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR, logging.CRITICAL, 5]
)
def test_logging_levels_are_accepted(level, restore_log_level):
    ndr.set_log_level(level)


@pytest.mark.parametrize("level", ["off", "OFF", None, "trace", "warning"])
def test_off_and_none_silence_rust(level, restore_log_level):
    ndr.set_log_level(level)


def test_a_bad_log_level_says_what_is_accepted(restore_log_level):
    with pytest.raises(ValueError, match="logging level"):
        ndr.set_log_level("loud")
    with pytest.raises(TypeError, match="logging level"):
        ndr.set_log_level(1.5)  # type: ignore[arg-type]


def test_log_level_off_drops_rust_records(caplog, restore_log_level):
    def relay_warning():
        # A frame that is not ndr makes the relay log a warning.
        with ndr.Link.listen(LOOPBACK) as listener, ndr.Relay(
            LOOPBACK, listener.address, profile="constant:0"
        ) as relay:
            with socket.create_connection(relay.address) as s:
                s.sendall(b"\xff" * 64)
                s.settimeout(2)
                try:
                    s.recv(1)
                except OSError:
                    pass
            relay.stats  # flushes the Rust records

    def rust_records():
        ndr.flush_logs()
        return [r for r in caplog.records if r.name.startswith("ndr.net")]

    with caplog.at_level(logging.DEBUG, logger="ndr"):
        ndr.set_log_level(logging.DEBUG)
        caplog.clear()
        relay_warning()
        assert rust_records(), "the relay logs a bad frame"
        ndr.set_log_level(None)
        caplog.clear()
        relay_warning()
        assert not rust_records()


def test_a_regulator_can_be_copied():
    r = ndr.Regulator(1, 2, capacity=8)
    r.push([1.0, 2.0])
    r.push([3.0, 4.0])
    c = copy.copy(r)
    d = copy.deepcopy(r)
    np.testing.assert_array_equal(r.tick(), [1.0, 2.0])
    assert len(c) == len(d) == 2 and len(r) == 1
    np.testing.assert_array_equal(c.samples(), [[1.0, 2.0], [3.0, 4.0]])
    assert c.arrived == 2 and c.released == 0 and c.phase == "prefilling"
    np.testing.assert_array_equal(d.tick(), [1.0, 2.0])


def _demo(*args):
    return subprocess.run(
        [sys.executable, "-m", "ndr", *args], capture_output=True, text=True, timeout=30
    )


def test_the_demo_reports_a_bad_period_in_milliseconds():
    proc = _demo("demo", "--period-ms", "-5")
    assert proc.returncode == 2
    assert "--period-ms" in proc.stderr and "-5" in proc.stderr
    assert "-0.005" not in proc.stderr


def test_python_m_ndr_without_a_command_is_a_usage_error_on_stderr():
    proc = _demo()
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert "usage" in proc.stderr
    ok = _demo("--help")
    assert ok.returncode == 0 and "usage" in ok.stdout


def test_the_relay_documents_its_default_delay_model():
    assert "lan-75km" in ndr.Relay.__doc__
    stub = pathlib.Path(ndr.__file__).with_name("_native.pyi").read_text(encoding="utf-8")
    relay_stub = stub[stub.index("class Relay:") :]
    assert "lan-75km" in relay_stub[: relay_stub.index("def __new__")]
    with ndr.Relay(LOOPBACK, ("127.0.0.1", 9)) as relay:
        assert relay.model == "lan-75km"


def test_a_relay_off_loopback_needs_insecure():
    with pytest.raises(ValueError, match="insecure"):
        ndr.Relay(("0.0.0.0", 0), ("127.0.0.1", 9))
    with ndr.Relay(("0.0.0.0", 0), ("127.0.0.1", 9), insecure=True) as relay:
        assert relay.address[0] == "0.0.0.0"
