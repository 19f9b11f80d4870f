"""The recognition protocol of 4.5: learning a fold, exact resume, checkpoint refusal, reports."""
import json
import os
import re
import subprocess
import sys
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from pgmpy.readwrite import BIFReader
from scipy import stats
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from ftorch import FeatureSpace
from ftorch.errors import InputError
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import LearnerSettings
from ftorch.recognition.stages import ClassAdded, Progress, Stage, next_target
from training import run
from training.data.datasets import Task
from training.plots import figure_rgb, fold_curves_figure
from training.recognition.protocol import Fold, FoldState, RunConfig
from training.recognition.records import FeatureBlock, FoldEntry, Report, StageEntry
from training.recognition.records import TestBlock as Scores  # (a Test class would be collected)
from training.recognition.report import growth, growth_over_seeds, seed_study, write_markdown

CONFIG = RunConfig("plym4", seed=0, learner=LearnerSettings.thesis())


def make_fold(task: Task, folder, k: int = 1, incremental: bool = False) -> Fold:
    space = FeatureSpace()
    train, test = task.fold(k)
    sets = [ImageSet([task.images[i] for i in idx], [{task.labels[i]} for i in idx], space) for idx in (train, test)]
    return Fold(k, *sets, replace(CONFIG, classes=task.classes()), folder, task.classes(), progress=False,
                incremental=incremental)


def without_timing(data):
    if isinstance(data, dict):
        return {k: without_timing(v) for k, v in data.items() if k != "seconds"}
    if isinstance(data, list):
        return [without_timing(v) for v in data]
    return data


def test_fold_learns_its_training_set_and_beats_chance(small_task, tmp_path):
    entry, learner = make_fold(small_task, tmp_path).run(max_cycles=30)
    entry = entry.to_json()  # the report entry as report.json holds it
    stage = entry["stages"][0]
    assert stage["train_learned"] and stage["mistakes_per_cycle"][-1] == 0
    assert stage["test"]["accuracy"] >= 0.5  # chance is 1/4
    assert sum(stage["test"][k] for k in ("correct", "wrong", "ambiguous", "confused", "ignorant")) == pytest.approx(1)
    assert stage["features"]["bn"] == sum(len(n.features) for n in learner.networks.values()) > 0
    rows = stage["confusion"]
    assert sum(sum(r["as"].values()) + r["ambiguous"] + r["confused"] + r["ignorant"] for r in rows.values()) == 4 * 7
    saved = DistinctiveFeatureLearner.load(tmp_path / "learner.json")
    assert saved.state_dict(training=False) == learner.state_dict(training=False) and not saved.trainable


def test_interrupted_fold_resumes_to_the_same_result(small_task, tmp_path, monkeypatch):
    """Four expert stages; the run is cut after the first cycle of the last, which learns expert features."""
    whole, learner = make_fold(small_task, tmp_path / "whole").run(max_cycles=4, stages=4)
    whole = whole.to_json()  # the report entry as report.json holds it
    assert [s["stage"] for s in whole["stages"]] == [0, 1, 2, 3, 4]
    assert whole["stages"][-1]["expert_per_cycle"][0] > 0
    cut_at = sum(s["cycles"] for s in whole["stages"][:-1]) + 1

    def stop(cycle):
        if cycle == cut_at:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        make_fold(small_task, tmp_path / "cut").run(max_cycles=4, stages=4, after_cycle=stop)
    saved = json.loads((tmp_path / "cut" / "checkpoint.json").read_text())
    assert saved["state"]["total_cycles"] == cut_at and saved["state"]["stage"] == 4 and len(saved["state"]["stages"]) == 4
    assert saved["learner"]["instances"]["values"]["relative"]  # to the value cache, written beside it
    with monkeypatch.context() as patch:  # as version 3 wrote them: absolute instance values
        state_dict = DistinctiveFeatureLearner.state_dict
        patch.setattr(DistinctiveFeatureLearner, "state_dict", lambda self, training=True, table=None, env=None:
                      state_dict(self, training, table))
        with pytest.raises(KeyboardInterrupt):
            make_fold(small_task, tmp_path / "old").run(max_cycles=4, stages=4, after_cycle=stop)
    old = json.loads((tmp_path / "old" / "checkpoint.json").read_text())
    assert "relative" not in old["learner"]["instances"]["values"]
    (tmp_path / "old" / "checkpoint.json").write_text(json.dumps({**old, "version": 3}))
    for folder in ("cut", "old"):
        resumed, again = make_fold(small_task, tmp_path / folder).run(max_cycles=4, stages=4, resume=True)  # fresh image sets
        resumed = resumed.to_json()  # the report entry as report.json holds it
        assert without_timing(resumed) == without_timing(whole)
        assert json.dumps(again.state_dict()) == json.dumps(learner.state_dict())


