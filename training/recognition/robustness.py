"""The robustness benchmark (7.2): a run's learners and the peers on perturbed test views.

For each fold of a ``recognize`` run, the fold's test views are perturbed (:mod:`training.data.perturb`,
seeded from the benchmark seed and the fold) and recognized by the fold's ``learner.json``; with
peers, pixel 1-NN and SIFT matching (:mod:`training.recognition.peers`) are fitted on the same fold's
training views and answer on the same images. ``pair`` images hold two classes: the learner and
SIFT (its two best classes) are scored by def. 4.5/4.6; pixel 1-NN cannot compare an image of
another size and is left out there.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ftorch.errors import InputError
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.packing import pack
from ftorch.space.draw import grid, panel, save_rgb, titled
from ftorch.space.features import Geometric
from ftorch.space.record import FeatureSpace
from training.records import INLINE, OPTIONAL, Record, key

from ..cli.outputs import Ledger
from ..data.datasets import Task
from ..data.perturb import KINDS, perturb, save_examples
from .peers import PixelNN, SiftMatcher, score, score_ranked
from .protocol import test_block
from .records import PeerFold, PeerMeans, PeerScores, SplitPeers, TestBlock, mean_block
from .report import cell

SETS = ("clean", *KINDS)
PEERS = ("pixel_nn", "sift")


@dataclass
class SetScores(Record):
    """The learner on one set: its test block (def. 4.5, 4.6), features queried per image, how often its
    nodes are present on their own class and on the others, and ``flipped``: the share of (node, view)
    states that differ from the clean view's (not on the clean views themselves)."""

    test: TestBlock = field(metadata=INLINE)
    queried: float
    present_own: float | None = field(default=None, metadata=OPTIONAL)
    present_other: float | None = field(default=None, metadata=OPTIONAL)
    flipped: float | None = field(default=None, metadata=OPTIONAL)


@dataclass
class Presence(Record):
    """How often a class network's nodes are present on views of that class and of the others: the
    features' recall and false-alarm rate."""

    present_own: float
    present_other: float


@dataclass
class NodeRow(Record):
    """One network node (4.4.1): its class, number, feature type, how often it is present on its own
    class and on the others per set, and how often it flips under each perturbation."""

    label: str = field(metadata=key("class"))
    node: int
    type: str
    own: dict[str, float | None]
    other: dict[str, float | None]
    flipped: dict[str, float | None]


@dataclass
class TypeRow(Record):
    """:class:`NodeRow` pooled over one feature type: the node count and each rate's mean."""

    nodes: int
    own: dict[str, float | None]
    other: dict[str, float | None]
    flipped: dict[str, float | None]


@dataclass
class Storage(Record):
    """Features per class network (the mean and the largest) and the bytes recognition needs per class."""

    features_per_class: float
    max_features_per_class: int
    bytes_per_class: float


@dataclass
class FoldRobustness(Record):
    """One fold: the learner on every set, what it stores, the seconds taken; on the training views the
    nodes' presence, every node; the peers."""

    fold: int
    ours: dict[str, SetScores]
    storage: Storage
    seconds: dict[str, float]
    train: Presence | None = field(default=None, metadata=OPTIONAL)
    nodes: list[NodeRow] | None = field(default=None, metadata=OPTIONAL)
    peers: dict[str, PeerScores] | None = field(default=None, metadata=OPTIONAL)


@dataclass
class RobustnessAverage(Record):
    """Mean over folds of every score of ours and the peers; the nodes pooled by feature type."""

    ours: dict[str, SetScores]
    train: Presence | None = field(default=None, metadata=OPTIONAL)
    types: dict[str, TypeRow] | None = field(default=None, metadata=OPTIONAL)
    peers: dict[str, dict[str, TestBlock]] | None = field(default=None, metadata=OPTIONAL)


@dataclass
class Robustness(Record):
    """robustness.json: the run, the images' folder, the perturbations' seed and sets, how the learners
    answered, the run's config, every fold and their average."""

    run: str
    data: str
    seed: int
    sets: list[str]
    evidence: str
    test_information: float | None
    learner: dict
    folds: list[FoldRobustness]
    average: RobustnessAverage
    machine: dict
    seconds: float



def views(task: Task, indices: list[int]) -> tuple[list, list[frozenset]]:
    """Images ``indices`` of the task as grey tensors, with their true label sets."""
    return [task.view(i) for i in indices], [frozenset({task.labels[i]}) for i in indices]


def nodes(learner: DistinctiveFeatureLearner) -> list:
    """Every (network, feature) node of the learner."""
    return [(net, f) for net in learner.networks.values() for f in net.features]


