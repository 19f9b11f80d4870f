"""The recognition protocol of 4.5: train on one fold until the training set is learned, test, checkpoint.

Training presents the training images one by one in a fresh random permutation each cycle
and stops after the first cycle without a mistake (or ``max_cycles``). Example images for
alg. 4.8 come from the training set. After every cycle the fold's state (learner, the
permutation generator, the value cache, the stages so far) is written to its checkpoint, so
an interrupted fold resumes to exactly the result it would have reached.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ftorch.checkpoint import decode_array, encode_array, load_checkpoint, save_checkpoint
from ftorch.environment import ImageSet
from ftorch.errors import InputError
from ftorch.learner import DistinctiveFeatureLearner
from ftorch.recognition import Recognition, accuracy, outcome

OUTCOMES = ("correct", "wrong", "ambiguous", "confused", "ignorant")
FOLD_KIND = "fold"


def test_block(recognitions: list[Recognition], labels: list[frozenset], classes: list) -> dict:
    """Accuracy (def. 4.6) and the proportions of the five outcomes (def. 4.5) over a test set."""
    outcomes = Counter(outcome(r.recognized, t) for r, t in zip(recognitions, labels))
    n = max(len(recognitions), 1)
    block = {"accuracy": float(np.mean([accuracy(r.recognized, t, len(classes)) for r, t in zip(recognitions, labels)]))}
    block.update({k: outcomes[k] / n for k in OUTCOMES})
    return block


def confusion(recognitions: list[Recognition], labels: list[frozenset], classes: list, networks: dict) -> dict:
    """Tables 4.3 and 4.4 for single-class images: per true class, recognized-as counts for correct
    and wrong results, the ambiguous / confused / ignorant counts, the network size, and the
    false-positive classes of ambiguous results."""
    rows = {c: {"as": dict.fromkeys(classes, 0), "ambiguous": 0, "confused": 0, "ignorant": 0,
                "features": len(networks[c].features) if c in networks else 0,
                "ambiguous_with": dict.fromkeys(classes, 0)} for c in classes}
    for rec, true in zip(recognitions, labels):
        if len(true) != 1:
            continue
        (c,) = true
        kind = outcome(rec.recognized, true)
        if kind in ("correct", "wrong"):
            for r in rec.recognized:
                rows[c]["as"][r] += 1
        else:
            rows[c][kind] += 1
        if kind == "ambiguous":
            for r in rec.recognized - true:
                rows[c]["ambiguous_with"][r] += 1
    return rows


def feature_block(learner: DistinctiveFeatureLearner, recognitions: list[Recognition]) -> dict:
    """Table 4.2's feature columns: nodes in all networks, different features, mean queried, sampled."""
    nodes = [f for net in learner.networks.values() for f in net.features]
    return {"bn": len(nodes), "different": len(set(nodes)),
            "queried": float(np.mean([len(r.queried) for r in recognitions])) if recognitions else 0.0,
            "sampled": learner.sampled}


@dataclass
class Fold:
    """One fold of a task: its image sets, the run configuration and where its files go."""

    fold: int
    train: ImageSet
    test: ImageSet
    config: dict
    folder: Path
    classes: list
    progress: bool = True
    logger: object = None

    @property
    def checkpoint(self) -> Path:
        return self.folder / "checkpoint.json"

    def _save(self, learner, order, history, stages, seconds, done):
        save_checkpoint(self.checkpoint, FOLD_KIND, {
            "config": self.config, "fold": self.fold, "history": history, "stages": stages, "done": done,
            "seconds": seconds, "order": encode_array(order.get_state().numpy().astype(np.float64)),
            "learner": learner.state_dict(), "cache": self.train.cache_state()})

    def _resume(self):
        data = load_checkpoint(self.checkpoint, FOLD_KIND)
        if data.get("config") != self.config or data.get("fold") != self.fold:
            raise InputError(f"{self.checkpoint}: written by a different run configuration; "
                             f"use another --out or delete it to start afresh")
        learner = DistinctiveFeatureLearner()
        order = torch.Generator()
        try:
            learner.load_state_dict(data["learner"])
            order.set_state(torch.from_numpy(decode_array(data["order"]).astype(np.uint8)))
            self.train.load_cache_state(data["cache"])
        except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as err:
            raise InputError(f"{self.checkpoint}: damaged fold checkpoint ({type(err).__name__}: {err})") from None
        return learner, order, data["history"], data["stages"], data["seconds"], data["done"]

    def run(self, max_cycles: int, resume: bool = False, after_cycle=None) -> tuple[dict, DistinctiveFeatureLearner]:
        """Train stage 0 and test; returns the fold's report entry and the learner (also saved as
        learner.json). ``after_cycle(cycle)`` is called after each cycle's checkpoint is written."""
        seed = self.config["seed"] * 1000 + self.fold
        if resume and self.checkpoint.is_file():
            learner, order, history, stages, elapsed, done = self._resume()
        else:
            learner = DistinctiveFeatureLearner(self.config["n_ex"], self.config["n_fgen"], seed=seed)
            order = torch.Generator().manual_seed(seed)
            history, stages, elapsed, done = [], [], 0.0, False
        start = time.perf_counter() - elapsed
        with tqdm(total=max_cycles, initial=len(history), desc=f"fold {self.fold} cycles", unit="cycle",
                  disable=not self.progress, leave=False) as bar:
            while not done and len(history) < max_cycles:
                mistakes = sum(learner.learn(self.train, i)[1] != "correct"
                               for i in torch.randperm(len(self.train), generator=order).tolist())
                history.append(mistakes)
                done = mistakes == 0
                bar.update(1)
                bar.set_postfix(mistakes=mistakes, features=sum(len(n.features) for n in learner.networks.values()))
                if self.logger is not None:
                    self.logger.add_scalar("train/mistakes_per_cycle", mistakes, len(history))
                self._save(learner, order, history, stages, time.perf_counter() - start, done)
                if after_cycle is not None:
                    after_cycle(len(history))
        if not stages:
            stages.append(self._stage(learner, history, time.perf_counter() - start))
            self._save(learner, order, history, stages, time.perf_counter() - start, True)
        learner.save(self.folder / "learner.json")
        return {"fold": self.fold, "stages": stages}, learner

    def _stage(self, learner, history, seconds) -> dict:
        recognitions = learner.recognize_many(self.test, range(len(self.test)))
        stage = {"stage": 0, "t_ksd": 0.0, "cycles": len(history), "presentations": learner.presentations,
                 "train_learned": bool(history and history[-1] == 0), "mistakes_per_cycle": list(history),
                 "test": test_block(recognitions, self.test.labels, self.classes),
                 "features": feature_block(learner, recognitions),
                 "confusion": confusion(recognitions, self.test.labels, self.classes, learner.networks),
                 "seconds": seconds}
        if self.logger is not None:
            for key, value in stage["test"].items():
                self.logger.add_scalar(f"test/{key}", value, 0)
            for key, value in stage["features"].items():
                self.logger.add_scalar(f"features/{key}", value, 0)
        return stage