def test_a_fold_checkpoint_of_schema_0_resumes_and_a_newer_schema_is_refused_in_one_line(small_task, tmp_path):
    """A checkpoint written before schemas were numbered and before some options existed (its config and
    its learner state without them) resumes to the same result: both migrations fill the options' values
    then, the thesis's here. One of a newer schema is refused in one line that names it."""
    whole, _ = make_fold(small_task, tmp_path / "whole").run(max_cycles=3, stages=1)

    def stop(cycle):
        if cycle == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        make_fold(small_task, tmp_path / "cut").run(max_cycles=3, stages=1, after_cycle=stop)
    path = tmp_path / "cut" / "checkpoint.json"
    saved = json.loads(path.read_text())
    assert saved["schema"] == 2 and saved["learner"]["schema"] == 2
    newer = ("leak", "contrast", "texture_parts", "calibrate", "regions", "test_information", "distinctions")
    old = {**{k: v for k, v in saved.items() if k != "schema"}, "config": {k: v for k, v in saved["config"].items()
                                                                            if k not in (*newer, "dynamic")},
           "learner": {k: v for k, v in saved["learner"].items() if k not in (*newer, "schema")}}
    path.write_text(json.dumps({**old, "schema": 3}))
    with pytest.raises(InputError, match=r"checkpoint.json: a fold checkpoint of schema 3, newer than this ftorch reads \(2\)"):
        make_fold(small_task, tmp_path / "cut").run(max_cycles=3, stages=1, resume=True)
    path.write_text(json.dumps(old))
    resumed, _ = make_fold(small_task, tmp_path / "cut").run(max_cycles=3, stages=1, resume=True)
    assert without_timing(resumed.to_json()) == without_timing(whole.to_json())


def test_checkpoints_are_written_once_their_interval_has_passed(small_task, tmp_path, monkeypatch):
    """checkpoint_every 0 writes after every cycle and stage; a long interval writes only at the end;
    both learn the same. The clock is faked: each reading advances it by one second."""
    writes = []
    save = Fold._save
    monkeypatch.setattr(Fold, "_save", lambda self, learner, order, state: (writes.append(state.progress.total_cycles),
                                                                             save(self, learner, order, state)))
    every, learner = make_fold(small_task, tmp_path / "every").run(max_cycles=2, stages=1)
    every = every.to_json()  # the report entry as report.json holds it
    steps = len(writes)
    assert steps == every["stages"][-1]["cycles"] + every["stages"][0]["cycles"] + 2  # each cycle and stage end
    clock = iter(range(10**6))
    monkeypatch.setattr("training.recognition.protocol.time.perf_counter", lambda: float(next(clock)))
    seen, writes[:] = [], []
    once, again = make_fold(small_task, tmp_path / "once").run(max_cycles=2, stages=1, checkpoint_every=10**6,
                                                               after_cycle=seen.append)
    once = once.to_json()  # the report entry as report.json holds it
    assert len(writes) == 1 and seen == []  # only the final state
    assert without_timing(once) == without_timing(every)
    assert json.dumps(again.state_dict()) == json.dumps(learner.state_dict())
    writes[:] = []
    make_fold(small_task, tmp_path / "some").run(max_cycles=2, stages=1, checkpoint_every=5)
    assert 1 < len(writes) < steps