def fold_sets(images: list, labels: list[frozenset], kinds: list[str], seed: int) -> dict:
    """Test views as they are ("clean") and under each perturbation: set -> (images, labels)."""
    sets = {"clean": (images, labels)} if "clean" in kinds else {}
    for kind in kinds:
        if kind != "clean":
            sets[kind] = perturb(images, labels, kind, seed)
    return sets


def peer_results(train_images: list, train_labels: list[frozenset], sets: dict, classes: list) -> dict[str, PeerScores]:
    """peer -> its scores per set (def. 4.6, top-1, 4.5 proportions), with what each peer stores per class."""
    nn = PixelNN().fit(train_images, train_labels)
    sift = SiftMatcher().fit(train_images, train_labels)
    pixels = PeerScores(nn.storage_per_class(), views_per_class=len(train_images) / len(classes))
    matched = PeerScores(sift.storage_per_class(), descriptors_per_view=sift.descriptors_per_view())
    for name, (images, labels) in sets.items():
        two = max(len(names) for names in labels)
        if all(nn.supports(tuple(x.shape)) for x in images):
            pixels.sets[name] = score(nn.predict(images), labels, classes)
        matched.sets[name] = score_ranked(sift.ranked(images, n_classes=two), labels, classes)
    return {"pixel_nn": pixels, "sift": matched}


def learner_results(learner: DistinctiveFeatureLearner, sets: dict, classes: list, space: FeatureSpace,
                    progress: bool) -> tuple[dict[str, SetScores], dict]:
    """set -> the learner's test block (def. 4.6 and 4.5), features queried per image and, where
    the clean views were recognized too, ``flipped``: the share of (network node, view) whose state
    (value above the node's cut-point) differs from the clean view's, a measure of how stable the
    features are under the perturbation; and set -> (node states (nodes, views), labels), for
    :func:`node_rows`."""
    out, states = {}, {}
    held = nodes(learner)
    for name, (images, labels) in sets.items():
        env = ImageSet(images, labels, space, progress=progress)
        recognitions = learner.recognize_many(env, range(len(env)))
        out[name] = SetScores(test_block(recognitions, env.labels, classes), float(np.mean([len(r.queried) for r in recognitions])))
        if held:
            states[name] = (node_states(held, env), env.labels)
            seen = presence(held, *states[name])
            out[name].present_own, out[name].present_other = seen.present_own, seen.present_other
    for name in out:
        if name != "clean" and "clean" in states:
            out[name].flipped = float((states[name][0] != states["clean"][0]).mean())
    return out, states


def feature_type(feature) -> str:
    """A node's type in the per-feature tables: texel, edgel pair (alg. 4.10 method 2), geometric
    compound of N parts (method 3), texture (7.2.1), conjunction, disjunction."""
    if isinstance(feature, Geometric):
        return "edgel pair" if feature.describe() == "geometric: edgel-edgel" else f"geometric, {len(feature.parts)} parts"
    return feature.TYPE


def node_rows(held: list, states: dict) -> list[NodeRow]:
    """Per network node (4.4.1): how often it fires (is present) on views of its own class and of
    the others, on every set (``train``: the training views its cut-point was set on), and how
    often its state differs from the clean view's under each perturbation (``flipped``)."""
    rows = []
    number = {}
    for k, (net, feature) in enumerate(held):
        number[net.label] = number.get(net.label, 0) + 1
        row = NodeRow(str(net.label), number[net.label], feature_type(feature), {}, {}, {})
        for name, (state, labels) in states.items():
            own = np.array([net.label in names for names in labels])
            row.own[name] = float(state[k, own].mean()) if own.any() else None
            row.other[name] = float(state[k, ~own].mean()) if (~own).any() else None
            if name not in ("clean", "train") and "clean" in states:
                row.flipped[name] = float((state[k] != states["clean"][0][k]).mean())
        rows.append(row)
    return rows


def type_table(rows: list[NodeRow]) -> dict[str, TypeRow]:
    """:func:`node_rows` pooled by feature type: the node count and each rate's mean over the nodes."""
    out = {}
    for kind in dict.fromkeys(r.type for r in rows):
        of_kind = [r for r in rows if r.type == kind]

        def pooled(rate) -> dict:  # rate: a row's rates by set
            return {name: _mean([rate(r)[name] for r in of_kind]) for name in rate(of_kind[0])}

        out[kind] = TypeRow(len(of_kind), pooled(lambda r: r.own), pooled(lambda r: r.other), pooled(lambda r: r.flipped))
    return out


def _mean(values: list) -> float | None:
    known = [v for v in values if v is not None]
    return float(np.mean(known)) if known else None


def node_states(held: list, env: ImageSet) -> np.ndarray:
    """(nodes, images) bool: each (network, feature) node present (value above its cut-point)."""
    values = env.values([f for _, f in held], list(range(len(env))))
    return values > np.array([net.threshold[f] for net, f in held])[:, None]


