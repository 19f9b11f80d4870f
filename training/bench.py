"""Benchmarks: ``python -m training.bench features [--quick] [--device cpu|cuda] --json PATH``.

Everything is measured in one run against baselines computed in the same run:
- pyramid: the five basis maps at all scales for 32 images of 128x128, ftorch (the default band
  matrices) vs OpenCV's ``cv2.sepFilter2D`` with the very same sampled kernels (same radius, same
  reflect border) and vs ftorch's conv2d bank (``FilterMethod.CONV``); all three are checked against
  scipy at the tests' tolerance on one image, and the conv2d bank against the band matrices on all.
- record: the whole per-image record (pyramid, scale functions, salient points, descriptors).
- texel / edgel_pair / edgel3 / geometric3 / boolean: (feature, image) evaluations per second,
  the ratio to the per-point reference loop of ``ftorch.space.reference`` timed on a subset, and the
  largest difference between the two there.
Timings are the best of several repeats after a warm-up.

``python -m training.bench recognition [--quick] --json PATH`` times the inner loop of alg. 4.4:
one ``ExactInference.infer`` (the posterior and the mutual information of every unobserved
feature: ``evaluate`` without its memory of evidence states, the groups' memories emptied first)
on networks shaped like learned ones (16 feature nodes: a geometric chain with a conjunction, a
disjunction, and arc-free nodes), for random evidence. Baselines in the same
run: the same network with every linked group contracted by einsum, and pgmpy's
VariableElimination (one query for the class and one per unobserved feature); all three are
checked to agree. Then whole recognitions (alg. 4.4's queries, one node observed at a time) with
the groups' memories of their own evidence against the same networks without them: small compiled
groups (that network) and one 20-node group contracted by einsum (a 30-node network). Last, the agreement check
of alg. 4.4 for a block of images at once (``recognize_block``) against the single-image reference
(``recognize``, image after image), on six such class networks from empty memories: the two must agree
bit for bit (``block_agreement``).

``python -m training.bench batching [--data DIR] [--classes N] --json PATH`` replays the feature-value
computations of one fold's chapter 4 learning (COIL as stored in ``--data``, else the rendered
Plym task; seed 0), each as the value cache made it, against the same values computed in one call per
search (alg. 4.8: all its methods' candidates on all its images): the time of both and how many values
differ in some bit, and whether more features or more images in a call cause it. Merging is what
bigger candidate batches would do; values that differ would change the run, so they say whether it
is exact.

``python -m training.bench contrast [--data DIR] [--trials N] --json PATH`` is the evidence behind
``ftorch.images.MIN_LEVELS``: a learner of fold 1 (stage 0; COIL objects 1-4 of ``--data`` as stored,
12 views each, else the rendered Plym task) answers on its test views transformed by a*I + b in
float32, with the offset then removed exactly; how many answers change, against how many float32
steps the views' range spans (the baseline: the untransformed views' answers).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from enum import StrEnum
from typing import NamedTuple

import cv2
import numpy as np
import torch

from ftorch import FeatureSpace, ScaleSpace
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.images import MIN_LEVELS
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.exact import engine, information
from ftorch.recognition.inference import Plan, recognize, recognize_block
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.space.evaluate import feature_values
from ftorch.space.features import Conjunction, Disjunction
from ftorch.space.generate import expand_geometric, random_edgel_pair, random_texel
from ftorch.space.kernels import derivative_kernels
from ftorch.space.reference import reference_values, scipy_basis
from ftorch.space.scale_space import FilterMethod
from training.cli.arguments import Parser, at_least
from training.cli.devices import resolve_device
from training.cli.outputs import writable_file
from training.data.builtin import builtin_scene
from training.data.datasets import load_task

TOLERANCE = 2e-6  # of each level's largest response, interior pixels (tests/space/test_scale_space.py)


class Benchmark(StrEnum):
    """The benchmarks, by their command names (module doc)."""

    FEATURES = "features"
    RECOGNITION = "recognition"
    BATCHING = "batching"
    CONTRAST = "contrast"


def _once(fn, device: torch.device) -> tuple[float, object]:
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    result = fn()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return time.perf_counter() - start, result


def _timed(fn, repeats: int, device: torch.device) -> tuple[float, object]:
    """Best of ``repeats`` after a warm-up; the previous result is freed before each call."""
    return _interleaved([fn], repeats, device)[0]


def _interleaved(fns, repeats: int, device: torch.device) -> list[tuple[float, object]]:
    """Best time of each function, the functions taking turns so that load drifts hit all alike."""
    results = [fn() for fn in fns]  # warm-up
    best = [float("inf")] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            results[i] = None
            seconds, results[i] = _once(fn, device)
            best[i] = min(best[i], seconds)
    return list(zip(best, results))


def bench_images(count: int, size: int = 128) -> np.ndarray:
    """The built-in scene turned and shifted: ``count`` distinct float32 images."""
    scene = builtin_scene(size)
    out = []
    for i in range(count):
        warp = cv2.getRotationMatrix2D(((size - 1) / 2, (size - 1) / 2), 360.0 * i / count, 1.0)
        out.append(cv2.warpAffine(scene, warp, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))
    return np.stack(out).astype(np.float32)


def opencv_basis(images: np.ndarray, sigmas: list[float], truncate: float) -> np.ndarray:
    """The same five maps with cv2.sepFilter2D (which correlates: kernels are flipped)."""
    kernels = [derivative_kernels(s, truncate)[:, ::-1].astype(np.float32) for s in sigmas]
    r3 = np.float32(np.sqrt(3) / 2)
    out = np.empty((len(images), len(sigmas), 5, *images.shape[1:]), np.float32)
    for b, image in enumerate(images):
        for k, (g, g1, g2) in enumerate(kernels):
            gx = cv2.sepFilter2D(image, -1, g1, g, borderType=cv2.BORDER_REFLECT)
            gy = cv2.sepFilter2D(image, -1, g, g1, borderType=cv2.BORDER_REFLECT)
            gxx = cv2.sepFilter2D(image, -1, g2, g, borderType=cv2.BORDER_REFLECT)
            gxy = cv2.sepFilter2D(image, -1, g1, g1, borderType=cv2.BORDER_REFLECT)
            gyy = cv2.sepFilter2D(image, -1, g, g2, borderType=cv2.BORDER_REFLECT)
            iso = cv2.addWeighted(gxx, 0.25, gyy, 0.75, 0.0)
            out[b, k, 0], out[b, k, 1], out[b, k, 2] = gx, gy, gxx
            out[b, k, 3] = cv2.scaleAdd(gxy, r3, iso)
            out[b, k, 4] = cv2.scaleAdd(gxy, -r3, iso)
    return out


def worst_error(maps: np.ndarray, image: np.ndarray, sigmas: list[float], valid: np.ndarray, truncate: float) -> float:
    """Largest interior error against scipy, relative to each level's largest response."""
    worst = 0.0
    for k, sigma in enumerate(sigmas):
        if not valid[k].any():
            continue
        expected = scipy_basis(image.astype(np.float64), sigma, truncate)
        err = np.abs(maps[k].astype(np.float64) - expected)[:, valid[k]].max()
        worst = max(worst, float(err / np.abs(expected).max()))
    return worst


