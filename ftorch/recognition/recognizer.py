"""The recognizer of a learner: alg. 4.4 over its class networks, for one image or a block of images.

It owns the plans (the networks' structures as alg. 4.4 indexes them), the choice between the
block path (:func:`~ftorch.recognition.inference.recognize_block`) and the reference, image by image
(:func:`~ftorch.recognition.inference.recognize`), and the recognitions made ahead of the presentations
of one cycle (:class:`Ahead`, set by the learner's ``present``). The block path equals the reference bit for bit: the tests and
``python -m training.bench recognition`` check it. Which path runs changes the work, never a result.
"""
from __future__ import annotations

from collections.abc import Hashable

import numpy as np

from .bayes import ClassNetwork
from .candidates import in_use
from .environment import ImageSet
from .inference import Plan, Recognition, recognize, recognize_block
from .value_cache import ValueCache

# From this many images on, alg. 4.4 runs as one block (recognize_block), below it image by image
# (recognize): a block's steps cost numpy calls per network, an image's steps Python on scalars
# (docs/benchmark.md, "Feature space and exact inference": a block pays from about 20 images on).
BLOCK_MIN = 24


def feature_values(env: ImageSet, features: list, images: list[int]) -> np.ndarray:
    """``env.values(features, images)`` (features x images), (0, len(images)) without features."""
    return env.values(features, images) if features else np.zeros((0, len(images)))


def signature(networks: dict[Hashable, ClassNetwork]) -> tuple:
    """What a recognition depends on besides the values and settings: the network objects at their revisions."""
    return tuple((label, net, net.revision) for label, net in networks.items())


class Ahead:
    """The first recognitions of the presentations still to come in one cycle, made in blocks and
    kept while the networks' :func:`signature` holds. A block is made only once the networks have
    stood for ``BLOCK_MIN`` presentations (a block is faster than image by image from there on, and a
    stable past predicts a stable future); it then spans as many presentations as they have stood, at
    most ``LIMIT``. The size changes only the work, never a result."""

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


class Recognizer:
    """Alg. 4.4 for one learner: its plans (the latest two kept, so that a structure seen again is not
    indexed again) and, inside one cycle, the recognitions made ahead (``ahead``, an :class:`Ahead`)."""

    def __init__(self):
        self.plans: list[Plan] = []  # the latest first
        self.ahead: Ahead | None = None

    def table(self, networks: dict[Hashable, ClassNetwork], table: np.ndarray, threshold: float, positive_only: bool,
              top: bool = False) -> list[Recognition]:
        """Alg. 4.4 on a block of images given their values ``table`` (features in :func:`in_use` order, which
        is the plan's, x images), stopping at ``threshold`` bits: as a block from ``BLOCK_MIN`` images on,
        else image by image (the same recognitions either way); ``top``: with their top labels."""
        plan = Plan.of(networks, *self.plans)
        self.plans = [plan, *(p for p in self.plans if p is not plan)][:2]
        tolerance = max(threshold, 1e-12)
        if table.shape[1] >= BLOCK_MIN:
            return recognize_block(networks, table, tolerance, positive_only, plan, top)
        return [recognize(networks, dict(zip(plan.keys, column)).__getitem__, tolerance, positive_only, plan, top)
                for column in table.T.tolist()]

    def images(self, networks: dict[Hashable, ClassNetwork], env: ImageSet, images, threshold: float,
               positive_only: bool, top: bool = False) -> list[Recognition]:
        """Alg. 4.4 on ``images`` of ``env``: every feature of every network measured on all of them in one batch."""
        images = [env.index(i) for i in images]
        return self.table(networks, feature_values(env, in_use(networks), images), threshold, positive_only, top)

    def first(self, networks: dict[Hashable, ClassNetwork], env: ImageSet, image: int, threshold: float,
              positive_only: bool) -> Recognition | None:
        """Inside a cycle (``ahead`` set), the presentation's first recognition: from the block made ahead
        where it still holds, else made now with the next images'; None outside a cycle."""
        ahead = self.ahead
        if ahead is None:
            return None
        now = signature(networks)
        rec = ahead.take(image, now)
        if rec is None:
            features = in_use(networks)
            table = feature_values(env, features, [image])  # asked for as one image's recognition asks
            following = ahead.following(env.cache, features)
            if following:
                table = np.concatenate([table, feature_values(env, features, following)], 1)
            rec = ahead.keep(self.table(networks, table, threshold, positive_only), now)
        return rec