def presence(held: list, states: np.ndarray, labels: list[frozenset]) -> Presence:
    """How often a class network's nodes are present on views of that class (``present_own``) and of
    other classes (``present_other``): the features' recall and false-alarm rate."""
    own = np.array([[net.label in names for names in labels] for net, _ in held])
    return Presence(float(states[own].mean()) if own.any() else 0.0, float(states[~own].mean()) if (~own).any() else 0.0)


def learner_storage(learner: DistinctiveFeatureLearner) -> Storage:
    """Features per class network (the mean and the largest) and the bytes recognition needs per
    class, packed as binary (ftorch.recognition.packing)."""
    sizes = [len(net.features) for net in learner.networks.values()]
    return Storage(float(np.mean(sizes)) if sizes else 0.0, max(sizes, default=0),
                   len(pack(learner.networks)) / max(1, len(learner.networks)))


def fold_robustness(task: Task, fold: int, learner: DistinctiveFeatureLearner, kinds: list[str], seed: int,
                    space: FeatureSpace, peers: bool, out: Path | None, progress: bool, ledger: Ledger | None = None
                    ) -> FoldRobustness:
    """One fold: the learner (and peers) on every set; perturbed images saved under ``out``/KIND,
    each recorded in the run's ``ledger`` first where the output lies in the run folder."""
    train, test = task.fold(fold)
    classes = task.classes()
    names = [task.names[i] for i in test]
    sets = fold_sets(*views(task, test), kinds, seed * 1000 + fold)
    if out is not None:
        for name, (images, _) in sets.items():
            if name != "clean":
                save_examples(images, names, out / f"fold{fold}" / name, ledger=ledger)
        (out / f"fold{fold}").mkdir(parents=True, exist_ok=True)
        if ledger is not None:
            ledger.files(out / f"fold{fold}" / "overview.png")
        save_rgb(out / f"fold{fold}" / "overview.png", overview(task, sets, test, f"{task.name}, fold {fold}, perturbation seed {seed}"))
    start = time.perf_counter()
    ours, states = learner_results(learner, sets, classes, space, progress)
    result = FoldRobustness(fold, ours, learner_storage(learner), {"ours": time.perf_counter() - start})
    training = views(task, train)
    held = nodes(learner)
    if held:  # the same on the training views, where the cut-points were set
        trained = ImageSet(*training, space)
        states = {"train": (node_states(held, trained), trained.labels), **states}
        result.train = presence(held, *states["train"])
        result.nodes = node_rows(held, states)
    if peers:
        start = time.perf_counter()
        result.peers = peer_results(*training, sets, classes)
        result.seconds["peers"] = time.perf_counter() - start
    return result


def average(folds: list[FoldRobustness]) -> RobustnessAverage:
    """Mean over folds of every score of ours and the peers."""
    def ours(scores: list[SetScores]) -> SetScores:
        return SetScores(mean_block([s.test for s in scores]), float(np.mean([s.queried for s in scores])),
                         **{k: _mean([getattr(s, k) for s in scores]) for k in ("present_own", "present_other", "flipped")})

    out = RobustnessAverage({s: ours([f.ours[s] for f in folds]) for s in folds[0].ours})
    if all(f.train is not None for f in folds):
        out.train = mean_block([f.train for f in folds])
    if all(f.nodes is not None for f in folds):
        out.types = type_table([r for f in folds for r in f.nodes])
    if folds[0].peers is not None:
        out.peers = {p: {s: mean_block([f.peers[p].sets[s] for f in folds]) for s in folds[0].peers[p].sets} for p in PEERS}
    return out


TABLE_CELLS = "top-1 accuracy / accuracy (def. 4.6) (ignorant share, def. 4.5)"  # what table()'s method rows hold


def table(result: Robustness) -> list[str]:
    """Markdown: per set, for ours and the peers, averaged over folds, top-1 accuracy (the figure ours
    is compared on), then def. 4.6's accuracy and the ignorant share (:data:`TABLE_CELLS`)."""
    avg = result.average
    ours = avg.ours
    sets = list(ours)
    head = ["| method | " + " | ".join(sets) + " |", "|---|" + "---|" * len(sets)]
    def row(name, blocks: dict[str, TestBlock]):
        return f"| {name} | " + " | ".join(f"{blocks[s].top1:.2f} / {blocks[s].accuracy:.2f} ({blocks[s].ignorant:.2f})"
                                            if s in blocks else "n/a" for s in sets) + " |"
    rows = [row("ftorch", {s: scores.test for s, scores in ours.items()})]
    if avg.train is not None and ours[sets[0]].present_own is not None:
        rows.append(f"| ftorch nodes present on own class (training views: {avg.train.present_own:.2f}) | "
                    + " | ".join(f"{ours[s].present_own:.2f}" for s in sets) + " |")
        rows.append(f"| ftorch nodes present on other classes (training views: {avg.train.present_other:.2f}) | "
                    + " | ".join(f"{ours[s].present_other:.2f}" for s in sets) + " |")
    if any(b.flipped is not None for b in ours.values()):
        rows.append("| ftorch nodes flipped vs clean | " + " | ".join(
            f"{ours[s].flipped:.2f}" if ours[s].flipped is not None else "" for s in sets) + " |")
    for peer, name in (("pixel_nn", "pixel 1-NN"), ("sift", "SIFT matching")):
        if avg.peers is not None:
            rows.append(row(name, avg.peers[peer]))
    return head + rows