@dataclass
class PyramidFigures:
    """The pyramid: the band matrices (``FilterMethod.BAND``) against OpenCV and the conv2d bank, times and
    errors (``rel``: relative to each level's largest response)."""

    batch: int
    size: list[int]
    levels: int
    default: FilterMethod
    images_per_s: float
    opencv_images_per_s: float
    ratio_vs_opencv: float
    conv_images_per_s: float
    conv_time_ratio_vs_band: float
    conv_max_difference_vs_band: float
    conv_max_rel_difference_vs_band: float
    conv_bitwise_equal_to_band: bool
    max_rel_error: float  # the band matrices against scipy
    conv_max_rel_error: float
    opencv_max_rel_error: float
    tolerance: float
    within_tolerance: bool


def pyramid_section(images: np.ndarray, device: torch.device, repeats: int) -> PyramidFigures:
    band = ScaleSpace(method=FilterMethod.BAND).to(device)
    conv = ScaleSpace(method=FilterMethod.CONV).to(device)
    batch = torch.from_numpy(images).to(device)
    sigmas = [band.sigma(k) for k in range(band.num_levels(*images.shape[1:]))]
    (band_seconds, band_out), (conv_seconds, conv_out), (opencv_seconds, opencv_maps) = _interleaved(
        [lambda: band(batch), lambda: conv(batch), lambda: opencv_basis(images, sigmas, band.truncate)], repeats, device)
    valid = band_out.valid.cpu().numpy()
    band_error = worst_error(band_out.responses[0].cpu().numpy(), images[0], sigmas, valid, band.truncate)
    conv_error = worst_error(conv_out.responses[0].cpu().numpy(), images[0], sigmas, valid, band.truncate)
    opencv_error = worst_error(opencv_maps[0], images[0], sigmas, valid, band.truncate)
    # conv2d bank vs band matrices on every image and pixel, relative to each level's largest response
    level_max = band_out.responses.abs().amax(dim=(0, 2, 3, 4)).double()
    difference = (conv_out.responses - band_out.responses).abs().amax(dim=(0, 2, 3, 4)).double()
    count = len(images)
    return PyramidFigures(
        batch=count, size=list(images.shape[1:]), levels=len(sigmas), default=ScaleSpace().method,
        images_per_s=count / band_seconds, opencv_images_per_s=count / opencv_seconds, ratio_vs_opencv=opencv_seconds / band_seconds,
        conv_images_per_s=count / conv_seconds, conv_time_ratio_vs_band=conv_seconds / band_seconds,
        conv_max_difference_vs_band=float(difference.max()),
        conv_max_rel_difference_vs_band=float((difference / level_max).max()),
        conv_bitwise_equal_to_band=bool(torch.equal(conv_out.responses, band_out.responses)),
        max_rel_error=band_error, conv_max_rel_error=conv_error, opencv_max_rel_error=opencv_error, tolerance=TOLERANCE,
        within_tolerance=max(band_error, conv_error, opencv_error) <= TOLERANCE)


