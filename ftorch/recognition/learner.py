"""The incremental distinctive-feature learner (alg. 4.7, 4.8, 4.10) with expert learning (alg. 5.1, 5.2).

It starts blank, recognizes each image it is shown (alg. 4.4) and learns only from mistakes:
first by re-discretizing and re-counting (alg. 4.7 step 3), then by searching for one new
feature that fixes the mistake (alg. 4.8), generated in order of structural complexity by the
five methods of alg. 4.10, n_fgen candidates each. With a KSD target t_KSD > 0 (alg. 5.1) a
new feature must also reach distinctive power >= t_KSD, and a correct recognition that leaves
some class uncertain triggers expert learning for the least-well-discriminated class pair
(alg. 5.2) when that pair's best consulted feature falls short of t_KSD.

The learner orchestrates; its parts own their state: :class:`~ftorch.recognition.counting.Counting` the
instance list and the counts made from it (discretization, CPTs), :class:`~ftorch.recognition.candidates.
CandidateGenerator` alg. 4.10's candidates, :func:`~ftorch.recognition.expertise.choose_pair` alg. 5.2's pair.

Decisions the text leaves open (the parts' modules give theirs):
- Success (alg. 4.8 step 8) is judged on the misrecognized image: its characterized class is
  now recognized if it is true there, or no longer recognized if it is false there (the
  ambiguous case, where the feature is sampled from an example image of that false class).
- Alg. 5.1 calls alg. 4.10 "until" a candidate reaches t_KSD. A search here calls it (the five
  methods, n_fgen candidates each) up to ``search_rounds`` times and stops at the first candidate
  accepted; a candidate that failed is not tried again in the same search. The cap ends a
  hopeless search (a pair that no feature near the sample image separates) so that the stage's
  cycle limit, not one image, bounds the work; ``search_rounds=1`` is one call per presentation.
  An expert feature is accepted when it reaches t_KSD and the image is still recognized correctly.

Options for generalization beyond the thesis, held with the rest in :class:`~ftorch.recognition.settings.LearnerSettings`
(whose defaults are the measured best; :meth:`~ftorch.recognition.settings.LearnerSettings.thesis` gives the thesis's behaviour):
- ``redundancy`` k (7.2.4): a distinction c-vs-d that an image needs is *carried* by k features:
  alg. 5.2 scores a pair by its support, the k-th largest KSD_{c,d}(f) over all features of c's
  network, and expert learning runs while the weakest support is 0 or below t_KSD. The true
  classes of the image are scored as well as the uncertain ones (a certain recognition may rest
  on a single feature), and the k strongest carriers of every scored pair count as used, so
  alg. 5.3's discarding keeps them. Each accepted expert feature raises its pair's support
  count by one, so a pair needs at most k of them; k = 1 is alg. 5.2 as printed.
- ``evidence``: "both" (4.4.1) or "positive" (4.4.2: only features found present are entered;
  an absent feature may be occluded), in training and recognition alike.
- ``cut_position`` w: a node's cut-point lies at w between the two adjacent values where its KSD
  is reached (0.5, the midpoint, as 4.3.2).
- ``test_information`` (bits): the stopping threshold of alg. 4.4 when the learner answers
  (``recognize``, ``recognize_many``), while ``min_information`` stops the recognitions inside
  learning (alg. 4.7 step 1, alg. 4.8 step 8, alg. 5.1), which decide what is a mistake and which
  features count as used. 4.4.2 offers the threshold only as a trade of queries for confidence;
  the thesis's experiments consult features "exhaustively" (0). A learner trained with a
  threshold rules a class out after one or two absent features and never asks the rest of its
  network, which gives ignorant answers; asking until I_max = 0 uses all the evidence it has.
- ``primitives``: the kinds of new primitive alg. 4.10's method 2 samples, drawn uniformly:
  texels and edgel pairs (the thesis), and the statistical texture of 7.2.1 where added
  (``ftorch.space.texture``: the intensity distribution around a point, which faces and other
  textured objects need and texels, normalised derivative responses, do not carry).
- ``texture_parts``: method 3's geometric expansions may also add a texture part beside an
  oriented one (3.5 with 7.2.1), so that "a smooth patch left of this corner" can be learned.
- ``calibrate`` (calibrated counting, cross-fitting): a node's cut-point and CPT are counted on
  the instances other than those its search selected it on, where enough remain
  (:mod:`ftorch.recognition.counting`), so that the networks trust a feature as much as it
  fires on views it was not chosen for.
- ``leak`` l (detection failure): every CPT entry p becomes l + (1 - 2l) p, so one feature
  missing from an unseen view (occluded, rotated away) never rules its class out alone.
- ``pseudocount`` a: CPTs count (n + a) / (N + 2a). The thesis's relative frequencies (a = 0)
  give a feature present in every training view of c P(absent | c) = 0, so one unseen view
  without it makes c impossible: an ignorant result.
"""
from __future__ import annotations

from collections.abc import Hashable
from typing import NamedTuple

import numpy as np
import torch