def feature_tables(result: Robustness) -> list[str]:
    """Markdown: every feature type's nodes, how often they fire on their own class and on the others
    per set, and how often they flip under each perturbation (all folds pooled); then every node."""
    types = result.average.types
    if not types:
        return []
    sets = list(next(iter(types.values())).own)
    flips = list(next(iter(types.values())).flipped)

    def cells(block: dict, names: list) -> str:
        return " | ".join("" if block[n] is None else f"{block[n]:.2f}" for n in names)
    lines = ["## Which features survive (per feature type, all folds)", "",
             "Share of views on which a type's nodes are present: on their own class (recall) and on the other "
             "classes (false alarms), per set (train: the training views their cut-points were set on); and the "
             "share of (node, view) states that differ from the clean view's under each perturbation.", "",
             "| type | nodes | " + " | ".join(f"own: {n}" for n in sets) + " | " + " | ".join(f"other: {n}" for n in sets)
             + " | " + " | ".join(f"flipped: {n}" for n in flips) + " |",
             "|---|---|" + "---|" * (2 * len(sets) + len(flips))]
    lines += [f"| {kind} | {t.nodes} | {cells(t.own, sets)} | {cells(t.other, sets)} | {cells(t.flipped, flips)} |"
              for kind, t in sorted(types.items(), key=lambda kv: -kv[1].nodes)]
    lines += ["", "## Every node", "", "| fold | class | node | type | " + " | ".join(f"own: {n}" for n in sets)
              + " | other: clean | " + " | ".join(f"flipped: {n}" for n in flips) + " |",
              "|---|---|---|---|" + "---|" * (len(sets) + 1 + len(flips))]
    lines += [f"| {f.fold} | {cell(r.label)} | {r.node} | {r.type} | {cells(r.own, sets)} | "
              f"{cells(r.other, ['clean'])} | {cells(r.flipped, flips)} |" for f in result.folds for r in f.nodes or []]
    return lines + [""]


def overview(task: Task, sets: dict, test: list[int], heading: str) -> np.ndarray:
    """One test view per class (columns) under every set (rows), as an RGB picture titled ``heading``."""
    first = {}
    for k, i in enumerate(test):
        first.setdefault(task.labels[i], k)
    panels = [panel(images[k], f"{name}: {label}") for name, (images, _) in sets.items() for label, k in first.items()]
    return titled(grid(panels, len(first)), f"{heading}: one test view per class under each set")


def split_peers(task: Task, folds: list[int]) -> SplitPeers:
    """The peers on each fold's clean test views (``recognize --peers``): per fold and averaged; the
    average holds the clean views' accuracy (def. 4.6) and top-1 accuracy."""
    results = []
    for k in folds:
        train, test = task.fold(k)
        start = time.perf_counter()
        peers = peer_results(*views(task, train), {"clean": views(task, test)}, task.classes())
        results.append(PeerFold(k, peers["pixel_nn"], peers["sift"], time.perf_counter() - start))
    mean = {}
    for p in PEERS:
        scores = [getattr(r, p) for r in results]

        def over(figure) -> float | None:  # a figure's mean over folds, None where the peer has none
            known = [figure(s) for s in scores]
            return None if None in known else float(np.mean(known))

        mean[p] = PeerMeans(bytes_per_class=over(lambda s: s.bytes_per_class), views_per_class=over(lambda s: s.views_per_class),
                            descriptors_per_view=over(lambda s: s.descriptors_per_view),
                            clean=over(lambda s: s.sets["clean"].accuracy), clean_top1=over(lambda s: s.sets["clean"].top1))
    return SplitPeers(results, mean)


def perturbations(text: str) -> list[str]:
    """--perturb: ``all`` or a comma-separated choice of :data:`SETS`, each once, in the order given."""
    kinds = list(SETS) if text == "all" else [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in SETS]
    if unknown or not kinds:
        raise InputError(f"--perturb {text!r}: expected all or a comma-separated list of {', '.join(SETS)}")
    return list(dict.fromkeys(kinds))
