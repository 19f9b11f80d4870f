"""Learning from mistakes (alg. 4.7, 4.8, 4.10) with expert learning (alg. 5.1, 5.2), top to bottom.

:class:`Learning` presents one image at a time (:meth:`Learning.learn`): it recognizes the image
(alg. 4.4) and learns only from mistakes, first by re-discretizing and re-counting (alg. 4.7 step
3), then by searching for one new feature that fixes the mistake (alg. 4.8), generated in order of
structural complexity by the five methods of alg. 4.10, n_fgen candidates each. With a KSD target
t_KSD > 0 (alg. 5.1) a new feature must also reach distinctive power >= t_KSD, and a correct
recognition that leaves some class uncertain triggers expert learning for the least-well-discriminated
class pair (alg. 5.2) when that pair's best consulted feature falls short of t_KSD.

It orchestrates; its parts own their state: :class:`~ftorch.recognition.counting.Counting` the instance
list and the counts made from it (discretization, CPTs), :class:`~ftorch.recognition.candidates.CandidateGenerator`
alg. 4.10's candidates, :class:`~ftorch.recognition.recognizer.Recognizer` alg. 4.4's plans and blocks,
:func:`~ftorch.recognition.expertise.choose_pair` alg. 5.2's pair. Every part reads the one immutable
:class:`~ftorch.recognition.settings.LearnerSettings` it is handed with each call (options: that class's doc).

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
- ``min_information`` stops the recognitions inside learning (alg. 4.7 step 1, alg. 4.8 step 8,
  alg. 5.1), which decide what is a mistake and which features count as used; the answers
  (the estimator's) stop at ``test_information``.
"""
from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import NamedTuple

import numpy as np
import torch

from ..errors import InputError
from ..space.features import Feature
from .bayes import ClassNetwork, compound_arcs
from .candidates import METHODS, CandidateGenerator, in_use, pick, search_order
from .counting import Counting
from .environment import ImageSet
from .expertise import Weakest, choose_pair, makes
from .inference import Outcome, Recognition, Result, outcome, residual_entropy
from .instances import InstanceList
from .recognizer import Ahead, Recognizer
from .settings import Distinctions, LearnerSettings


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


class Search(NamedTuple):
    """One search's question (alg. 4.8 step 1, alg. 5.2): a feature characteristic of ``characterized``
    against the classes ``discriminated``; ``is_true``: whether the characterized class is one of the image's;
    ``also``: the other classes whose distinction from it a candidate should make too (shared distinctions)."""

    characterized: Hashable
    discriminated: frozenset
    is_true: bool
    also: frozenset = frozenset()