from ..checkpoint import DAMAGED, decode_array, encode_array, load_checkpoint, save_checkpoint, stored_position
from ..errors import InputError, NotFittedError
from ..settings import as_device
from ..space.features import Feature, FeatureTable, unpack_features
from ..space.record import FeatureSpace
from .bayes import ClassNetwork, compound_arcs
from .candidates import METHODS, CandidateGenerator, in_use, pick
from .counting import Counting
from .environment import ImageSet
from .expertise import choose_pair
from .explain import Explanation, explain
from .inference import (
    Answer,
    Outcome,
    Plan,
    Recognition,
    Result,
    accuracy,
    outcome,
    recognize,
    recognize_block,
    residual_entropy,
    top1_accuracy,
)
from .instances import InstanceList, are_stored_values
from .settings import Evidence, LearnerSettings, bits, whole
from .stages import MAX_CYCLES, Schedule, Stage
from .value_cache import ValueCache

KIND = "learner"
# From this many images on, alg. 4.4 runs as one block (recognize_block), below it image by image
# (recognize): a block's steps cost numpy calls per network, an image's steps Python on scalars. On
# COIL-6's learned networks (2-core AMD EPYC) a block costs per image 6.3x one image's time at 1
# image, 1.9x at 8, 1.1x at 16, 0.70x at 32 and 0.38x at 120.
BLOCK_MIN = 24
TRAINING_STATE = ("generator", "discriminates", "selected", "usage", "instances")  # what state_dict(training=True) adds


class Presentation(NamedTuple):
    """What one training presentation did: its first recognition, its :class:`Result`, the residual
    entropy per class in bits; ``pair`` and ``ksd``: alg. 5.2's choice and its KSD_{c,d} (eq. 5.1),
    None where no class was left uncertain; ``searched``: the classes of the search it made, if any."""

    recognition: Recognition
    result: Result
    entropy: dict
    pair: tuple | None = None
    ksd: float | None = None
    searched: tuple | None = None  # (characterized class, discriminated classes) of its search (alg. 4.8, 5.1)


class Ahead:
    """The first recognitions of the presentations still to come in one :meth:`DistinctiveFeatureLearner.present`
    call, made in blocks and kept while the networks' ``signature`` (network objects and revisions)
    holds. A block is made only once the networks have stood for ``BLOCK_MIN`` presentations (a block
    is faster than image by image from there on, and a stable past predicts a stable future); it then
    spans as many presentations as they have stood, at most ``LIMIT``. The size changes only the
    work, never a result."""

    LIMIT = 64

    def __init__(self, images: list[int]):
        self.images, self.at = images, 0  # the presentations, and the next one's position
        self.block: list[Recognition] = []  # recognitions of images[at:at + len(block)]
        self.signature: tuple | None = None  # the networks' when the block was made
        self.last: tuple | None = None  # the networks' at the previous presentation
        self.stood = 0  # presentations since the networks last changed

    def take(self, image: int, signature: tuple) -> Recognition | None:
        """The next presentation's recognition where the block holds it and the networks are unchanged."""
        if self.images[self.at] != image:
            raise ValueError(f"presented image {image}, but {self.images[self.at]} comes next")
        self.at += 1
        self.stood = self.stood + 1 if signature == self.last else 0
        self.last = signature
        if self.block and signature == self.signature:
            return self.block.pop(0)
        self.block = []  # used up, or a change dropped the rest
        return None

    def upcoming(self) -> list[int]:
        """The images after the current one that the next block would recognize too (none while the
        networks have stood for fewer than ``BLOCK_MIN`` presentations)."""
        if self.stood < BLOCK_MIN:
            return []
        return self.images[self.at:self.at + min(self.stood, self.LIMIT) - 1]

    def following(self, cache: ValueCache, features: list) -> list[int]:
        """Of :meth:`upcoming`, the leading images whose values of ``features`` ``cache`` holds all:
        a block computes no value."""
        upcoming = self.upcoming()
        if not upcoming:  # most presentations: no lookup of every feature in the cache
            return []
        missing = np.isnan(cache.stored(features, upcoming)).any(0)
        return upcoming[:int(missing.argmax()) if missing.any() else len(upcoming)]

    def keep(self, block: list[Recognition], signature: tuple) -> Recognition:
        """Keep a new block (the current image's recognition first); returns that first one."""
        self.block, self.signature = block[1:], signature
        return block[0]


GENERATOR_STATE = tuple(torch.Generator().get_state().shape)  # the bytes of a torch.Generator's state
MAX_SEED = 2**63 - 1  # torch.Generator.manual_seed takes 0 .. 2**64 - 1; a seed stays a signed 64-bit integer


def _cached(env: ImageSet | None, features: list, images: list) -> np.ndarray | None:
    """``env``'s cached values (images, features), the reference of relative instance values; None without ``env``."""
    return None if env is None else env.cache.stored(features, images).T


def _values(env: ImageSet, features: list, images: list[int]) -> np.ndarray:
    """``env.values(features, images)``, (0, len(images)) without features."""
    return env.values(features, images) if features else np.zeros((0, len(images)))


