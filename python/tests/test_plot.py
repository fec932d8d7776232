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
