"""ndr.plot draws the paper's figures (skipped without matplotlib)."""

import json

import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

import ndr.plot  # noqa: E402
import ndr.sim  # noqa: E402


@pytest.fixture(scope="module")
def result():
    return ndr.sim.run("paper-fig6", regulation="paper-dynamic", period=0.2, duration=120)


@pytest.mark.parametrize("draw", [ndr.plot.round_trips, ndr.plot.predictions, ndr.plot.queues])
def test_figures_are_drawn(result, draw, tmp_path):
    fig = draw(result)
    lines = [line for ax in fig.axes for line in ax.get_lines()]
    assert lines and all(len(line.get_xdata()) > 100 for line in lines)
    fig.savefig(tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 1000


def test_a_result_without_series_is_refused():
    r = ndr.sim.run("lan-75km", duration=10, series=False)
    with pytest.raises(ValueError, match="series"):
        ndr.plot.round_trips(r)


def test_compare_draws_one_point_per_regulation(tmp_path):
    # The shape of `ndr compare --json` (schema ndr-compare/2), trimmed.
    report = {
        "schema": "ndr-compare/2",
        "families": [
            {
                "name": "lan-75km",
                "regulations": [
                    {"regulation": "paper-static", "mean_delay_s": {"mean": 0.6, "ci95": 0.0},
                     "late_rate": {"mean": 0.0, "ci95": 0.0},
                     "point": {"mean_delay_s": 0.6, "late_rate": 0.0}},
                    {"regulation": "ramjee-1", "mean_delay_s": {"mean": 0.05, "ci95": 0.001},
                     "late_rate": {"mean": 0.01, "ci95": 0.001},
                     "point": {"mean_delay_s": 0.05, "late_rate": 0.01}},
                    {"regulation": "oracle", "mean_delay_s": {"mean": 0.02, "ci95": 0.0},
                     "late_rate": {"mean": 0.001, "ci95": 0.0}},
                ],
            }
        ],
    }
    path = tmp_path / "compare.json"
    path.write_text(json.dumps(report))
    fig = ndr.plot.compare(str(path))
    assert len(fig.axes[0].collections) == 3
    with pytest.raises(ValueError, match="no family"):
        ndr.plot.compare(report, family="mars")
    with pytest.raises(ValueError, match="families"):
        ndr.plot.compare({"nothing": 1})
    # Schema 1's names for the same rows still draw.
    old = json.loads(
        json.dumps(report).replace('"regulations"', '"policies"').replace('"regulation"', '"policy"')
    )
    assert "policies" in old["families"][0]
    assert len(ndr.plot.compare(old).axes[0].collections) == 3


DEMO_CSV = """t_s,seq,status,grtt_s,nrtt_s,command,state,x3e
0.050000,1,fresh,,0.041000,0.000000,0.000000,
0.100000,2,fresh,0.100000,0.043000,0.050000,0.010000,
0.150000,3,held,0.100000,,0.090000,0.010000,
0.200000,4,fresh,0.100000,0.039000,0.120000,0.040000,0.050000
"""


def test_a_run_s_csv_is_drawn_as_nrtt_against_grtt(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(DEMO_CSV)
    s = ndr.plot.read_series(str(path))
    assert s["grtt_s"][0] != s["grtt_s"][0]  # an empty field is NaN
    assert list(s["status"]) == [0.0, 0.0, 1.0, 0.0]
    fig = ndr.plot.demo(str(path))
    top, bottom = fig.axes
    labels = [line.get_label() for line in top.get_lines()]
    assert labels == ["NRTT (network)", "GRTT (regulated)"]
    assert list(top.get_lines()[1].get_ydata()[1:]) == pytest.approx([100.0] * 3)
    assert len(bottom.get_lines()) == 2


def test_python_m_ndr_plot_writes_the_figure_beside_the_csv(tmp_path, capsys):
    from ndr.__main__ import main

    path = tmp_path / "run.csv"
    path.write_text(DEMO_CSV)
    assert main(["plot", str(path)]) == 0
    assert (tmp_path / "run.png").stat().st_size > 1000
    assert "run.png" in capsys.readouterr().out
    assert main(["plot", str(path), "-o", str(tmp_path / "fig.svg")]) == 0
    assert (tmp_path / "fig.svg").read_text().lstrip().startswith("<?xml")


@pytest.mark.parametrize(
    "text, message",
    [
        ("t_s,seq,grtt_s\n0.1,1,0.1\n", "no column nrtt_s, command, state"),
        (DEMO_CSV.replace("0.041000", "fast"), "line 2: nrtt_s is 'fast', not a number"),
        (DEMO_CSV + "0.25,5\n", "line 6: 2 fields where the header has 8"),
    ],
)
def test_a_file_that_is_not_a_run_s_series_gets_a_clear_error(tmp_path, capsys, text, message):
    from ndr.__main__ import main

    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        ndr.plot.read_series(str(path))
    assert main(["plot", str(path)]) == 1
    assert message in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()
