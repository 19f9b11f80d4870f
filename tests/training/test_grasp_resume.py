"""``grasp --resume``: an interrupted run goes on from each fold's last finished epoch to the same
report.json as an uninterrupted one; the grasp learner's training state restores exactly; bad
checkpoints and changed options are refused in one line."""
import json
import re

from ftorch import FeatureSpace
from ftorch.grasp.learner import GraspLearner
from training import run
from training.grasping import command
from training.grasping.experiment import GraspFold, simulate_pool
from training.grasping.haptics import HapticController

ARGV = ["grasp", "--experiment", "mixed", "--pool", "8", "--best", "3", "--epochs", "3", "--folds", "1", "--online",
        "--device", "cpu", "--quiet"]


def timeless(path):
    return re.sub(r'"seconds": [0-9.e+-]+', "_", path.read_text())


def test_a_learners_training_state_goes_on_learning_exactly():
    """Two epochs, the fold's state through JSON into a fold built afresh, one epoch more: the same
    features, models, instance lists and generator as the fold that was never stopped."""
    pool = simulate_pool("mixed", 6, seed=2, size=64, controller=HapticController())

    def fold():
        return GraspFold(1, "mixed", pool, 2, FeatureSpace(), GraspLearner(seed=7), HapticController(), seed=2)

    whole, cut = fold(), fold()
    whole.fit(3, online=True)
    cut.fit(2, online=True)
    saved = json.dumps(cut.state_dict())
    assert sum(len(s) for s in cut.learner.sets.values()) > 0 and any(s.images for s in cut.learner.sets.values())
    resumed = fold()
    resumed.load_state_dict(json.loads(saved))
    assert json.dumps(resumed.state_dict()) == saved
    resumed.fit(3, online=True)
    assert resumed.epochs == whole.epochs and resumed.predictions == whole.predictions
    assert json.dumps(resumed.state_dict()) == json.dumps(whole.state_dict())


def test_an_interrupted_grasp_run_resumes_to_the_same_report(tmp_path, monkeypatch, capsys):
    whole = tmp_path / "whole"
    assert run.main([*ARGV, "--out", str(whole), "--resume"]) == 0  # --resume of an empty folder starts afresh
    assert f"note: no checkpoint in {whole}; --resume starts afresh" in capsys.readouterr().err
    save = command._save

    def interrupt_at(folder: str, epochs: int):
        def saving(path, config, fold, entry=None):
            save(path, config, fold, entry)
            if path.parent.name == folder and len(fold.epochs) == epochs and entry is None:
                raise KeyboardInterrupt
        return saving

    cut = tmp_path / "cut"
    with monkeypatch.context() as patch:  # cut after the off-line fold's first epoch
        patch.setattr(command, "_save", interrupt_at("fold1", 1))
        assert run.main([*ARGV, "--out", str(cut)]) == 130
    assert f"the checkpoints in {cut} keep the epochs finished up to their last write: run the same command with --resume" \
        in capsys.readouterr().err
    state = json.loads((cut / "fold1" / "checkpoint.json").read_text())
    assert not state["done"] and len(state["state"]["epochs"]) == 1 and not (cut / "report.json").exists()
    with monkeypatch.context() as patch:  # resumed, and cut again after the on-line fold's second epoch
        patch.setattr(command, "_save", interrupt_at("fold1-online", 2))
        assert run.main([*ARGV, "--out", str(cut), "--resume"]) == 130
    assert json.loads((cut / "fold1" / "checkpoint.json").read_text())["done"]
    assert run.main([*ARGV, "--out", str(cut), "--resume"]) == 0
    assert timeless(cut / "report.json") == timeless(whole / "report.json")
    assert (cut / "report.md").read_text().split("\n", 3)[3] == (whole / "report.md").read_text().split("\n", 3)[3]
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    for name in ("fold1", "fold1-online"):  # each fold's TensorBoard run written once, as the whole run's
        logs = [EventAccumulator(str(folder / "tensorboard" / name)) for folder in (whole, cut)]
        mistakes = [[(e.step, e.value) for e in log.Reload().Scalars("epoch/mistakes")] for log in logs]
        assert mistakes[0] == mistakes[1] and [step for step, _ in mistakes[1]] == [1, 2, 3][: len(mistakes[1])]
    capsys.readouterr()
    assert run.main([*ARGV, "--out", str(cut), "--resume"]) == 0  # every fold ended: the same report again
    assert timeless(cut / "report.json") == timeless(whole / "report.json")


def test_a_grasp_resume_under_other_options_or_from_a_bad_checkpoint_is_refused(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    save = command._save

    def interrupt(path, config, fold, entry=None):
        save(path, config, fold, entry)
        raise KeyboardInterrupt

    monkeypatch.setattr(command, "_save", interrupt)
    assert run.main([*ARGV, "--out", str(out)]) == 130
    monkeypatch.setattr(command, "_save", save)
    checkpoint = out / "fold1" / "checkpoint.json"
    text = checkpoint.read_text()
    capsys.readouterr()

    def refused(message, *extra):
        assert run.main([*ARGV, "--out", str(out), "--resume", *extra]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err

    refused("written by a different run configuration", "--t-dtheta", "12")
    refused("written by a different run configuration", "--finger-choice", "thesis")
    assert run.main([*ARGV, "--out", str(out)]) == 2 and "--resume continues it" in capsys.readouterr().err
    checkpoint.write_text(text[: len(text) // 2])
    refused("not a readable checkpoint")
    checkpoint.write_text(json.dumps({**json.loads(text), "kind": "fold"}))
    refused("kind 'fold', expected 'grasp-fold'")
    for damage in (lambda d: d["state"]["learner"]["sets"][0].__setitem__("source_of_row", [99]),
                   lambda d: d["state"]["learner"]["sets"][1]["images"].append(["square", 2, 1]),
                   lambda d: d["state"].__setitem__("epochs", []),
                   lambda d: d["state"]["learner"].__setitem__("generator", {"shape": [3]}),
                   lambda d: d.__setitem__("done", "yes")):
        data = json.loads(text)
        damage(data)
        checkpoint.write_text(json.dumps(data))
        refused("damaged grasp fold checkpoint")
    data = json.loads(text)
    assert list(data)[-1] == list(data["state"]["learner"])[-1] == "schema" and data["schema"] == data["state"]["learner"]["schema"] == 1
    checkpoint.write_text(json.dumps({**data, "schema": 2}))
    refused(f"{checkpoint}: a grasp fold checkpoint of schema 2, newer than this ftorch reads (1)")
    checkpoint.write_text(json.dumps({**data, "state": {**data["state"], "learner": {**data["state"]["learner"], "schema": 2}}}))
    refused(f"{checkpoint}: a grasp learner state of schema 2, newer than this ftorch reads (1)")
    del data["schema"], data["state"]["learner"]["schema"]  # a checkpoint of schema 0, written before the schema was numbered
    checkpoint.write_text(json.dumps(data))
    assert run.main([*ARGV, "--out", str(out), "--resume"]) == 0
    assert list(json.loads((out / "report.json").read_text()))[-1] == "schema"
    checkpoint.write_text(text)
    assert run.main([*ARGV, "--out", str(out), "--resume"]) == 0


def test_resume_and_overwrite_are_one_or_the_other(tmp_path, capsys):
    assert run.main([*ARGV, "--out", str(tmp_path), "--resume", "--overwrite"]) == 2
    assert "give one of them" in capsys.readouterr().err
