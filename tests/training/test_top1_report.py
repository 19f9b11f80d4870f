"""The runner's reports of the top-1 answer (issue 53): report.json's top-1 is the learner's on its
test views, and a run resumed from a checkpoint written before top-1 reports n/a with one note."""
import json
import math
import shutil
from dataclasses import replace

import numpy as np
import pytest

from ftorch import DistinctiveFeatureLearner, FeatureSpace
from training import run
from training.data.datasets import load_task
from training.plots import curves_figure, figure_rgb
from training.recognition.protocol import image_set
from training.recognition.protocol import test_block as scored  # (a test_ name would be collected)
from training.recognition.records import Averages, Report
from training.recognition.report import average, write_markdown


@pytest.fixture(scope="module")
def plym_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("top1") / "run"
    assert run.main(["recognize", "--task", "plym", "--size", "32", "--classes", "3", "--folds", "1", "--stages", "1",
                     "--max-cycles", "6", "--quiet", "--device", "cpu", "--out", str(out)]) == 0
    return out


def test_the_reports_top1_is_the_learners_on_its_test_views(plym_run):
    report = json.loads((plym_run / "report.json").read_text())
    c = report["config"]
    task = load_task(c["task"], c["data"], len(c["classes"]), c["views"], c["size"], c["seed"], c["first_view"])
    _, test = task.fold(1)
    env = image_set(task, test, FeatureSpace(), False)
    learner = DistinctiveFeatureLearner.load(plym_run / "fold1" / "learner.json")
    answers = learner.recognize_many(env, range(len(env)))
    final = report["folds"][0]["stages"][-1]["test"]
    assert final["top1"] == pytest.approx(np.mean([r.top in t for r, t in zip(answers, env.labels)]))
    assert final["accuracy"] == pytest.approx(scored(answers, env.labels, c["classes"]).accuracy)
    assert report["average"]["final"]["test"]["top1"] == final["top1"]
    markdown = (plym_run / "report.md").read_text()
    assert "| acc. | top-1 | cor." in markdown and f"| {final['top1']:.2f}".replace("| 0.", "| .") in markdown


def test_stages_from_an_older_checkpoint_read_as_not_available(plym_run, tmp_path, capsys):
    """A run resumed from a fold checkpoint written before top-1 was reported: its stages have no top1;
    the report says n/a with one note, the figures leave a gap, nothing fails."""
    old = tmp_path / "old"
    shutil.copytree(plym_run, old)
    checkpoint = old / "fold1" / "checkpoint.json"
    data = json.loads(checkpoint.read_text())
    for stage in data["state"]["stages"]:
        del stage["test"]["top1"]
    checkpoint.write_text(json.dumps(data))
    capsys.readouterr()
    assert run.main(["recognize", "--task", "plym", "--size", "32", "--classes", "3", "--folds", "1", "--stages", "1",
                     "--max-cycles", "6", "--quiet", "--device", "cpu", "--out", str(old), "--resume"]) == 0
    err = capsys.readouterr().err
    notes = [line for line in err.splitlines() if "top-1" in line]
    assert notes == ["note: top-1 accuracy is not available (n/a) for fold 1 seed 0 stage 0, fold 1 seed 0 stage 1: tested "
                     "before ftorch reported it (resumed from an older checkpoint); train afresh for it"]
    report = json.loads((old / "report.json").read_text())
    assert report["average"]["final"]["test"].get("top1") is None  # no stage has it: not available
    assert "top1" not in report["folds"][0]["stages"][0]["test"]
    markdown = (old / "report.md").read_text()
    assert "Note: top-1 accuracy is not available (n/a) for fold 1 stage 0, fold 1 stage 1" in markdown
    assert "| n/a | " in markdown
    mixed = json.loads((plym_run / "report.json").read_text())  # one fold with top-1, one without
    second = json.loads(json.dumps(mixed["folds"][0]))
    second["fold"] = 2
    for stage in second["stages"]:
        del stage["test"]["top1"]
    report = Report.from_json({**mixed, "folds": [mixed["folds"][0], second]})
    folds = report.folds
    assert math.isnan(average(folds, -1).test.top1) and average(folds, -1).test.accuracy == mixed["folds"][0][
        "stages"][-1]["test"]["accuracy"]
    assert figure_rgb(curves_figure(report)).shape[2] == 3
    write_markdown(tmp_path / "mixed.md", replace(report, average=Averages(average(folds, 0), average(folds, -1))), [])
    assert "fold 2 stage 0, fold 2 stage 1" in (tmp_path / "mixed.md").read_text()