@dataclass
class RecordFigures:
    """The whole per-image record: images per second and salient points per image."""

    images_per_s: float
    texels_per_image: float
    edgels_per_image: float


@dataclass
class EvaluationFigures:
    """(feature, image) evaluations of one kind of feature, against the per-point reference loop on a subset."""

    features: int
    images: int
    evals_per_s: float
    reference_evals_per_s: float
    ratio_vs_reference: float
    max_error_vs_reference: float


def evaluation_section(features, records, repeats: int, device: torch.device, reference_features: int,
                       reference_images: int) -> EvaluationFigures:
    seconds, batched = _timed(lambda: feature_values(features, records), repeats, device)
    rate = len(features) * len(records) / seconds
    cpu_records = records[: reference_images].to("cpu")
    start = time.perf_counter()
    expected = reference_values(features[:reference_features], cpu_records)
    reference_seconds = time.perf_counter() - start
    reference_rate = reference_features * reference_images / reference_seconds
    found = batched.values[:reference_features, :reference_images].double().cpu().numpy()
    return EvaluationFigures(features=len(features), images=len(records), evals_per_s=rate,
                             reference_evals_per_s=reference_rate, ratio_vs_reference=rate / reference_rate,
                             max_error_vs_reference=float(np.abs(found - expected).max()))


@dataclass
class FeaturesReport:
    """The ``features`` benchmark (module doc), fields in the JSON file's order."""

    device: str
    torch: str
    threads: int
    opencv_threads: int
    quick: bool
    pyramid: PyramidFigures
    record: RecordFigures
    edgel_pair: EvaluationFigures
    edgel3: EvaluationFigures
    texel: EvaluationFigures
    geometric3: EvaluationFigures
    boolean: EvaluationFigures

    def evaluations(self) -> list[tuple[str, EvaluationFigures]]:
        """The kinds of feature in the printed table's order."""
        return [("texel", self.texel), ("edgel_pair", self.edgel_pair), ("edgel3", self.edgel3),
                ("geometric3", self.geometric3), ("boolean", self.boolean)]