def test_damaged_foreign_and_mismatched_checkpoints_are_refused(small_task, tmp_path):
    fold = make_fold(small_task, tmp_path)
    fold.run(max_cycles=1)
    text = fold.checkpoint.read_text()
    fold.checkpoint.write_text(text[: len(text) // 2])
    with pytest.raises(InputError, match="not a readable checkpoint"):
        fold.run(max_cycles=1, resume=True)
    fold.checkpoint.write_text(json.dumps({"weights": [1, 2, 3]}))
    with pytest.raises(InputError, match="not an ftorch checkpoint"):
        fold.run(max_cycles=1, resume=True)
    fold.checkpoint.write_text(text)
    fold.config = replace(fold.config, seed=1)
    with pytest.raises(InputError, match="different run configuration"):
        fold.run(max_cycles=1, resume=True)
    with pytest.raises(InputError, match="kind 'learner', expected 'fold'"):
        (tmp_path / "learner.json").replace(fold.checkpoint)
        fold.config = replace(fold.config, seed=0)
        fold.run(max_cycles=1, resume=True)
    broken = json.loads(fold.checkpoint.read_text())
    del broken["learner"]["networks"]
    fold.checkpoint.write_text(json.dumps(broken))
    with pytest.raises(InputError, match="damaged learner checkpoint .*networks"):
        DistinctiveFeatureLearner.load(fold.checkpoint)
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temporary files behind


def test_recognize_command_report_is_reproducible_and_complete(tmp_path, capsys):
    args = ["recognize", "--task", "plym", "--size", "40", "--folds", "1", "--seed", "3", "--device", "cpu", "--quiet",
            "--stages", "2", "--max-cycles", "6", "--min-information", "0"]
    assert run.main([*args, "--out", str(tmp_path / "a")]) == 0
    assert run.main([*args, "--out", str(tmp_path / "b")]) == 0
    printed = capsys.readouterr().out
    assert "report:" in printed and "tensorboard --logdir" in printed
    texts = [re.sub(r'"seconds": [0-9.e+-]+', '"seconds": _', (tmp_path / x / "report.json").read_text()) for x in "ab"]
    assert texts[0] == texts[1]  # byte-identical but for the timings
    a = json.loads((tmp_path / "a" / "report.json").read_text())
    assert {"task", "classes", "seed", "device", "machine", "seconds", "folds", "average"} <= set(a)
    # the report names what fixes its last bits besides the seed: processor, CPU kernels, versions
    assert a["machine"]["cpu_kernels"] == torch.backends.cpu.get_cpu_capability()
    assert a["machine"]["torch"] == torch.__version__ and a["machine"]["numpy"] == np.__version__
    assert "gpu" not in a["machine"] and a["machine"]["cpu"]
    assert a["folds"][0]["machine"] == a["machine"]  # where the fold trained: here, the runner's machine
    stage = a["folds"][0]["stages"][0]
    assert {"stage", "t_ksd", "cycles", "presentations", "train_learned", "test", "features", "seconds"} <= set(stage)
    assert set(stage["test"]) == {"accuracy", "top1", "correct", "wrong", "ambiguous", "confused", "ignorant"}
    assert set(stage["features"]) == {"bn", "different", "queried", "sampled"}
    assert set(a["average"]) == {"stage0", "final"} and set(a["average"]["final"]) == {"test", "features"}
    markdown = (tmp_path / "a" / "report.md").read_text()
    assert f"device cpu ({a['machine']['cpu']}, {a['machine']['cpu_kernels']} kernels; torch {torch.__version__}" in markdown
    assert "other machines" not in markdown
    a["folds"][0]["machine"] = {**a["machine"], "cpu": "Another CPU"}  # as a Ray node of another kind would report
    write_markdown(tmp_path / "elsewhere.md", Report.from_json(a), [])
    assert "Folds trained on other machines: fold 1 on Another CPU, " in (tmp_path / "elsewhere.md").read_text()
    assert "gpu_memory_mib" not in a and "gpu_memory_mib" not in a["folds"][0] and "GPU memory" not in markdown
    a["gpu_memory_mib"] = {"fold 1 seed 3": 812.4, "fold 1 seed 4": 790.0}  # as a run on a GPU reports each task
    write_markdown(tmp_path / "gpu.md", Report.from_json(a), [])
    assert "Peak GPU memory per task (torch's allocator, MiB): fold 1 seed 3 812; fold 1 seed 4 790." in (tmp_path / "gpu.md").read_text()
    assert "| task | cls. | fold | acc." in markdown and "amb. | cnf. | ign. | # feats. BN |" in markdown
    for figure in ("fold1/features.png", "fold1/con6_features.png"):
        assert figure in markdown and cv2.imread(str(tmp_path / "a" / figure)) is not None
    learner = DistinctiveFeatureLearner.load(tmp_path / "a" / "fold1" / "learner.json")
    bif = BIFReader(str(tmp_path / "a" / "fold1" / "networks" / "cube.bif")).get_model()
    assert bif.get_cpds("class").values[1] == pytest.approx(learner.networks["cube"].prior[1])
    assert len(bif.nodes()) == len(learner.networks["cube"].features) + 1
    assert "table 5.1 form" in markdown and "every stage" in markdown and "curves.png" in markdown
    assert cv2.imread(str(tmp_path / "a" / "curves.png")) is not None
    check_events(tmp_path / "a" / "tensorboard" / "fold1", a["folds"][0], a["config"])


def check_events(folder, fold: dict, config: dict) -> None:
    """Every documented TensorBoard tag is there, with the report's values at each stage, and the
    fold's stage curves (the report's, drawn again) at its final stage."""
    events = EventAccumulator(str(folder), size_guidance={"scalars": 0, "images": 0})
    events.Reload()
    tags = set(events.Tags()["scalars"])
    stages = fold["stages"]
    for block, keys in (("test", ("accuracy", "top1", "correct", "wrong", "ambiguous", "confused", "ignorant")),
                        ("features", ("bn", "different", "queried", "sampled"))):
        for key in keys:
            assert [e.value for e in events.Scalars(f"{block}/{key}")] == pytest.approx([s[block][key] for s in stages])
            assert [e.step for e in events.Scalars(f"{block}/{key}")] == [s["step"] for s in stages]
    for key in ("t_ksd", "ksd_min", "cycles", "target_met", "train_learned", "classes"):
        assert [e.value for e in events.Scalars(f"stage/{key}")] == pytest.approx([float(s[key]) for s in stages])
    mistakes = [m for s in stages for m in s["mistakes_per_cycle"]]
    assert [e.value for e in events.Scalars("train/mistakes_per_cycle")] == mistakes
    assert {"train/expert_per_cycle", "train/discarded_per_cycle", "train/features_per_cycle", "train/ksd_min"} <= tags
    assert events.Scalars("hparam/accuracy")[0].value == pytest.approx(stages[-1]["test"]["accuracy"])
    assert events.Scalars("hparam/top1")[0].value == pytest.approx(stages[-1]["test"]["top1"])
    assert "_hparams_/session_start_info" in events.PluginTagToContent("hparams")
    assert "features/features" in events.Tags()["images"]
    [curves] = events.Images("figures/curves")
    drawn = cv2.cvtColor(cv2.imdecode(np.frombuffer(curves.encoded_image_string, np.uint8), cv2.IMREAD_COLOR),
                         cv2.COLOR_BGR2RGB)
    assert curves.step == stages[-1]["step"] and np.array_equal(drawn, figure_rgb(fold_curves_figure(FoldEntry.from_json(fold), config)))


def test_folder_task_trains_and_a_saved_learner_evaluates_new_images(small_task, tmp_path, capsys):
    for image, label, name in zip(small_task.images, small_task.labels, small_task.names):
        (tmp_path / "data" / label).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tmp_path / "data" / label / f"{name}.png"), (image.numpy() * 255).round().astype(np.uint8))
    common = ["--task", "folder", "--data", str(tmp_path / "data"), "--device", "cpu", "--quiet"]
    assert run.main(["recognize", *common, "--folds", "1", "--out", str(tmp_path / "run")]) == 0
    assert run.main(["evaluate", "--learner", str(tmp_path / "run/fold1/learner.json"), *common,
                     "--out", str(tmp_path / "eval")]) == 0
    result = json.loads((tmp_path / "eval" / "evaluate.json").read_text())
    assert len(result["images"]) == 60 and result["test"]["accuracy"] > 0.5
    assert "| class |" in (tmp_path / "eval" / "evaluate.md").read_text()
    # --learner takes the fold's checkpoint.json as well: the same networks, the same answers
    assert run.main(["evaluate", "--learner", str(tmp_path / "run/fold1/checkpoint.json"), *common,
                     "--out", str(tmp_path / "again")]) == 0
    again = json.loads((tmp_path / "again" / "evaluate.json").read_text())
    assert {k: v for k, v in again.items() if k != "checkpoint"} == {k: v for k, v in result.items() if k != "checkpoint"}
    assert run.main(["evaluate", "--learner", str(tmp_path / "run"), *common, "--out", str(tmp_path / "e3")]) == 2
    assert run.main(["robustness", "--run", str(tmp_path / "run/fold1/checkpoint.json")]) == 2