class Learning:
    """What a distinctive-feature learner has learned (class networks, instance list, usage, random state)
    and the algorithms that learn it. ``settings`` is replaced, never changed, by its owner."""

    def __init__(self, settings: LearnerSettings, seed: int):
        self.settings = settings
        self.seed = seed
        self.generator = torch.Generator()  # every random choice; set in place on load
        self.blank()

    def blank(self) -> None:
        """The state before any presentation: no network, no instance, the generator at ``seed``."""
        self.generator.manual_seed(self.seed)
        self.networks: dict[Hashable, ClassNetwork] = {}
        self.recognizer = Recognizer()
        self.counting = Counting()
        self.candidates = CandidateGenerator(self.generator)
        self.usage: dict = {}  # feature -> the last presentation whose training recognition queried it (alg. 5.3)
        self.presentations = 0
        self.trainable = True  # False once loaded from a recognition-only state
        self.sides: tuple[int, int] | None = None  # the smallest and largest shorter side of the images learned from

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

    def recognitions(self, env: ImageSet, images, threshold: float, top: bool = False) -> list[Recognition]:
        """Alg. 4.4 on ``images`` of ``env`` with this learner's networks and ``evidence``, stopping at
        ``threshold`` bits; ``top``: with their top labels (:func:`~ftorch.recognition.inference.top_class`)."""
        return self.recognizer.images(self.networks, env, images, threshold, self.settings.positive_only, top)

    def reestimate(self) -> None:
        """Re-discretize every feature node by KSD and re-count every CPT and prior (alg. 4.7 step 3)."""
        self.counting.reestimate(self.networks, self.settings)

    # -- learning (alg. 4.7) -----------------------------------------------------------------
    def learn(self, env: ImageSet, image: int, t_ksd: float = 0.0) -> Presentation:
        """Present one training image (alg. 4.7, and alg. 5.1 with the KSD target ``t_ksd``).

        One learner learns from one :class:`ImageSet`: its image indices are the instance ids.
        """
        self._check_learnable(env, t_ksd)
        image = env.index(image)
        side = min(env.images[image].shape)
        self.sides = (side, side) if self.sides is None else (min(self.sides[0], side), max(self.sides[1], side))
        self.presentations += 1
        true = env.labels[image]
        for label in sorted(true, key=str):  # network order breaks ties in alg. 4.4: keep it fixed
            if label not in self.networks:
                self.networks[label] = ClassNetwork(label)
        self.counting.instances.add(image, true)
        first = self._training_recognition(env, image, self.recognizer.first(
            self.networks, env, image, self.settings.min_information, self.settings.positive_only))
        entropy = residual_entropy(first)
        if outcome(first.recognized, true) is Outcome.CORRECT:
            return self._expert(env, image, first, entropy, t_ksd)
        self.reestimate()
        again = self._training_recognition(env, image)
        if outcome(again.recognized, true) is Outcome.CORRECT:
            return Presentation(first, Result.REESTIMATED, entropy)
        search = self.choose_classes(again, true)
        if search is None:
            return Presentation(first, Result.FAILED, entropy)
        learned = self._search(env, image, search, t_ksd,
                               lambda after: (search.characterized in after.recognized) == search.is_true)
        return Presentation(first, Result.LEARNED if learned else Result.FAILED, entropy,
                            searched=(search.characterized, search.discriminated))

    def _check_learnable(self, env: ImageSet, t_ksd: float) -> None:
        if not 0.0 <= t_ksd <= 1.0:
            raise InputError(f"t_ksd must lie in [0, 1], got {t_ksd}")
        if not env.labeled:
            raise InputError("learning needs labels: this image set was made without the images' true classes")
        if not self.trainable:
            raise InputError("this learner was loaded from a recognition-only file (learner.json) and cannot learn: "
                             "load a state saved with training=True, such as a fold's checkpoint.json, to go on learning")

    def present(self, env: ImageSet, images, t_ksd: float = 0.0) -> list[Presentation]:
        """Present ``images`` in their order, each by :meth:`learn`: one cycle of alg. 5.3.

        Their first recognitions (alg. 4.7 step 1) are made in blocks (:class:`~ftorch.recognition.recognizer.Ahead`):
        a recognition depends only on the networks (structure, CPTs, thresholds, prior), the settings
        and the image's feature values, so while no network changes (the same network objects at the
        same :attr:`~ftorch.recognition.bayes.ClassNetwork.revision`) the recognitions of the next
        images, made together, are the ones each presentation would make; a block is made only where
        every value it reads is in the value cache, so that it computes no value (the cache's rule keeps
        values, not only results, exact); any change drops what remains of it. So the presentations,
        the state and every report are those of :meth:`learn` called image by image (tested).
        """
        images = [env.index(i) for i in images]
        self.recognizer.ahead = Ahead(images)
        try:
            return [self.learn(env, i, t_ksd) for i in images]
        finally:
            self.recognizer.ahead = None

    def _expert(self, env: ImageSet, image: int, rec: Recognition, entropy: dict, t_ksd: float) -> Presentation:
        """Alg. 5.1 steps 2-4 on a correctly recognized image."""
        true = env.labels[image]
        chosen = self.choose_pair(rec, true, entropy)
        if chosen is None:
            return Presentation(rec, Result.CORRECT, entropy)
        c, d, weakest, _ = chosen
        k = self.settings.redundancy
        if makes(weakest, t_ksd, k):
            return Presentation(rec, Result.CORRECT, entropy, (c, d), weakest)
        shared = self.settings.distinctions is Distinctions.SHARED
        also = chosen.short(t_ksd, k) - {d} if shared else frozenset()
        learned = self._search(env, image, Search(c, frozenset({d}), c in true, also), t_ksd,
                               lambda after: outcome(after.recognized, true) is Outcome.CORRECT)
        return Presentation(rec, Result.EXPERT if learned else Result.EXPERT_FAILED, entropy, (c, d), weakest,
                            (c, frozenset({d})))

    def choose_pair(self, rec: Recognition, true: frozenset, entropy: dict) -> Weakest | None:
        """Alg. 5.2 (:func:`ftorch.recognition.expertise.choose_pair` with ``redundancy``): the
        least-well-discriminated pair, or None; with k > 1 the k strongest carriers of every pair scored
        count as used."""
        best, used = choose_pair(self.networks, self.counting, rec, true, entropy, self.settings.redundancy)
        for carriers in used:
            self._mark_usage(carriers)
        return best

    def _learning_recognition(self, env: ImageSet, image: int) -> Recognition:
        """A recognition inside learning: it stops at ``min_information``."""
        return self.recognitions(env, [image], self.settings.min_information)[0]

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
                self.counting.estimate(net, self.settings)
        return unused

    def choose_classes(self, rec: Recognition, true: frozenset) -> Search | None:
        """Alg. 4.8 step 1 (table 4.1): the characterized class, the discriminated classes, and whether
        the characterized class is true.

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
            pool, other, is_true = trues, false, True
            belief = min(beliefs[c] for c in trues)
        elif recognized - true:
            pool, other, is_true = false, trues, False
            belief = max(beliefs[c] for c in false)
        else:
            return None
        characterized = pick([c for c in pool if beliefs[c] == belief], self.generator)
        if not other:
            return Search(characterized, frozenset(), is_true)
        target = max(beliefs[c] for c in other) if is_true else min(beliefs[c] for c in other)
        return Search(characterized, frozenset(c for c in other if beliefs[c] == target), is_true)

    def _search(self, env: ImageSet, image: int, search: Search, t_ksd: float,
                succeeded: Callable[[Recognition], bool]) -> bool:
        """Alg. 4.8 from step 2: add one feature characteristic of the characterized class against the
        discriminated ones with distinctive power > 0 and >= ``t_ksd`` after which ``succeeded(recognition
        of image)``. Alg. 4.10 (the five methods) is called up to ``search_rounds`` times (alg. 5.1's "until")."""
        settings, (label, against, is_true, also) = self.settings, search
        sample = image if is_true else pick(env.examples(label, settings.n_ex, self.generator), self.generator)
        own = env.examples(label, settings.n_ex, self.generator)
        examples = list(own)
        classes = [*sorted(against, key=str), *sorted(also - against, key=str)]  # fixed: set order follows the hash seed
        for d in classes:
            examples += env.examples(d, settings.n_ex, self.generator)
        images = list(dict.fromkeys([image, sample, *examples]))
        samples = [sample] if settings.contrast == 1 else list(dict.fromkeys([sample, *own]))
        net = self.networks[label]
        failed: list = []
        for method in [m for _ in range(settings.search_rounds) for m in METHODS]:
            tried = set(failed)
            drawn = self.candidates(method, settings.n_fgen * settings.contrast, settings, self.networks, env, samples,
                                    label, against, failed)
            candidates = [f for f in drawn if f not in net and f not in tried]
            candidates = list(dict.fromkeys(candidates))
            if not candidates:
                continue
            self.counting.measure(env, [*candidates, *net.features], images)
            # trying a candidate changes no candidate's values or classes: discretize them all at once
            cuts, powers = self.counting.discretize(label, candidates, settings, against)
            for candidate, cut, power in self._in_order(label, classes if also else [], candidates, cuts, powers, t_ksd):
                if not (power <= 0 or power < t_ksd) and self._try(env, image, search, candidate, cut, images, succeeded):
                    return True
                failed.append(candidate)
        return False

    def _try(self, env: ImageSet, image: int, search: Search, candidate: Feature, cut: float, images: list[int],
             succeeded: Callable[[Recognition], bool]) -> bool:
        """Alg. 4.8 steps 6-8: add ``candidate`` at ``cut`` to the characterized class's network and keep it
        where ``succeeded(recognition of image)``; else take it out again. The recognition joins the instances."""
        label, settings, counting = search.characterized, self.settings, self.counting
        net = self.networks[label]
        counting.discriminates[(label, candidate)] = search.discriminated
        counting.selected[(label, candidate)] = frozenset(images)
        parents, children = compound_arcs(candidate, net.features)
        net.add_feature(candidate, parents, children, threshold=cut)
        counting.estimate(net, settings)
        after = self._learning_recognition(env, image)
        counting.record(image, after)
        if succeeded(after):
            self._mark_usage([*after.queried, candidate])
            return True
        net.remove_feature(candidate)
        del counting.discriminates[(label, candidate)]
        del counting.selected[(label, candidate)]
        counting.estimate(net, settings)
        return False

    def _in_order(self, label, classes: list, candidates: list, cuts: np.ndarray, powers: np.ndarray,
                  t_ksd: float) -> list[tuple]:
        """(candidate, cut-point, power) in the order a search tests them (:func:`~ftorch.recognition.candidates.search_order`),
        with each candidate's KSD_{c,x} at its cut-point summed over the ``classes`` x (shared distinctions; 0 without)."""
        served = np.zeros(len(candidates))
        if classes:
            served = self.counting.pair_powers(self.networks, [(label, classes, candidates)], cuts)[0].numpy().sum(0)
        return search_order(candidates, cuts, powers, served, t_ksd, self.settings)
