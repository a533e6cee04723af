"""research/sensors/rule_null.py: the seed table's rule on label-swapped episodes."""
import json

import numpy as np
import pytest

from tests.test_eval_table import results
from research.tests.study_loader import study_module
from tests.eval_readers import reader


def three_runs():
    """Three runs of an arm evaluation. fast/multi: A wins each run's 4 episodes, B loses
    them; nominal/multi: both grasp all 4 (ties); hdr/single: one graspable episode each."""
    return {f"s{k}": results({"fast/multi": [True] * 4, "nominal/multi": [True] * 4,
                              "hdr/single": [True, None]},
                             {"fast/multi": [False] * 4, "nominal/multi": [True] * 4,
                              "hdr/single": [False, None]}) for k in range(3)}


def test_the_null_chances_are_the_coin_flips_counted_by_hand():
    """fast/multi under the null: a run is ahead when 3 or 4 of its 4 coins say A (5/16),
    and its mean is then >= 50 points, so "helps" needs all three: (5/16)^3 = 0.0305; as
    large as seen (+100) needs all 12 coins: 1/4096. Ties never give a verdict."""
    with study_module("sensors/rule_null") as tool:
        got = tool.rule_null(three_runs(), "rgb+event", "rgb", None, 10.0, None,
                             draws=200_000, seed=1)
        fast = got["cells"]["fast/multi"]
        assert fast["reading"] == "rgb+event helps" and fast["effect_points"] == 100
        assert fast["episodes_per_run"] == [4, 4, 4]
        assert fast["p_helps"] == pytest.approx((5 / 16) ** 3, rel=0.05)
        assert fast["p_hurts"] == pytest.approx((5 / 16) ** 3, rel=0.05)
        assert fast["p_as_large"] == pytest.approx(1 / 4096, rel=0.3)
        tie = got["cells"]["nominal/multi"]
        assert tie["p_helps"] == tie["p_hurts"] == 0 and tie["p_as_large"] is None
        # one episode a run: every run ahead or every run behind, each 1/8
        one = got["cells"]["hdr/single"]
        assert one["episodes_per_run"] == [1, 1, 1]
        assert one["p_helps"] == pytest.approx(1 / 8, rel=0.05)
        # the cells' verdicts add up: expected count, at least one, at least as many (2)
        p = [(5 / 16) ** 3 * 2, 0.0, 1 / 4]
        assert got["verdicts_seen"] == 2
        assert got["verdicts_expected"] == pytest.approx(sum(p), rel=0.05)
        assert got["p_at_least_one"] == pytest.approx(1 - np.prod([1 - x for x in p]),
                                                      rel=0.05)
        assert got["p_at_least_as_many"] == pytest.approx(p[0] * p[2], rel=0.1)


def test_the_pairs_are_the_ones_the_seed_table_averages():
    """Each run's mean over its pairs is seed_table's per-run difference, including
    episodes that only one side scored (left out) and a run that differs from the others."""
    runs = three_runs()
    runs["s2"] = results({"fast/multi": [True, False, None, True]},
                         {"fast/multi": [False, False, True, None]})
    with reader("table") as seeds, study_module("sensors/rule_null") as tool:
        table = seeds.seed_table(runs, "rgb+event", "rgb")
        pairs = tool.paired_outcomes(runs, "rgb+event", "rgb", "grasp_success",
                                     list(table["cells"]))
        for cell, per_run in pairs.items():
            for (name, observed), p in zip(table["cells"][cell]["per_run"].items(), per_run):
                assert (p[:, 0] - p[:, 1]).mean() == pytest.approx(observed["diff"]), name
        assert [len(p) for p in pairs["fast/multi"]] == [4, 4, 2]


def test_the_command_line_reads_runs_or_the_study_and_refuses_both(tmp_path, capsys):
    with study_module("sensors/rule_null") as tool:
        for name, res in three_runs().items():
            (tmp_path / name).mkdir()
            (tmp_path / name / "results.json").write_text(json.dumps(res))
        specs = [f"s{k}={tmp_path / f's{k}'}" for k in range(3)]
        out = tmp_path / "null.json"
        assert tool.main([*specs, "--a", "rgb+event", "--b", "rgb", "--draws", "2000",
                          "--json", str(out)]) == 0
        text = capsys.readouterr().out
        assert "| fast/multi | +100.0 | rgb+event helps | 4, 4, 4 |" in text
        assert "verdicts: 2 seen in 3 cells" in text
        saved = json.loads(out.read_text())
        assert saved["readings"]["reading"]["cells"]["fast/multi"]["p_as_large"] is not None
        assert saved["together"]["verdicts_seen"] == 2
        assert tool.main([*specs[:2], f"s2={tmp_path / 'nope'}", "--a", "rgb+event",
                          "--b", "rgb"]) == 2
        assert "run 's2'" in capsys.readouterr().err
        assert tool.main(["--study", "nav99"]) == 2
        assert "expected one of nav10" in capsys.readouterr().err
        for bad in ([*specs, "--study", "nav10"], [], [*specs], ["--study", "nav10", "--a", "rgb"],
                    ["--study", "arm10", "--min-diff", "5"]):
            with pytest.raises(SystemExit):
                tool.main(bad)
