"""The distinctive-feature learner as an estimator in the manner of scikit-learn: the face of
:class:`~ftorch.recognition.learning.Learning` (alg. 4.7, 4.8, 5.1, 5.2), whose state it fits, answers
with (alg. 4.4, def. 4.5, 4.6) and saves (:mod:`ftorch.recognition.state`).

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

import numpy as np
import torch

from ..checkpoint import load_checkpoint, reading, save_checkpoint
from ..errors import InputError, NotFittedError
from ..settings import as_device
from ..space.features import Feature, FeatureTable
from ..space.record import FeatureSpace
from . import state as saved
from .environment import ImageSet
from .explain import Explanation, trace
from .inference import Answer, Recognition, accuracy, top1_accuracy
from .learning import Learning
from .settings import LearnerSettings, threshold_bits
from .stages import MAX_CYCLES, Schedule, Stage


class DistinctiveFeatureLearner(Learning):
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
        super().__init__((LearnerSettings() if settings is None else settings).replace(**options),
                         saved.checked_seed(seed))
        self.device = device
        self.space = FeatureSpace().to(as_device(device))

    def blank(self) -> None:
        super().blank()
        self.images_: ImageSet | None = None  # the images fit and partial_fit learned from
        self.stages_: list[Stage] = []  # fit's stages

    @classmethod
    def thesis(cls, *, seed: int = 0, device: str | torch.device = "cpu", **options) -> "DistinctiveFeatureLearner":
        """A learner with the dissertation's settings (:meth:`LearnerSettings.thesis`), changed by ``options``."""
        return cls(LearnerSettings.thesis(), seed=seed, device=device, **options)

    def get_params(self, deep: bool = True) -> dict:
        """The constructor's arguments (scikit-learn's estimator API: ``sklearn.base.clone`` makes an unfitted copy)."""
        return {"settings": self.settings, "seed": self.seed, "device": self.device}

    def set_params(self, **params) -> "DistinctiveFeatureLearner":
        """Change ``settings``, ``seed`` or ``device``, or single settings by name, validated as the
        constructor validates them, and return the learner; e.g. ``set_params(evidence="positive",
        test_information=0.1)`` answers with another evidence mode and threshold (the robustness benchmark).
        A new seed takes effect at the next ``fit``."""
        settings = params.pop("settings", self.settings)
        if not isinstance(settings, LearnerSettings):
            raise InputError(f"settings must be a LearnerSettings, got {type(settings).__name__}")
        if "seed" in params:
            self.seed = saved.checked_seed(params.pop("seed"))
        if "device" in params:
            self.device = params.pop("device")
            self.space = self.space.to(as_device(self.device))
        self.settings = settings.replace(**params)
        return self

    @property
    def classes_(self) -> list:
        """The classes learned, in network order (the columns of :meth:`predict_proba`)."""
        self._check_fitted()
        return list(self.networks)

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
        self.blank()
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
        threshold = self.settings.test_information if information is None else threshold_bits("information", information)
        return self.recognitions(env, images, threshold, top=True)

    def explain(self, image) -> Explanation:
        """The trace of this learner's recognition of one ``image`` (a file path, array or tensor): the
        features alg. 4.4 queried in order, their values, presence per network and location, each
        class's belief after each query, and a picture of it (:mod:`ftorch.recognition.explain`). Its
        answer is ``predict([image])[0]``: the same recognition, with ``test_information`` and ``evidence``."""
        self._check_fitted()  # before anything is measured
        if isinstance(image, (list, tuple, ImageSet)):
            raise InputError("explain takes one image (a file path, array or tensor); predict takes a list")
        env = ImageSet([image], space=self.space)
        return trace(self.networks, self.settings, env, self.recognize(env, 0))

    # -- saving and loading (ftorch.recognition.state) -----------------------------------------
    def state_dict(self, training: bool = True, table: FeatureTable | None = None, env: ImageSet | None = None) -> dict:
        """:func:`ftorch.recognition.state.state_dict` of this learner."""
        return saved.state_dict(self, training, table, env)

    def load_state_dict(self, state: dict, features: list[Feature] | None = None, env: ImageSet | None = None) -> None:
        """:func:`ftorch.recognition.state.load_state_dict` into this learner."""
        saved.load_state_dict(self, state, features, env)

    def save(self, path, training: bool = False) -> None:
        """Write the learner to ``path`` (JSON, atomically): what recognition needs, or with
        ``training=True`` the complete state (see :meth:`state_dict`); NotFittedError for a learner
        that has learned nothing and would write no network to recognize with."""
        if not training:
            self._check_fitted()
        save_checkpoint(path, saved.KIND, {"learner": self.state_dict(training)})

    @classmethod
    def load(cls, path, device: str | torch.device = "cpu") -> "DistinctiveFeatureLearner":
        """Read a learner written by :meth:`save` (``device``: where it computes records); one clear
        InputError for a damaged or foreign file."""
        data = load_checkpoint(path, saved.KIND)
        learner = cls(device=device)
        with reading(path, "learner checkpoint"):
            learner.load_state_dict(data["learner"])
        return learner
