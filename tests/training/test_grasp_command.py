"""The grasp command: its report, figures and TensorBoard events; seeds in worker processes equal the sequential study."""
import json
import re

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from training import run


def test_grasp_command_writes_report_figures_and_events(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["grasp", "--experiment", "mixed", "--pool", "8", "--best", "3", "--epochs", "2", "--folds", "1", "--online",
            "--device", "cpu", "--quiet", "--out", str(out)]
    assert run.main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert set(report["orientation_error_deg"]) >= {"median", "p90"}
    for key in ("mu0", "probes"):
        assert set(report[key]) == {"haptic", "cued"} and report[key]["haptic"]["n"] == 16  # 4 categories x 4 held out
    assert set(report["poor_grasp_fraction"]) >= {"haptic", "cued"}
    assert set(report["online"]) == {"offline", "online"} and [f["mode"] for f in report["folds"]] == ["offline", "online"]
    assert all((out / name).is_file() for name in ("errors.png", "grasps.png", "fold1_features.png", "report.md"))
    assert f"Device cpu ({report['machine']['cpu']}, {report['machine']['cpu_kernels']} kernels" in (out / "report.md").read_text()
    events = EventAccumulator(str(out / "tensorboard" / "fold1"), size_guidance={"scalars": 0, "histograms": 0, "images": 0})
    events.Reload()
    fold = report["folds"][0]
    steps = [e["epoch"] + 1 for e in fold["epochs"]]
    assert [e.step for e in events.Scalars("epoch/mistakes")] == steps
    assert [e.value for e in events.Scalars("epoch/mistakes")] == pytest.approx([e["mistakes"] for e in fold["epochs"]])
    # per epoch, what the learner predicted before each training grasp (the fold's checkpoint holds it)
    predictions = json.loads((out / "fold1" / "checkpoint.json").read_text())["state"]["predictions"]
    assert len(predictions) == len(steps) and all(len(p["error_deg"]) == 12 for p in predictions)  # 4 categories x 3
    unpredicted = [p["error_deg"].count(None) for p in predictions]
    assert [e.value for e in events.Scalars("epoch/unpredicted")] == unpredicted and 0 < sum(unpredicted) < 12 * len(steps)
    predicted = [s for s, n in zip(steps, unpredicted) if n < 12]
    for tag, key in (("epoch/orientation_error_deg", "error_deg"), ("epoch/mu0_expected", "expected_mu0")):
        histograms = events.Histograms(tag)
        assert [h.step for h in histograms] == predicted
        for h, p in zip(histograms, (p for p, n in zip(predictions, unpredicted) if n < 12)):
            values = [v for v in p[key] if v is not None]  # the grasps without a prediction are left out
            assert (h.histogram_value.num, h.histogram_value.min, h.histogram_value.max) == pytest.approx(
                (len(values), min(values), max(values)))
    assert [h.step for h in events.Histograms("epoch/mu0_measured")] == predicted
    assert {h.step for h in events.Histograms("epoch/fingers_chosen")} <= set(steps)
    assert events.Histograms("epoch/fingers_chosen")[-1].histogram_value.min >= 2
    assert events.Scalars("fold/poor_cued")[0].value == pytest.approx(fold["poor_grasp_fraction"]["cued"])
    assert events.Scalars("fold/unpredicted")[0].value == fold["orientation_error_deg"]["unpredicted"]
    errors = events.Histograms("fold/orientation_error_deg")[0].histogram_value
    assert errors.num == fold["orientation_error_deg"]["n"] - fold["orientation_error_deg"]["unpredicted"]
    assert errors.max < 180 or 180.0 in fold["tests"]["orientation_errors_deg"]  # no 180-degree stand-ins
    for side in ("haptic", "cued"):
        unbounded = [g["mu0"] for g in fold["tests"][side]].count(None)
        assert events.Scalars(f"fold/no_equilibrium_{side}")[0].value == unbounded
        assert events.Histograms(f"fold/mu0_{side}")[0].histogram_value.num == len(fold["tests"][side]) - unbounded
        assert events.Histograms(f"fold/probes_{side}")[0].step == len(steps)
    for tag in ("fold/figure_errors", "fold/figure_grasps", "fold/figure_features"):  # charts by add_figure, features by add_image
        assert [e.step for e in events.Images(tag)] == [len(steps)]
    assert run.main(argv[:-2] + ["--best", "5", "--out", str(out)]) == 2
    assert "--best 5" in capsys.readouterr().err


def test_grasp_seeds_in_processes_equal_the_sequential_study(tmp_path):
    common = ["grasp", "--experiment", "mixed", "--pool", "8", "--best", "3", "--epochs", "2", "--folds", "1",
              "--online", "--device", "cpu", "--quiet", "--seed", "4", "--seeds", "2"]
    assert run.main([*common, "--out", str(tmp_path / "a")]) == 0
    assert run.main([*common, "--workers", "2", "--out", str(tmp_path / "b")]) == 0
    timeless = lambda path: re.sub(r'"seconds": [0-9.e+-]+', "_", path.read_text())  # noqa: E731
    for name in ("report.json", "seed5/report.json"):
        assert timeless(tmp_path / "a" / name) == timeless(tmp_path / "b" / name)
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    alone = json.loads((tmp_path / "a" / "seed5" / "report.json").read_text())
    runs = report["seeds"]["runs"]
    assert [r["seed"] for r in runs] == [4, 5] and runs[1]["poor_grasp_fraction"] == {
        k: alone["poor_grasp_fraction"][k] for k in ("haptic", "cued", "reduction")}
    reductions = [r["poor_grasp_fraction"]["reduction"] for r in runs]
    offline = report["seeds"]["reduction"]["offline"]
    assert offline["mean"] == pytest.approx(np.mean(reductions)) and offline["worst"] == min(reductions)
    assert offline["sd"] == pytest.approx(np.std(reductions, ddof=1)) and "online" in report["seeds"]["reduction"]
    assert (tmp_path / "a" / "reductions.png").is_file() and "## Seeds 4-5" in (tmp_path / "a" / "report.md").read_text()
