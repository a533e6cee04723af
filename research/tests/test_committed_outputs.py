"""The sensor study's results stay reproducible from what research/sensors/outputs/ commits:
each reading (read/<task><rate>.json) is what `sebvs eval table` makes again from
the committed evaluations with the plan's rule, and the tables docs/results.md opens with
are what sensor_report.py makes again from them. Nothing is trained or evaluated: a few
seconds of reading JSON."""
import contextlib
import io
import json

import pytest

from research.tests.study_loader import RESEARCH, study_module
from tests.eval_readers import reader

ROOT = RESEARCH.parent
READINGS = ("nav10", "nav30", "arm10", "arm30")


@pytest.mark.parametrize("name", READINGS)
def test_each_committed_reading_is_what_the_committed_evaluations_give(name, tmp_path):
    with study_module("sensors/sensor_study") as study, \
            reader("table") as seeds:
        task, rate = study.READINGS[name]
        again = tmp_path / f"{name}.json"
        # the read step's own arguments (sensor_study.py plan prints them), minus the plot
        with contextlib.redirect_stdout(io.StringIO()):
            assert seeds.main([*study.read_arguments(study.STUDY_DIR, task, rate),
                               "--json", str(again)]) == 0
        committed = study.reading_path(study.STUDY_DIR, task, rate)
        assert json.loads(again.read_text()) == json.loads(committed.read_text())


def test_the_tables_of_docs_results_are_what_the_committed_outputs_give():
    with study_module("sensors/sensor_study") as study, \
            study_module("sensors/sensor_report") as report:
        tables, _, done = report.report(study.STUDY_DIR)
        page = (ROOT / "docs" / "results.md").read_text()
        assert done
        # `sensor_report.py --update docs/results.md` would leave the page as it is
        assert report.replace_block(page, tables) == page, (
            "docs/results.md's generated tables differ from what "
            "research/sensors/sensor_report.py makes of research/sensors/outputs/")