def features(args) -> FeaturesReport:
    device = resolve_device(args.device)
    repeats = 4 if args.quick else 10
    images = bench_images(32)
    pyramid = pyramid_section(images, device, repeats)

    space = FeatureSpace().to(device)
    batch = torch.from_numpy(images).to(device)
    seconds, records = _timed(lambda: space(batch), repeats, device)
    counts = records.counts()  # ftorch's dict of point counts per image, by kind
    record = RecordFigures(images_per_s=len(images) / seconds,
                           texels_per_image=float(np.mean(np.add(counts["blobs"], counts["corners"]))),
                           edgels_per_image=float(np.mean(counts["edgels"])))

    generator = torch.Generator().manual_seed(0)
    count = 16 if args.quick else 64
    texels = [random_texel(records, i % len(records), generator) for i in range(count)]
    geometric3 = [expand_geometric(expand_geometric(t, records, i % len(records), generator), records, i % len(records), generator)
                  for i, t in enumerate(texels[: count // 2])]
    boolean = [(Conjunction if i % 2 else Disjunction)(texels[i], geometric3[i]) for i in range(count // 2)]
    pairs = [random_edgel_pair(records, i % len(records), generator) for i in range(count)]
    edgel3 = [expand_geometric(p, records, i % len(records), generator) for i, p in enumerate(pairs[: count // 2])]
    reference_images = 2
    return FeaturesReport(
        device=str(device), torch=torch.__version__, threads=torch.get_num_threads(), opencv_threads=cv2.getNumThreads(),
        quick=bool(args.quick), pyramid=pyramid, record=record,
        edgel_pair=evaluation_section(pairs, records, repeats, device, 2, reference_images),
        edgel3=evaluation_section(edgel3, records, repeats, device, 2, reference_images),
        texel=evaluation_section(texels, records, repeats, device, 4, reference_images),
        geometric3=evaluation_section(geometric3, records, repeats, device, 2, reference_images),
        boolean=evaluation_section(boolean, records, repeats, device, 2, reference_images))


def learned_like_network(rng: np.random.Generator, table_limit: int = ClassNetwork.TABLE_LIMIT,
                         label: str = "bench") -> ClassNetwork:
    """16 nodes: G2 <- G3 <- G4 (geometric chain, G4 -> G2 too), C -> {T, G2}, {a, b} -> D, 9 arc-free
    (feature names prefixed by a ``label`` other than "bench", but for the arc-free n0 and n1, which
    such networks share)."""
    net = ClassNetwork(label, table_limit)

    def own(key: str) -> str:
        return key if label == "bench" or key in ("n0", "n1") else f"{label}.{key}"

    structure = [("G2", []), ("G3", ["G2"]), ("G4", ["G3", "G2"]), ("T", []), ("C", []), ("a", []), ("b", []),
                 ("D", ["a", "b"])] + [(f"n{i}", []) for i in range(8)]
    for key, children in structure:
        net.add_feature(own(key), children=[own(c) for c in children])
    net.add_feature(own("n8"))
    net.add_arc(own("C"), own("T"))
    net.add_arc(own("C"), own("G2"))
    return _random_cpts(net, rng)


def large_group_network(rng: np.random.Generator, group: int = 20, singles: int = 10) -> ClassNetwork:
    """``group`` linked nodes, each g_i a compound over g_(i-1) and g_(i-2): one group beyond
    ``TABLE_LIMIT``, contracted by einsum; and ``singles`` arc-free nodes. The largest networks of
    COIL-inc 20 look like this (linked groups of 17 and 21 nodes; 29 nodes per network on average)."""
    net = ClassNetwork("bench-large")
    for i in range(group):
        net.add_feature(f"g{i}", children=[f"g{j}" for j in (i - 1, i - 2) if j >= 0])
    for i in range(singles):
        net.add_feature(f"s{i}")
    return _random_cpts(net, rng)


def _random_cpts(net: ClassNetwork, rng: np.random.Generator) -> ClassNetwork:
    """``net`` with every CPT entry drawn from U(0.02, 0.98) and the prior (0.7, 0.3)."""
    for key in net.features:
        p = rng.uniform(0.02, 0.98, size=(2,) * (len(net.parents[key]) + 1))
        net.set_cpt(key, np.stack([1 - p, p], axis=-1))
    net.prior = np.array([0.7, 0.3])
    return net


def forget_groups(net: ClassNetwork) -> None:
    """Empty every group's memory of its own evidence (compiled tables and einsum contractions)."""
    for group in engine(net).groups:
        group.given.clear()
        group.contracted.clear()


def infer_afresh(net: ClassNetwork, state: np.ndarray) -> tuple[float, np.ndarray]:
    """``engine(net).infer(state)`` with the groups' memories emptied first (:func:`forget_groups`): the
    inference itself, not a lookup (random evidence sets meet most small groups' states again)."""
    forget_groups(net)
    return engine(net).infer(state)


def recognitions(net: ClassNetwork, truths: list[np.ndarray], forget: bool = False) -> list[tuple[float, np.ndarray]]:
    """Alg. 4.4's queries on one network: from no evidence, observe the most informative open node
    (its state from ``truth``) until none is informative; every evaluation's result. ``forget``:
    the groups' memories are emptied before each evaluation (:func:`forget_groups`)."""
    out = []
    for truth in truths:
        state = np.full(len(net.features), -1, dtype=np.int64)
        while True:
            if forget:
                forget_groups(net)
            posterior, info = engine(net).evaluate(state)
            out.append((posterior, info))
            best = int(np.argmax(np.where(state < 0, info, -1.0)))
            if state[best] >= 0 or not info[best] > 0:
                break
            state = state.copy()
            state[best] = truth[best]
    return out


def _largest_difference(ours: list[tuple[float, np.ndarray]], theirs: list[tuple[float, np.ndarray]]) -> float:
    """The largest over evaluations of |posterior difference| + max |information difference|."""
    return max(abs(a[0] - b[0]) + float(np.abs(a[1] - b[1]).max()) for a, b in zip(ours, theirs))


@dataclass
class MemoryFigures:
    """Recognitions with the groups' memories of their own evidence against the same without them."""

    nodes: int
    groups: list[int]  # the linked groups' sizes
    recognitions: int
    evaluations: int
    seconds: float
    seconds_without_memory: float
    ratio_vs_without_memory: float
    max_difference_vs_without_memory: float


def memory_section(build, truths: int, repeats: int) -> MemoryFigures:
    """Recognitions on the network ``build()`` makes, with the groups' memories of their own
    evidence against the same network emptying them before every evaluation (as computing each
    afresh), from empty memories every repeat."""
    probe = build()
    rng = np.random.default_rng(1)
    states = [rng.integers(0, 2, len(probe.features)) for _ in range(truths)]
    (fast, remembering), (slow, forgetting) = _interleaved([lambda: recognitions(build(), states),
                                                            lambda: recognitions(build(), states, forget=True)],
                                                           repeats, torch.device("cpu"))
    return MemoryFigures(nodes=len(probe.features), groups=sorted(len(group.keys) for group in engine(probe).groups),
                         recognitions=truths, evaluations=len(remembering), seconds=fast, seconds_without_memory=slow,
                         ratio_vs_without_memory=slow / fast,
                         max_difference_vs_without_memory=_largest_difference(remembering, forgetting))


@dataclass
class BlockAgreement:
    """Alg. 4.4 for a block of images (``recognize_block``) checked against the single-image reference
    (``recognize``, image after image): times, and whether every recognition agrees bit for bit."""

    networks: int
    features: int
    images: int
    queries: int
    seconds: float
    seconds_one_by_one: float
    ratio_vs_one_by_one: float
    bitwise_equal: bool


def block_agreement(images: int, repeats: int) -> BlockAgreement:
    """``recognize_block`` on ``images`` images at once against the reference ``recognize``, image after
    image, on six learned-like class networks sharing two features, random values, both from fresh
    networks (empty memories) every repeat; their recognitions (queries, values, beliefs, recognized
    classes) must agree bit for bit."""
    def networks() -> dict:
        return {label: learned_like_network(np.random.default_rng(10 + i), label=label) for i, label in enumerate("ABCDEF")}

    plan = Plan.of(networks())
    values = np.random.default_rng(3).random((len(plan.keys), images))

    def one_by_one():
        nets = networks()
        return [recognize(nets, dict(zip(plan.keys, values[:, image].tolist())).__getitem__) for image in range(images)]

    (fast, block), (slow, reference) = _interleaved([lambda: recognize_block(networks(), values), one_by_one],
                                                    repeats, torch.device("cpu"))
    same = all((a.queried, a.values, a.beliefs, a.recognized) == (b.queried, b.values, b.beliefs, b.recognized)
               for a, b in zip(block, reference))
    return BlockAgreement(networks=6, features=len(plan.keys), images=images,
                          queries=sum(len(rec.queried) for rec in block), seconds=fast, seconds_one_by_one=slow,
                          ratio_vs_one_by_one=slow / fast, bitwise_equal=same)


@dataclass
class RecognitionReport:
    """The ``recognition`` benchmark (module doc), fields in the JSON file's order."""

    nodes: int
    evidence_sets: int
    evaluations_per_s: float
    einsum_evaluations_per_s: float
    pgmpy_evaluations_per_s: float
    ratio_vs_einsum: float
    ratio_vs_pgmpy: float
    max_difference_vs_einsum: float
    max_difference_vs_pgmpy: float
    small_groups: MemoryFigures  # compiled groups of 2 to 4 nodes
    large_group: MemoryFigures  # one 20-node group contracted by einsum
    block: BlockAgreement


def recognition(args) -> RecognitionReport:
    from pgmpy.inference import VariableElimination

    rng = np.random.default_rng(0)
    net = learned_like_network(rng)
    # the baseline contracts every group by einsum; both empty the groups' memories first, which
    # would answer most of these evidence sets, timing no contraction at all (infer_afresh)
    einsum = learned_like_network(np.random.default_rng(0), table_limit=0)
    nodes = len(net.features)
    states = [np.where(rng.random(nodes) < 0.4, rng.integers(0, 2, nodes), -1) for _ in range(200 if args.quick else 1000)]
    device = torch.device("cpu")
    repeats = 3 if args.quick else 5
    (fast, ours), (slow, contracted) = _interleaved([lambda: [infer_afresh(net, x) for x in states],
                                                     lambda: [infer_afresh(einsum, x) for x in states]], repeats, device)
    model = VariableElimination(net.to_pgmpy())
    name = net.node_names()
    pgmpy_states = states[:10 if args.quick else 30]

    def pgmpy_all():
        out = []
        for x in pgmpy_states:
            evidence = {name[k]: int(x[i]) for i, k in enumerate(net.features) if x[i] >= 0}
            posterior = model.query(["class"], evidence=evidence, show_progress=False).values[1]
            informations = []
            for i, k in enumerate(net.features):
                if x[i] < 0:
                    joint = model.query(["class", name[k]], evidence=evidence, show_progress=False)
                    table = np.transpose(joint.values, [joint.variables.index("class"), joint.variables.index(name[k])])
                    informations.append(information(table[None])[0])
            out.append((posterior, np.array(informations)))
        return out

    pgmpy_seconds, pgmpy_answers = _timed(pgmpy_all, 1, device)
    unobserved = [(posterior, informations[x < 0]) for (posterior, informations), x in zip(ours, pgmpy_states)]
    return RecognitionReport(
        nodes=nodes, evidence_sets=len(states), evaluations_per_s=len(states) / fast,
        einsum_evaluations_per_s=len(states) / slow, pgmpy_evaluations_per_s=len(pgmpy_states) / pgmpy_seconds,
        ratio_vs_einsum=slow / fast, ratio_vs_pgmpy=(pgmpy_seconds / len(pgmpy_states)) / (fast / len(states)),
        max_difference_vs_einsum=_largest_difference(ours, contracted),
        max_difference_vs_pgmpy=_largest_difference(unobserved, pgmpy_answers),
        small_groups=memory_section(lambda: learned_like_network(np.random.default_rng(2)), 20 if args.quick else 100, repeats),
        large_group=memory_section(lambda: large_group_network(np.random.default_rng(1)), 5 if args.quick else 20, repeats),
        block=block_agreement(20 if args.quick else 60, repeats))


class _Call(NamedTuple):
    """One value computation of the value cache: the number of the search it belongs to (None
    outside a search), its features and images, and the values it gave (features, images)."""

    search: int | None
    features: list
    images: list[int]
    values: np.ndarray


class _RecordedImages(ImageSet):
    """An image set that records each value computation (:class:`_Call`)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.calls: list[_Call] = []
        self.search: int | None = None  # the number of the search under way, if any
        self.searches = 0

    def _compute(self, features, images):
        values = super()._compute(features, images)
        self.calls.append(_Call(self.search, list(features), list(images), values))
        return values


class _MarkedLearner(DistinctiveFeatureLearner):
    """A learner that numbers its searches (alg. 4.8) on a :class:`_RecordedImages`."""

    def _search(self, env, *args, **kwargs):
        env.searches += 1
        env.search = env.searches
        try:
            return super()._search(env, *args, **kwargs)
        finally:
            env.search = None


def _differing(a: np.ndarray, b: np.ndarray) -> int:
    """How many entries differ in some bit (NaN equal to NaN)."""
    a, b = (np.ascontiguousarray(x).view(np.uint8).reshape(x.size, -1) for x in (a, b))
    return int((a != b).any(1).sum())


@dataclass
class BatchingReport:
    """The ``batching`` benchmark (module doc), fields in the JSON file's order."""

    task: str
    classes: int
    images: int
    learning_seconds: float
    calls: int
    searches: int
    median_features: float
    median_images: float
    merged_calls: int
    seconds_one_by_one: float
    seconds_per_search: float
    ratio_vs_one_by_one: float
    replay_differing: int  # values that differ when the calls are made again as the cache made them
    values: int
    values_differing: int
    differing_with_more_features: int
    differing_with_more_images: int


def batching(args) -> BatchingReport:
    task = (load_task("coil", args.data, args.classes) if args.data is not None
            else load_task("plym", classes=args.classes, size=64))
    train, _ = task.fold(1)
    learner = _MarkedLearner(seed=0)
    env = _RecordedImages([task.view(i) for i in train], [task.labels[i] for i in train], space=learner.space)
    start = time.perf_counter()
    learner.fit(env, stages=0)
    learning = time.perf_counter() - start
    calls = env.calls

    def compute(features, images):  # without recording
        return ImageSet._compute(env, features, images)

    groups: list[list[_Call]] = []  # the calls of one search together, every other call alone
    for call in calls:
        if call.search is not None and groups and groups[-1][0].search == call.search:
            groups[-1].append(call)
        else:
            groups.append([call])
    merged = [(list(dict.fromkeys(f for c in group for f in c.features)), sorted({i for c in group for i in c.images}))
              for group in groups]

    def one_by_one():
        return [compute(call.features, call.images) for call in calls]

    def per_search():
        return [compute(features, images) for features, images in merged]

    device = torch.device("cpu")
    (alone, replayed), (together, out) = _interleaved([one_by_one, per_search], 1, device)
    # the premise: a computation made again as the cache made it gives the same bits
    replay_differing = sum(_differing(call.values, again) for call, again in zip(calls, replayed))
    differ = total = by_features = by_images = 0
    for group, (features, images), values in zip(groups, merged, out):
        row, column = {f: k for k, f in enumerate(features)}, {i: k for k, i in enumerate(images)}
        for call in group:
            rows, columns = [row[f] for f in call.features], [column[i] for i in call.images]
            total += call.values.size
            differ += _differing(call.values, values[np.ix_(rows, columns)])
            by_features += _differing(call.values, compute(features, call.images)[rows])
            by_images += _differing(call.values, compute(call.features, images)[:, columns])
    return BatchingReport(
        task=task.name, classes=len(task.classes()), images=len(train), learning_seconds=learning,
        calls=len(calls), searches=sum(1 for group in groups if group[0].search is not None),
        median_features=float(np.median([len(call.features) for call in calls])),
        median_images=float(np.median([len(call.images) for call in calls])),
        merged_calls=len(merged), seconds_one_by_one=alone, seconds_per_search=together,
        ratio_vs_one_by_one=alone / together, replay_differing=replay_differing,
        values=total, values_differing=differ, differing_with_more_features=by_features, differing_with_more_images=by_images)


def print_batching(report: BatchingReport) -> None:
    r = report
    print(f"{r.task}, {r.classes} classes, fold 1 ({r.images} images), stage 0: learning {r.learning_seconds:.1f} s, "
          f"{r.calls} value computations (median {r.median_features:.0f} features x {r.median_images:.0f} images), "
          f"{r.searches} searches")
    print(f"one by one {r.seconds_one_by_one:.2f} s, one call per search ({r.merged_calls} calls) "
          f"{r.seconds_per_search:.2f} s (ratio {r.ratio_vs_one_by_one:.2f}); the calls made again as made: "
          f"{'bit for bit the same' if not r.replay_differing else str(r.replay_differing) + ' values DIFFERENT'}")
    print(f"values differing in some bit: {r.values_differing} of {r.values} "
          f"(with more features in the call {r.differing_with_more_features}, with more images {r.differing_with_more_images})"
          f"{'' if r.values_differing else ': merging is exact here'}")


def print_recognition(report: RecognitionReport) -> None:
    r = report
    print(f"evaluate (posterior + {r.nodes} informations): {r.evaluations_per_s:9.0f}/s  "
          f"einsum groups {r.einsum_evaluations_per_s:8.0f}/s (ratio {r.ratio_vs_einsum:.1f})  "
          f"pgmpy VE {r.pgmpy_evaluations_per_s:6.1f}/s (ratio {r.ratio_vs_pgmpy:.0f})")
    print(f"agreement: {r.max_difference_vs_einsum:.1e} vs einsum, {r.max_difference_vs_pgmpy:.1e} vs pgmpy")
    for name, how, memory in (("small groups", "tables", r.small_groups), ("large group", "einsum beyond 14", r.large_group)):
        print(f"{name} ({'+'.join(map(str, memory.groups))} of {memory.nodes} nodes, {how}), "
              f"{memory.recognitions} recognitions, {memory.evaluations} evaluations: {memory.seconds:.2f} s, without the "
              f"groups' memory {memory.seconds_without_memory:.2f} s (ratio {memory.ratio_vs_without_memory:.2f}), "
              f"max difference {memory.max_difference_vs_without_memory:.1e}")
    block = r.block
    print(f"block of {block.images} images ({block.networks} networks, {block.features} features, {block.queries} queries): "
          f"{block.seconds:.2f} s, one image at a time {block.seconds_one_by_one:.2f} s (ratio {block.ratio_vs_one_by_one:.2f}), "
          f"{'bit for bit the same' if block.bitwise_equal else 'DIFFERENT'}")


def print_features(report: FeaturesReport) -> None:
    p = report.pyramid
    print(f"device {report.device}, torch {report.torch}, {report.threads} threads")
    print(f"pyramid   {p.batch}x{p.size[0]}x{p.size[1]}, {p.levels} levels: "
          f"{p.images_per_s:8.1f} images/s  opencv {p.opencv_images_per_s:8.1f}  ratio {p.ratio_vs_opencv:.2f}")
    print(f"          conv2d bank {p.conv_images_per_s:8.1f} images/s, time conv / band "
          f"{p.conv_time_ratio_vs_band:.2f} (default: {p.default}), max difference vs band "
          f"{p.conv_max_difference_vs_band:.1e} ({p.conv_max_rel_difference_vs_band:.1e} of the level's largest), "
          f"{'bit for bit' if p.conv_bitwise_equal_to_band else 'not bit for bit'}")
    print(f"          max error vs scipy {p.max_rel_error:.1e} (conv2d {p.conv_max_rel_error:.1e}, opencv "
          f"{p.opencv_max_rel_error:.1e}), tolerance {p.tolerance:.0e}: {'ok' if p.within_tolerance else 'EXCEEDED'}")
    record = report.record
    print(f"record    {record.images_per_s:8.1f} images/s  ({record.texels_per_image:.0f} texels, "
          f"{record.edgels_per_image:.0f} edgels per image)")
    for kind, figures in report.evaluations():
        print(f"{kind:10s}{figures.evals_per_s:10.0f} evals/s  reference {figures.reference_evals_per_s:8.2f}  "
              f"ratio {figures.ratio_vs_reference:.0f}  max error vs reference {figures.max_error_vs_reference:.1e}")


@dataclass
class ContrastTrial:
    """One transform a*I + b: the float32 steps the transformed views' range spans (the fewest over the
    views) and how many of their answers differ from the originals'."""

    a: float
    b: float
    steps: float
    changed: int


@dataclass
class ContrastReport:
    """The ``contrast`` benchmark (module doc), fields in the JSON file's order."""

    task: str
    views: int
    trials: list[ContrastTrial]
    min_levels: int
    most_steps_with_a_change: float | None
    fewest_steps_without_a_change: float | None


def contrast(args) -> ContrastReport:
    """The ``contrast`` benchmark (module doc): per trial, the steps of float32 the transformed views'
    range spans (the fewest over the views) and how many of their answers differ from the originals'."""
    task = (load_task("coil", args.data, 4, 12) if args.data else load_task("plym", classes=4, views=12, size=40))
    train, test = task.fold(1)
    learner = DistinctiveFeatureLearner(seed=0).fit([task.view(i) for i in train], [task.labels[i] for i in train],
                                                    stages=0, max_cycles=8)
    views = [task.view(i).double() for i in test]
    original = learner.predict(views)
    rng = np.random.default_rng(args.seed)
    trials = []
    for _ in range(args.trials):
        a = 10 ** rng.uniform(-3, 3)
        b = a / 10 ** rng.uniform(2, 5) / np.finfo(np.float32).eps * rng.uniform(1, 2) * rng.choice([-1, 1])
        given = [(v * a + b).float() for v in views]  # what a user's float32 conversion keeps
        steps = min(float(x.max() - x.min()) / float(np.spacing(np.float32(x.abs().max()))) for x in given)
        answers = learner.predict([x.double() - float(x.min()) for x in given])  # the offset removed exactly
        trials.append(ContrastTrial(a=a, b=b, steps=steps, changed=sum(x != y for x, y in zip(answers, original))))
    return ContrastReport(task=task.name, views=len(views), trials=trials, min_levels=MIN_LEVELS,
                          most_steps_with_a_change=max((t.steps for t in trials if t.changed), default=None),
                          fewest_steps_without_a_change=min((t.steps for t in trials if not t.changed), default=None))


def print_contrast(report: ContrastReport) -> None:
    for low, high in ((0, 1e3), (1e3, 3e3), (3e3, 1e4), (1e4, 3e4), (3e4, 1e5), (1e5, math.inf)):
        band = [t for t in report.trials if low <= t.steps < high]
        if band:
            print(f"{low:8.0f} to {high:8.0f} steps: {len(band):3d} trials, answers changed in {sum(t.changed > 0 for t in band):3d} "
                  f"({sum(t.changed for t in band)} of {len(band) * report.views} answers)")
    print(f"answers changed at up to {report.most_steps_with_a_change} steps; ftorch refuses float images of fewer than "
          f"{report.min_levels}")


def parser() -> argparse.ArgumentParser:
    top = Parser(prog="python -m training.bench", description=__doc__.split("\n\n")[0])
    commands = top.add_subparsers(dest="command", required=True)
    p = commands.add_parser(Benchmark.FEATURES, help="feature-space benchmark")
    p.add_argument("--quick", action="store_true", help="fewer repeats and features (under a minute)")
    p.add_argument("--device", default="cpu", help="cpu, cuda[:N] or auto (default cpu)")
    p.add_argument("--json", help="write the figures to this JSON file")
    p = commands.add_parser(Benchmark.RECOGNITION, help="exact-inference benchmark (alg. 4.4 inner loop)")
    p.add_argument("--quick", action="store_true", help="fewer evidence sets")
    p.add_argument("--json", help="write the figures to this JSON file")
    p = commands.add_parser(Benchmark.BATCHING, help="feature values one call per search against the value cache's calls")
    p.add_argument("--data", help="a COIL-20 folder (images as stored); default: the rendered Plym task")
    p.add_argument("--classes", type=at_least(2, "classes"), default=None, help="the first N classes (default: COIL 6, Plym all)")
    p.add_argument("--json", help="write the figures to this JSON file")
    p = commands.add_parser(Benchmark.CONTRAST, help="answers against the float32 steps a transformed image's range spans")
    p.add_argument("--data", help="a COIL-20 folder (images as stored); default: the rendered Plym task")
    p.add_argument("--trials", type=at_least(1, "trials", 10000), default=60, help="transforms drawn (default 60)")
    p.add_argument("--seed", type=at_least(0, "a seed", 2**31 - 1), default=0, help="seed of the transforms (default 0)")
    p.add_argument("--json", help="write the figures to this JSON file")
    return top


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        if args.json:
            writable_file(args.json, "--json")  # before the benchmark runs, not after
        command = Benchmark(args.command)
        if command is Benchmark.RECOGNITION:
            report = recognition(args)
            print_recognition(report)
        elif command is Benchmark.BATCHING:
            report = batching(args)
            print_batching(report)
        elif command is Benchmark.CONTRAST:
            report = contrast(args)
            print_contrast(report)
        else:
            resolve_device(args.device)  # an absent device is refused before the benchmark runs
            report = features(args)
            print_features(report)
        if args.json:  # the JSON boundary: the report's fields, in order
            write_text(args.json, json.dumps(asdict(report), indent=2) + "\n")
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"error: {err.filename or args.json}: {err.strerror or err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