@pytest.mark.parametrize("argv, message", [
    (["recognize", "--stages", "many"], "expected a number of expert stages"),
    (["recognize", "--n-fgen", "0"], "--n-fgen: 0: expected a number of candidates (an integer from 1 to 1000)"),
    (["recognize", "--size", "8"], "--size: 8: expected an image side in pixels (an integer from 9 to 8192)"),
    (["recognize", "--task", "coil", "--data", "/nonexistent"], "no such folder"),
    (["evaluate", "--learner", "/nonexistent.json", "--data", "images"], "no such checkpoint file"),
])
def test_bad_runs_get_one_clear_line(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # outputs are checked, hence made, before anything else
    try:
        code = run.main(argv)
    except SystemExit as exit:  # argparse refuses bad option values itself
        code = exit.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and message in err and "\n" not in err


def test_same_seed_same_report_across_processes(tmp_path):
    """Python randomizes str hashes per process: no result may depend on set iteration order."""
    texts = []
    for hash_seed in ("1", "2"):
        done = subprocess.run([sys.executable, "-m", "training.run", "recognize", "--task", "plym", "--size", "32",
                               "--folds", "1", "--device", "cpu", "--quiet", "--out", str(tmp_path / hash_seed)],
                              capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": hash_seed})
        assert done.returncode == 0, done.stderr
        texts.append(re.sub(r'"seconds": [0-9.e+-]+', '"seconds": _', (tmp_path / hash_seed / "report.json").read_text()))
    assert texts[0] == texts[1]


@pytest.mark.parametrize("t, ksd_min, expected", [
    (0.0, 0.0, 0.5), (0.0, 0.3, 0.5), (0.5, 0.9, 0.75), (0.75, 0.8, 0.875), (0.875, 1.0, 0.9375),
    (0.9375, 1.0, 0.96875), (0.96875, 1.0, 1.0),  # 0.984 > 0.98 becomes 1
    (0.75, 0.6, 0.8),  # a missed target ramps from KSD_min, not t
])
def test_t_ksd_schedule(t, ksd_min, expected):
    assert next_target(t, ksd_min) == pytest.approx(expected)


def test_expert_stages_raise_the_target_and_test_after_each(small_task, tmp_path):
    entry, learner = make_fold(small_task, tmp_path).run(max_cycles=4, stages=4)
    entry = entry.to_json()  # the report entry as report.json holds it
    stages = entry["stages"]
    assert [s["t_ksd"] for s in stages][:2] == [0.0, 0.5]
    for before, after in zip(stages, stages[1:]):
        assert after["t_ksd"] == pytest.approx(next_target(before["t_ksd"], before["ksd_min"]))
        assert after["presentations"] > before["presentations"] and after["features"]["sampled"] >= before["features"]["sampled"]
    assert sum(sum(s["expert_per_cycle"]) for s in stages[1:]) > 0  # expert features were learned
    assert sum(stages[0]["expert_per_cycle"]) == 0  # t = 0: chapter 4 learning only
    for stage in stages:
        assert stage["target_met"] == (stage["train_learned"] and stage["ksd_min"] >= stage["t_ksd"])


def test_incremental_fold_adds_one_class_at_a_time(small_task, tmp_path):
    """Alg. 5.4: two classes first, then one more per phase, each phase alg. 5.3 from t = 0; tests
    only on the classes taught; the learner is kept throughout."""
    entry, learner = make_fold(small_task, tmp_path, incremental=True).run(max_cycles=3, stages=1)
    entry = entry.to_json()  # the report entry as report.json holds it
    stages, classes = entry["stages"], small_task.classes()
    assert [s["classes"] for s in stages] == [2, 2, 3, 3, 4, 4]
    assert [s["t_ksd"] for s in stages][::2] == [0.0, 0.0, 0.0] and [s["step"] for s in stages] == list(range(6))
    assert stages[0]["presentations"] == stages[0]["cycles"] * 2 * 8  # 8 training views per class, 7 test views
    for stage in stages:
        rows = stage["confusion"]
        assert list(rows) == classes[:stage["classes"]]
        assert sum(sum(r["as"].values()) + r["ambiguous"] + r["confused"] + r["ignorant"] for r in rows.values()) == 7 * stage["classes"]
    assert [(a["classes"], a["class"]) for a in entry["added"]] == [(2, classes[1]), (3, classes[2]), (4, classes[3])]
    assert sum(a["sampled"] for a in entry["added"]) == learner.sampled == stages[-1]["features"]["sampled"]
    assert sorted(learner.networks) == sorted(classes)


def test_growth_exponent_of_figure_5_19_recovers_a_known_power_law():
    classes = list(range(2, 21))
    folds = []
    for k, (a, b) in enumerate([(40.0, 1.6), (55.0, 1.6)], 1):
        totals = [round(a * c**b) for c in classes]  # features are counted: the power law to the nearest count
        steps = np.diff([0, *totals])
        folds.append(FoldEntry(k, [], [ClassAdded(c, c, int(n), 0) for c, n in zip(classes, steps)]))
    g = growth(folds).to_json()
    assert g["folds"]["1"]["exponent"] == pytest.approx(1.6, abs=2e-3) == g["folds"]["2"]["exponent"]
    assert g["points"] == 2 * len(classes) and g["interval"][0] < 1.6 < g["interval"][1]
    line = stats.linregress(np.log(classes * 2), np.log([p[1] for k in ("1", "2") for p in g["sampled"][k]]))
    assert g["exponent"] == pytest.approx(line.slope) and g["scale"] == pytest.approx(np.exp(line.intercept))
    assert g["folds"]["1"]["scale"] == pytest.approx(40.0, rel=1e-2)  # a of a * classes**b
    assert g["interval"][1] - g["interval"][0] == pytest.approx(2 * stats.t.ppf(0.975, 2 * len(classes) - 2) * line.stderr)


def test_growth_over_seeds_is_a_t_interval_of_the_seeds_exponents():
    classes = list(range(2, 21))
    truth = [1.5, 1.7, 1.6, 1.9]
    runs = [FoldEntry(1, [], [ClassAdded(c, c, int(n), 0) for c, n in
                              zip(classes, np.diff([0, *[round(30.0 * c**b) for c in classes]]))]) for b in truth]
    g = growth_over_seeds(runs, [0, 1, 2, 3]).to_json()
    assert g["exponents"] == pytest.approx(truth, abs=2e-3) and g["seeds"] == [0, 1, 2, 3] and g["fold"] == 1
    b = np.array(g["exponents"])
    half = stats.t.ppf(0.975, 3) * b.std(ddof=1) / 2  # n - 1 = 3 degrees of freedom, sqrt(4) = 2
    assert g["mean"] == pytest.approx(b.mean()) and g["interval"] == pytest.approx([b.mean() - half, b.mean() + half])
    assert g["exponents"][2] == pytest.approx(growth(runs[2:3]).exponent)  # each seed's own fit of figure 5.19
    assert g["sampled"]["2"] == growth(runs[2:3]).sampled["1"]  # each seed's curve, drawn in growth.png


def stage_tested(accuracy: float, queried: float, classes: int = 4) -> StageEntry:
    """A stage entry of which a seed study reads the accuracy, the features queried and the classes taught."""
    return StageEntry(Stage(0, 0, classes, 0.0, 1, 1, True, 1.0, True, [0], [0], [0]),
                      Scores(accuracy=accuracy, correct=0, wrong=0, ambiguous=0, confused=0, ignorant=0),
                      FeatureBlock(0, 0, queried, 0), {}, 0.0)


def test_seed_study_is_a_paired_one_tailed_t_test():
    runs = [FoldEntry(1, [stage_tested(a, 20.0 + a), stage_tested(b, 8.0 + b)]) for a, b in [(.6, .8), (.62, .75), (.55, .81), (.64, .7)]]
    study = seed_study(runs, [0, 1, 2, 3]).to_json()
    d = np.array([.8 - .6, .75 - .62, .81 - .55, .7 - .64])
    t = d.mean() / (d.std(ddof=1) / 2)
    assert study["t"] == pytest.approx(t)
    assert study["p"] == pytest.approx(stats.t.sf(t, 3))
    assert study["novice"]["mean"] == pytest.approx(np.mean([.6, .62, .55, .64]))
    assert study["expert"]["sd"] == pytest.approx(np.std([.8, .75, .81, .7], ddof=1))

    def phase(classes, novice, expert):  # alg. 5.4: stage 0 and one expert stage per class count
        return [stage_tested(a, q, classes) for a, q in ((novice, 9.0), (expert, 4.0))]

    incremental = [FoldEntry(1, phase(2, .95, .97) + phase(3, a, b)) for a, b in [(.6, .8), (.62, .75), (.55, .81)]]
    study = seed_study(incremental, [0, 1, 2]).to_json()  # the novices are stage 0 with all three classes, not with two
    assert study["novice"]["values"] == [.6, .62, .55] and study["expert"]["values"] == [.8, .75, .81]
    assert study["novice_queried"]["mean"] == 9.0 and study["expert_queried"]["mean"] == 4.0


def test_seeds_and_incremental_commands(tmp_path, capsys):
    common = ["--task", "plym", "--classes", "3", "--size", "32", "--folds", "1", "--device", "cpu", "--quiet",
              "--max-cycles", "3", "--min-information", "0"]
    assert run.main(["recognize", *common, "--stages", "1", "--seeds", "2", "--out", str(tmp_path / "s")]) == 0
    report = json.loads((tmp_path / "s" / "report.json").read_text())
    assert report["seeds"]["seeds"] == [0, 1] and len(report["seeds"]["novice"]["values"]) == 2
    assert report["seeds"]["novice"]["values"][0] == report["folds"][0]["stages"][0]["test"]["accuracy"]
    assert (tmp_path / "s" / "seed1" / "fold1" / "learner.json").is_file()
    assert "2 seeds, fold 1: novice accuracy" in capsys.readouterr().out
    assert run.main(["incremental", *common, "--stages", "0", "--seeds", "2", "--out", str(tmp_path / "i")]) == 0
    report = json.loads((tmp_path / "i" / "report.json").read_text())
    assert report["config"]["incremental"] and [s["classes"] for s in report["folds"][0]["stages"]] == [2, 3]
    markdown = (tmp_path / "i" / "report.md").read_text()
    assert "figure 5.13 form" in markdown and "incremental, alg. 5.4" in markdown
    growth_seeds = report["seeds"]["growth"]
    assert growth_seeds["seeds"] == [0, 1] and growth_seeds["exponents"][0] == report["growth"]["folds"]["1"]["exponent"]
    assert "(figure 5.19), fold 1" in markdown and "2 seeds, fold 1: features sampled ~ classes^b" in capsys.readouterr().out
    assert "](growth.png)" in (tmp_path / "i" / "report.md").read_text()
    assert cv2.imread(str(tmp_path / "i" / "growth.png")) is not None
    check_events(tmp_path / "i" / "tensorboard" / "fold1", report["folds"][0], report["config"])


def test_the_run_config_defaults_to_the_library_learner_and_the_fold_state_is_checked():
    learner = RunConfig("t").new_learner(3)
    assert learner.settings == DistinctiveFeatureLearner().settings == LearnerSettings()
    assert (learner.settings.n_ex, learner.settings.min_information, learner.seed) == (5, 0.1, 3)
    assert RunConfig("t", seed=2).fold_seed(3) == 2003
    state = FoldState(Progress(phase=1, added=[ClassAdded(3, "cube", 4, 2)]))
    assert FoldState.from_dict(json.loads(json.dumps(state.to_dict()))) == state
    with pytest.raises(ValueError, match="progress fields"):
        FoldState.from_dict({**state.to_dict(), "extra": 1})
    with pytest.raises(ValueError, match="t_KSD"):
        FoldState.from_dict({**state.to_dict(), "t_ksd": 2.0})