def _label(value):
    """Class labels and image ids are stored as JSON scalars: str or int."""
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise InputError(f"class labels and image ids must be str or int to be saved, got {value!r}")
    return value


def _number(value) -> float:
    """A stored number: int or float, never a string or a bool that float() would also accept."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{value!r} is not a number")
    return float(value)


def _count(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"count {value!r} is not an integer >= 0")
    return value


class DistinctiveFeatureLearner:
    """Learns class networks of distinctive features from labelled images, incrementally and only
    from its mistakes; an estimator in the manner of scikit-learn.

    ``fit(images, labels)`` runs training stages (alg. 5.3; alg. 5.4 with ``incremental``) from a
    blank state; ``partial_fit`` presents images once each, keeping what was learned (the
    incremental loop, alg. 4.7 / 5.1); ``predict`` answers each image's recognized classes (alg. 4.4,
    def. 4.5: a set, empty where nothing is recognized), ``predict_proba`` the posterior of every
    class (open world: a row need not sum to 1), ``score`` the mean accuracy of def. 4.6. Labels are
    any hashable values, or a set of them per image. ``settings`` (:class:`LearnerSettings`, the
    measured best by default; :meth:`thesis` for the dissertation's) may be changed by keyword,
    ``DistinctiveFeatureLearner(redundancy=1)``. ``seed`` seeds every random choice; ``device``
    where the feature space computes the images' records.

    The lower-level face: ``learn(env, i)`` presents image i of an :class:`ImageSet`;
    ``recognize``/``recognize_many`` recognize images of any image set; ``save``/``load`` write and
    read the whole state (networks, instance list, usage, random state) exactly.
    """

    def __init__(self, settings: LearnerSettings | None = None, *, seed: int = 0, device: str | torch.device = "cpu",
                 **options):
        self.settings = (LearnerSettings() if settings is None else settings).replace(**options)
        self.seed = whole("seed", seed, 0, MAX_SEED)
        self.device = as_device(device)
        self.space = FeatureSpace().to(self.device)
        self.generator = torch.Generator()  # every random choice; set in place on load
        self._blank()

    def _blank(self) -> None:
        """The state before any presentation: no network, no instance, the generator at ``seed``."""
        self.generator.manual_seed(self.seed)
        self.networks: dict[Hashable, ClassNetwork] = {}
        self._plans: list[Plan] = []  # the networks' structures as alg. 4.4 indexes them, the latest first
        self._ahead: Ahead | None = None  # first recognitions of the presentations to come (:meth:`present`)
        self.counting = Counting(self.settings.calibrate)
        self.candidates = CandidateGenerator(self.generator, self.settings.primitives, self.settings.regions,
                                             self.settings.texture_parts)
        self.usage: dict = {}  # feature -> the last presentation whose training recognition queried it (alg. 5.3)
        self.presentations = 0
        self.trainable = True  # False once loaded from a recognition-only state
        self.sides: tuple[int, int] | None = None  # the smallest and largest shorter side of the images learned from
        self.images_: ImageSet | None = None  # the images fit and partial_fit learned from
        self.stages_: list[Stage] = []  # fit's stages

    @classmethod
    def thesis(cls, *, seed: int = 0, device: str | torch.device = "cpu", **options) -> "DistinctiveFeatureLearner":
        """A learner with the dissertation's settings (:meth:`LearnerSettings.thesis`), changed by ``options``."""
        return cls(LearnerSettings.thesis(), seed=seed, device=device, **options)

    @property
    def instances(self) -> InstanceList:
        return self.counting.instances

    @property
    def discriminates(self) -> dict[tuple, frozenset]:
        return self.counting.discriminates

    @property
    def sampled(self) -> int:
        """Features sampled from images so far (alg. 4.10 methods 2 and 3; figures 4.10 and 5.19)."""
        return self.candidates.sampled

    @property
    def classes_(self) -> list:
        """The classes learned, in network order (the columns of :meth:`predict_proba`)."""
        self._check_fitted()
        return list(self.networks)

    def set_params(self, **options) -> "DistinctiveFeatureLearner":
        """Change settings, validated as the constructor validates them, and return the learner; e.g.
        ``set_params(evidence="positive", test_information=0.1)`` answers with another evidence mode
        and threshold (the robustness benchmark)."""
        self.settings = self.settings.replace(**options)
        self.counting.calibrate = self.settings.calibrate
        self.candidates.primitives = self.settings.primitives
        self.candidates.regions = self.settings.regions
        self.candidates.texture_parts = self.settings.texture_parts
        return self

    def _check_fitted(self) -> None:
        if not self.networks:
            raise NotFittedError("this DistinctiveFeatureLearner has learned no class yet: call fit or partial_fit "
                                 "(or learn), or load a saved learner, first")

    # -- the estimator face ------------------------------------------------------------------
    def _image_set(self, images, labels=None) -> ImageSet:
        return images if isinstance(images, ImageSet) else ImageSet(images, labels, space=self.space)

    def fit(self, images, labels=None, *, stages: int | None = None, max_cycles: int = MAX_CYCLES,
            incremental: bool = False, classes: list | None = None) -> "DistinctiveFeatureLearner":
        """Learn from a blank state: training stages (alg. 5.3) on ``images`` (files, arrays or
        tensors, or an :class:`ImageSet`, then without ``labels``) with their ``labels``. ``stages``:
        expert stages after stage 0 (0: chapter 4 learning only; None: until t_KSD = 1 or two stages
        in a row miss their target); ``incremental``: add the classes one at a time in the order of
        ``classes`` (default: sorted), alg. 5.4. The presentation order is drawn from ``seed``, as
        every other random choice. Returns the learner; ``stages_`` holds the stages' reports."""
        env = self._image_set(images, labels)
        self._blank()
        self.images_ = env
        schedule = Schedule(self, env, torch.Generator().manual_seed(self.seed), stages, max_cycles, classes,
                            incremental)
        self.stages_ = schedule.run()
        return self

    def partial_fit(self, images, labels=None, *, t_ksd: float = 0.0) -> "DistinctiveFeatureLearner":
        """Present ``images`` once each, in their order, keeping what was learned (alg. 4.7; alg. 5.1
        with the KSD target ``t_ksd``). New images join the images learned from (their examples
        serve later searches, alg. 4.8); an :class:`ImageSet` already learned from is presented again."""
        if isinstance(images, ImageSet) and labels is not None:
            raise InputError("partial_fit: an ImageSet carries its own labels; pass no labels with it")
        if self.images_ is None and self.presentations:
            raise InputError("partial_fit: this learner learned from images it no longer holds (it was loaded, or "
                             "taught through learn); go on with learn(env, i) on the image set it learned from")
        if self.images_ is None or isinstance(images, ImageSet) and images is self.images_:
            added = self._image_set(images, labels)
            start = 0
        else:
            new = self._image_set(images, labels)
            start = len(self.images_)
            added = self.images_.extended(new)
        self.images_ = added
        self.present(added, range(start, len(added)), t_ksd)
        return self

    def predict(self, images, answer: Answer | str = Answer.OPEN_WORLD) -> list:
        """Each image's answer. ``Answer.OPEN_WORLD`` (the thesis's): the classes recognized (alg. 4.4,
        posterior > 0.5), a set per image, empty where no class is recognized (an ignorant result,
        def. 4.5). ``Answer.TOP1``: one class label per image (:attr:`Recognition.top`, alg. 4.4
        continued on the candidates where the set is not one class)."""
        answer = Answer.of(answer)
        answers = self._answers(images)
        if answer is Answer.TOP1:
            return [r.top for r in answers]
        return [frozenset(r.recognized) for r in answers]

    def predict_proba(self, images) -> np.ndarray:
        """Each image's posterior per class (images x :attr:`classes_`), after alg. 4.4. The classes
        are not exclusive (an image may show several or none), so a row need not sum to 1."""
        labels = self.classes_
        return np.array([[r.posteriors[c] for c in labels] for r in self._answers(images)], dtype=np.float64)

    def score(self, images, labels=None, answer: Answer | str = Answer.OPEN_WORLD) -> float:
        """Mean accuracy over labelled images: ``Answer.OPEN_WORLD``, def. 4.6 against every class
        learned; ``Answer.TOP1``, the share of images whose top label is one of their true classes."""
        answer = Answer.of(answer)
        self._check_fitted()
        env = self._image_set(images, labels)
        if not env.labeled:
            raise InputError("score needs labels: the true classes of each image")
        answers = self._answers(env)
        if answer is Answer.TOP1:
            return float(np.mean([top1_accuracy(r.top, t) for r, t in zip(answers, env.labels)]))
        n = len(set(self.networks) | set(env.classes()))
        return float(np.mean([accuracy(r.recognized, t, n) for r, t in zip(answers, env.labels)]))

    def _answers(self, images) -> list[Recognition]:
        self._check_fitted()
        env = self._image_set(images)
        return self.recognize_many(env, range(len(env)))

    # -- recognition (alg. 4.4) --------------------------------------------------------------
    def recognize(self, env: ImageSet, image: int) -> Recognition:
        """Recognize one image of ``env`` (alg. 4.4, stopping at ``test_information``), its top label
        filled (:func:`~ftorch.recognition.inference.top_class`); nothing is learned or recorded."""
        return self.recognize_many(env, [image])[0]

    def recognize_many(self, env: ImageSet, images, information: float | None = None) -> list[Recognition]:
        """Recognize several images: every feature of every network is measured on all of them in one
        batch. ``information``: the stopping threshold in bits (default ``test_information``; the
        learning recognitions' ``min_information`` judges a training image as learning does). These are
        answers: each one's top label is filled (:func:`~ftorch.recognition.inference.top_class`, from
        the values already measured); learning's own recognitions leave it None."""
        self._check_fitted()
        threshold = self.settings.test_information if information is None else bits("information", information)
        return self._recognize_many(env, images, threshold, top=True)

    def explain(self, image) -> Explanation:
        """The trace of this learner's recognition of one ``image`` (a file path, array or tensor): the
        features alg. 4.4 queried in order, their values, presence per network and location, each
        class's belief after each query, and a picture of it (:mod:`ftorch.recognition.explain`). Its
        answer is ``predict([image])[0]``: the same recognition, with ``test_information`` and ``evidence``."""
        return explain(self, image)

    def _recognize_many(self, env: ImageSet, images, threshold: float, top: bool = False) -> list[Recognition]:
        images = [env.index(i) for i in images]
        return self._recognize_table(_values(env, in_use(self.networks), images), threshold, top)

    def _recognize_table(self, table: np.ndarray, threshold: float, top: bool = False) -> list[Recognition]:
        """Alg. 4.4 on a block of images given their values ``table`` (features in :func:`in_use` order, which
        is the plan's, x images), stopping at ``threshold`` bits: as a block from ``BLOCK_MIN`` images on,
        else image by image (the same recognitions either way; :data:`BLOCK_MIN` says which is faster);
        ``top``: with their top labels."""
        plan = Plan.of(self.networks, *self._plans)
        self._plans = [plan, *(p for p in self._plans if p is not plan)][:2]
        tolerance, positive_only = max(threshold, 1e-12), self.settings.evidence is Evidence.POSITIVE
        if table.shape[1] >= BLOCK_MIN:
            return recognize_block(self.networks, table, tolerance, positive_only, plan, top)
        return [recognize(self.networks, dict(zip(plan.keys, column)).__getitem__, tolerance, positive_only, plan, top)
                for column in table.T.tolist()]

    # -- estimation (alg. 4.7 step 3) --------------------------------------------------------
    def reestimate(self) -> None:
        """Re-discretize every feature node by KSD and re-count every CPT and prior."""
        self.counting.reestimate(self.networks, self.settings.cut_position, self.settings.pseudocount, self.settings.leak)

    # -- learning (alg. 4.7) -----------------------------------------------------------------
    def learn(self, env: ImageSet, image: int, t_ksd: float = 0.0) -> Presentation:
        """Present one training image (alg. 4.7, and alg. 5.1 with the KSD target ``t_ksd``).

        One learner learns from one :class:`ImageSet`: its image indices are the instance ids.
        """
        if not 0.0 <= t_ksd <= 1.0:
            raise InputError(f"t_ksd must lie in [0, 1], got {t_ksd}")
        if not env.labeled:
            raise InputError("learning needs labels: this image set was made without the images' true classes")
        if not self.trainable:
            raise InputError("this learner was loaded from a recognition-only file (learner.json) and cannot learn: "
                             "load a state saved with training=True, such as a fold's checkpoint.json, to go on learning")
        image = env.index(image)
        side = min(env.images[image].shape)
        self.sides = (side, side) if self.sides is None else (min(self.sides[0], side), max(self.sides[1], side))
        self.presentations += 1
        true = env.labels[image]
        for label in sorted(true, key=str):  # network order breaks ties in alg. 4.4: keep it fixed
            if label not in self.networks:
                self.networks[label] = ClassNetwork(label)
        self.counting.instances.add(image, true)
        first = self._first_recognition(env, image)
        entropy = residual_entropy(first)
        if outcome(first.recognized, true) is Outcome.CORRECT:
            return self._expert(env, image, first, entropy, t_ksd)
        self.reestimate()
        again = self._training_recognition(env, image)
        if outcome(again.recognized, true) is Outcome.CORRECT:
            return Presentation(first, Result.REESTIMATED, entropy)
        chosen = self.choose_classes(again, true)
        if chosen is None:
            return Presentation(first, Result.FAILED, entropy)
        char, disc, char_is_true = chosen
        learned = self._search(env, image, char, disc, char_is_true, t_ksd,
                               lambda after: (char in after.recognized) == char_is_true)
        return Presentation(first, Result.LEARNED if learned else Result.FAILED, entropy, searched=(char, disc))

    def present(self, env: ImageSet, images, t_ksd: float = 0.0) -> list[Presentation]:
        """Present ``images`` in their order, each by :meth:`learn`: one cycle of alg. 5.3.

        Their first recognitions (alg. 4.7 step 1) are made in blocks (:class:`Ahead`): a recognition
        depends only on the networks (structure, CPTs, thresholds, prior), the learner's settings and
        the image's feature values, so while no network changes (the same network objects at the
        same :attr:`~ftorch.recognition.bayes.ClassNetwork.revision`) the recognitions of the next
        images, made together (:func:`~ftorch.recognition.inference.recognize_block`, equal to one
        image's), are the ones each presentation would make; a block is made only where every value
        it reads is in the value cache, so that it computes no value (the cache's rule keeps
        values, not only results, exact); any change drops what remains of it. So the presentations,
        the learner's state and every report are those of :meth:`learn` called image by image (tested).
        """
        images = [env.index(i) for i in images]
        self._ahead = Ahead(images)
        try:
            return [self.learn(env, i, t_ksd) for i in images]
        finally:
            self._ahead = None

    def _first_recognition(self, env: ImageSet, image: int) -> Recognition:
        """The training recognition of a presentation's start: inside :meth:`present`, from the block
        made ahead where it still holds, else made now with the next images' (:class:`Ahead`)."""
        ahead = self._ahead
        if ahead is None:
            return self._training_recognition(env, image)
        signature = tuple((label, net, net.revision) for label, net in self.networks.items())
        rec = ahead.take(image, signature)
        if rec is None:
            features = in_use(self.networks)
            table = _values(env, features, [image])  # asked for as one image's recognition asks
            following = ahead.following(env.cache, features)
            if following:
                table = np.concatenate([table, _values(env, features, following)], 1)
            rec = ahead.keep(self._recognize_table(table, self.settings.min_information), signature)
        return self._training_recognition(env, image, rec)

    def _expert(self, env: ImageSet, image: int, rec: Recognition, entropy: dict, t_ksd: float) -> Presentation:
        """Alg. 5.1 steps 2-4 on a correctly recognized image."""
        true = env.labels[image]
        chosen = self.choose_pair(rec, true, entropy)
        if chosen is None:
            return Presentation(rec, Result.CORRECT, entropy)
        c, d, weakest = chosen
        if weakest >= t_ksd and (self.settings.redundancy == 1 or weakest > 0):  # k > 1: carried means power > 0 too
            return Presentation(rec, Result.CORRECT, entropy, (c, d), weakest)
        learned = self._search(env, image, c, frozenset({d}), c in true, t_ksd,
                               lambda after: outcome(after.recognized, true) is Outcome.CORRECT)
        return Presentation(rec, Result.EXPERT if learned else Result.EXPERT_FAILED, entropy, (c, d), weakest,
                            (c, frozenset({d})))

    def choose_pair(self, rec: Recognition, true: frozenset, entropy: dict) -> tuple | None:
        """Alg. 5.2 (:func:`ftorch.recognition.expertise.choose_pair` with this learner's ``redundancy``): (c, d,
        KSD_{c,d}) for the least-well-discriminated pair, or None; with k > 1 the k strongest carriers
        of every pair scored count as used."""
        best, used = choose_pair(self.networks, self.counting, rec, true, entropy, self.settings.redundancy)
        for carriers in used:
            self._mark_usage(carriers)
        return best

    def _learning_recognition(self, env: ImageSet, image: int) -> Recognition:
        """A recognition inside learning: it stops at ``min_information``."""
        return self._recognize_many(env, [image], self.settings.min_information)[0]

    def _training_recognition(self, env: ImageSet, image: int, rec: Recognition | None = None) -> Recognition:
        """A learning recognition of ``image`` (``rec`` where made already) whose values join the
        instance list and whose queried features count as used (alg. 5.3)."""
        rec = self._learning_recognition(env, image) if rec is None else rec
        self.counting.record(image, rec)
        self._mark_usage(rec.queried)
        return rec

    def _mark_usage(self, features) -> None:
        for f in features:
            self.usage[f] = self.presentations

    def discard_unused(self, since: int) -> list:
        """Remove every feature not queried in a training recognition since presentation ``since``
        (alg. 5.3 step 4); returns them. The networks are re-counted."""
        unused = [f for f in in_use(self.networks) if self.usage.get(f, -1) < since]
        for f in unused:
            self.usage.pop(f, None)
        self.counting.forget(unused, self.networks)
        if unused:
            for net in self.networks.values():
                self.counting.estimate(net, self.settings.pseudocount, self.settings.leak)
        return unused

    def choose_classes(self, rec: Recognition, true: frozenset) -> tuple[Hashable, frozenset, bool] | None:
        """Alg. 4.8 step 1 (table 4.1): (characterized class, discriminated classes, characterized is true).

        The error comes from the final result; the beliefs compared are the final ones unless
        they all have zero entropy, in which case the latest earlier stage with some uncertainty
        is consulted. Ties among characterized classes are broken at random, discriminated ties kept.
        """
        final = rec.beliefs[-1]
        recognized = {c for c, p in final.items() if p > 0.5}
        beliefs = next((b for b in reversed(rec.beliefs) if any(0 < p < 1 for p in b.values())), final)
        trues = [c for c in beliefs if c in true]
        false = [c for c in beliefs if c not in true]
        if true - recognized:
            char_pool, other, char_is_true = trues, false, True
            char_belief = min(beliefs[c] for c in trues)
        elif recognized - true:
            char_pool, other, char_is_true = false, trues, False
            char_belief = max(beliefs[c] for c in false)
        else:
            return None
        char = pick([c for c in char_pool if beliefs[c] == char_belief], self.generator)
        if not other:
            return char, frozenset(), char_is_true
        target = max(beliefs[c] for c in other) if char_is_true else min(beliefs[c] for c in other)
        return char, frozenset(c for c in other if beliefs[c] == target), char_is_true

    def _search(self, env: ImageSet, image: int, char, disc: frozenset, char_is_true: bool, t_ksd: float,
                succeeded) -> bool:
        """Alg. 4.8 from step 2: add one feature characteristic of ``char`` against ``disc`` with
        distinctive power > 0 and >= ``t_ksd`` after which ``succeeded(recognition of image)``.
        Alg. 4.10 (the five methods) is called up to ``search_rounds`` times (alg. 5.1's "until")."""
        sample = image if char_is_true else pick(env.examples(char, self.settings.n_ex, self.generator), self.generator)
        own = env.examples(char, self.settings.n_ex, self.generator)
        examples = list(own)
        for d in sorted(disc, key=str):  # a fixed order: set order varies with the process hash seed
            examples += env.examples(d, self.settings.n_ex, self.generator)
        images = list(dict.fromkeys([image, sample, *examples]))
        contrast = self.settings.contrast
        samples = [sample] if contrast == 1 else list(dict.fromkeys([sample, *own]))
        net = self.networks[char]
        failed: list = []
        for method in [m for _ in range(self.settings.search_rounds) for m in METHODS]:
            tried = set(failed)
            candidates = [f for f in self.candidates(method, self.settings.n_fgen * contrast, self.networks, env,
                                                     samples, char, disc, failed)
                          if f not in net and f not in tried]
            candidates = list(dict.fromkeys(candidates))
            if not candidates:
                continue
            self.counting.measure(env, [*candidates, *net.features], images)
            # trying a candidate changes no candidate's values or classes: discretize them all at once
            cuts, powers = self.counting.discretize(char, candidates, self.settings.cut_position, disc)
            for candidate, cut, power in self._in_order(candidates, cuts.tolist(), powers.tolist(), t_ksd):
                if power <= 0 or power < t_ksd:
                    failed.append(candidate)
                    continue
                self.counting.discriminates[(char, candidate)] = disc
                self.counting.selected[(char, candidate)] = frozenset(images)
                parents, children = compound_arcs(candidate, net.features)
                net.add_feature(candidate, parents, children, threshold=cut)
                self.counting.estimate(net, self.settings.pseudocount, self.settings.leak)
                after = self._learning_recognition(env, image)
                self.counting.record(image, after)
                if succeeded(after):
                    self._mark_usage([*after.queried, candidate])
                    return True
                net.remove_feature(candidate)
                del self.counting.discriminates[(char, candidate)]
                del self.counting.selected[(char, candidate)]
                self.counting.estimate(net, self.settings.pseudocount, self.settings.leak)
                failed.append(candidate)
        return False

    def _in_order(self, candidates: list, cuts: list, powers: list, t_ksd: float) -> list[tuple]:
        """(candidate, cut-point, power) in the order a search tests them: as drawn (alg. 4.10); with
        ``contrast`` N > 1 those that fail the power test first, then the n_fgen most distinctive on
        the search's images, most distinctive first (ties in drawing order)."""
        drawn = list(zip(candidates, cuts, powers))
        if self.settings.contrast == 1:
            return drawn
        fails = [power <= 0 or power < t_ksd for _, _, power in drawn]
        weak = [item for item, failing in zip(drawn, fails) if failing]
        strong = [item for item, failing in zip(drawn, fails) if not failing]
        return weak + sorted(strong, key=lambda item: -item[2])[:self.settings.n_fgen]

    # -- state ---------------------------------------------------------------------------------
    def _networks_state(self, table: FeatureTable) -> list:
        return [{
            "label": _label(label), "features": [table.index(f) for f in net.features],
            "parents": [[table.index(p) for p in net.parents[f]] for f in net.features],
            "threshold": [net.threshold[f] for f in net.features],
            "prior": net.prior.tolist(), "cpt": [encode_array(net.cpt[f]) for f in net.features],
        } for label, net in self.networks.items()]

    def state_dict(self, training: bool = True, table: FeatureTable | None = None, env: ImageSet | None = None) -> dict:
        """The learner state as JSON-ready data, features referred to by position in a feature table.

        ``training=True``: the complete state (instance list, usage, random state), from which
        learning continues exactly; ``False``: what recognition needs (the networks). The table
        is written into the state as "features", unless the caller passes its own ``table``
        (to store features shared with other state once) and writes it. ``env``: the image set it
        learns from, whose value cache the caller writes too; the instance values, which are that
        cache's values, are then written relative to it (nearly nothing), and :meth:`load_state_dict`
        needs the same image set, its cache restored.
        """
        own = table is None
        table = FeatureTable() if own else table
        state = {**self.settings.to_dict(), "primitives": [str(p) for p in self.settings.primitives],
                 "seed": self.seed, "presentations": self.presentations, "sampled": self.sampled,
                 "sides": None if self.sides is None else list(self.sides), "networks": self._networks_state(table)}
        if training:
            instances = self.instances
            state.update({
                "generator": encode_array(self.generator.get_state().numpy().astype(np.float64)),
                "discriminates": [[_label(c), table.index(f), sorted(map(_label, d), key=str)]
                                  for (c, f), d in self.discriminates.items()],
                "selected": [[_label(c), table.index(f), sorted(map(_label, images), key=str)]
                             for (c, f), images in self.counting.selected.items()],
                "usage": [[table.index(f), n] for f, n in self.usage.items()],
                "instances": {"images": [_label(i) for i in instances.images],
                              "labels": [sorted(map(_label, labels), key=str) for labels in instances.labels],
                              "features": [table.index(f) for f in instances.features],
                              "values": encode_array(instances.values_table(), _cached(env, instances.features, instances.images))},
            })
        if own:
            state["features"] = table.pack()
        return state

    def load_state_dict(self, state: dict, features: list[Feature] | None = None, env: ImageSet | None = None) -> None:
        """Restore a state written by :meth:`state_dict` (``features``: the caller's table, where it
        kept one; ``env``: the image set whose cache its instance values were written relative to);
        ValueError or InputError where it is damaged. A recognition-only state gives a learner that
        recognizes but refuses to learn."""
        features = unpack_features(state["features"]) if features is None else features
        at = lambda i: features[stored_position(i, len(features))]  # noqa: E731
        # a state written before an option existed ran with the thesis's value (test_information: with
        # min_information's, which its answers used)
        stored = {k: state[k] for k in ("n_ex", "n_fgen", "min_information")}  # in every state
        stored.update({k: state[k] for k in LearnerSettings.names() if k in state})
        stored.setdefault("test_information", stored["min_information"])  # validated by LearnerSettings
        self.seed = whole("seed", state.get("seed", 0), 0, MAX_SEED)  # states written before it was recorded: 0
        self.set_params(**{**LearnerSettings.thesis().to_dict(), **stored})
        self.presentations, self.candidates.sampled = _count(state["presentations"]), _count(state["sampled"])
        sides = state.get("sides")  # files written before sides were recorded have none
        if sides is not None and (not isinstance(sides, list) or len(sides) != 2 or _count(sides[0]) > _count(sides[1])):
            raise ValueError(f"sides {sides!r}: expected [smallest, largest] shorter image side")
        self.sides = None if sides is None else (sides[0], sides[1])
        self.networks = {}
        for record in state["networks"]:
            parents = [[at(p) for p in ps] for ps in record["parents"]]
            net = ClassNetwork.of(_label(record["label"]), [at(i) for i in record["features"]], parents,
                                  [_number(t) for t in record["threshold"]], [_number(p) for p in record["prior"]],
                                  [decode_array(table, shape=(2,) * (len(ps) + 2))  # [c, p1..pk, f]
                                   for table, ps in zip(record["cpt"], parents)])
            if net.label in self.networks:
                raise ValueError(f"two networks for class {net.label!r}")
            self.networks[net.label] = net
        if not self.networks and "instances" not in state:
            raise ValueError("a recognition file without a class network")  # a fresh learner's full state has none
        self.trainable = "instances" in state
        self.counting, self.usage = Counting(self.settings.calibrate), {}
        self.generator.set_state(torch.Generator().get_state())  # in place: the parts hold this generator
        if not self.trainable:
            return
        self.generator.set_state(torch.from_numpy(decode_array(state["generator"], shape=GENERATOR_STATE).astype(np.uint8)))
        self.counting.discriminates.update({(c, at(f)): frozenset(d) for c, f, d in state["discriminates"]})
        # files written before selection images were recorded count every node on all instances
        self.counting.selected.update({(c, at(f)): frozenset(i) for c, f, i in state.get("selected", [])})
        self.usage = {at(f): _count(n) for f, n in state["usage"]}
        block = state["instances"]
        for image, labels in zip(block["images"], block["labels"]):
            self.instances.add(image, labels)
        columns = [at(i) for i in block["features"]]
        values = decode_array(block["values"], _cached(env, columns, self.instances.images),
                              shape=(len(self.instances), len(columns)))
        if not are_stored_values(values):
            raise ValueError("instance values outside [0, 1] (feature values are similarities, eq. 3.13)")
        if columns:
            self.instances.set_block(self.instances.images, columns, values.T)
        if len(self.instances.features) < len(columns):
            raise ValueError("an instance feature listed twice")
        known = set(self.instances.images)
        if any(not images <= known for images in self.counting.selected.values()):
            raise ValueError("a node selected on an image that is not an instance")

    def save(self, path, training: bool = False) -> None:
        """Write the learner to ``path`` (JSON, atomically): what recognition needs, or with
        ``training=True`` the complete state (see :meth:`state_dict`); NotFittedError for a learner
        that has learned nothing and would write no network to recognize with."""
        if not training:
            self._check_fitted()
        save_checkpoint(path, KIND, {"learner": self.state_dict(training)})

    @classmethod
    def load(cls, path, device: str | torch.device = "cpu") -> "DistinctiveFeatureLearner":
        """Read a learner written by :meth:`save` (``device``: where it computes records); one clear
        InputError for a damaged or foreign file."""
        data = load_checkpoint(path, KIND)
        learner = cls(device=device)
        try:
            learner.load_state_dict(data["learner"])
        except DAMAGED as err:
            raise InputError(f"{path}: damaged learner checkpoint ({type(err).__name__}: {err})") from None
        return learner
