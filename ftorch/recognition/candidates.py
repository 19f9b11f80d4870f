"""Alg. 4.10: candidate features in order of structural complexity, by five methods, and a sixth
where the learner bounds features to regions.

1. reuse a feature of an unrelated class; 2. a new primitive sampled from the sample image, of a
kind drawn uniformly from the learner's ``primitives`` (the thesis's: texel or edgel pair; the
statistical texture of 7.2.1 where added); 2b. (``regions``) a feature in use or failed before,
bounded to a region around its strongest occurrence in the sample image (``localize``): the whole
image first, as the thesis measures every feature, then narrower discs, general-to-specific (3.6);
3. a geometric expansion of a local feature in use (or failed before) at its strongest occurrence
in the sample image (its new part a salient point, or, with ``texture_parts``, a texture grid
point half of the time: 3.5 with 7.2.1); 4. a conjunction and 5. a disjunction of two such features.

A method's n_fgen candidates are drawn together when the method starts, from the pools as they
stand then (features in use, failed candidates of earlier methods); the learner measures them in
one batch and tests them one by one in order, which is exactly what trying them one at a time
would give under that drawing rule.
"""
from __future__ import annotations

from collections.abc import Callable, Hashable
from enum import StrEnum

import numpy as np
import torch

from ..space.features import Conjunction, Disjunction, Feature, LocalFeature, Within
from ..space.generate import expand_geometric, localize, random_edgel_pair, random_texel, random_texture
from ..space.record import ImageRecords
from ..space.region import Frame
from .bayes import ClassNetwork
from .environment import ImageSet
from .settings import LearnerSettings, Primitive


class Method(StrEnum):
    """Alg. 4.10's five methods of candidate generation, in the order a search tries them."""

    REUSE = "reuse"  # 1: a feature of an unrelated class
    PRIMITIVE = "primitive"  # 2: a new primitive from the sample image
    REGION = "region"  # 2b: a feature bounded to a region around its strongest occurrence (with ``regions``)
    EXPANSION = "expansion"  # 3: a geometric expansion of a local feature
    CONJUNCTION = "conjunction"  # 4
    DISJUNCTION = "disjunction"  # 5


METHODS = tuple(Method)
_SAMPLERS: dict[Primitive, Callable[[ImageRecords, int, torch.Generator | None], Feature | None]] = {
    Primitive.TEXEL: random_texel, Primitive.EDGEL: random_edgel_pair, Primitive.TEXTURE: random_texture}


# The first disc of each frame and the smallest (radius in the frame's units, ftorch.space.region):
# a quarter of the image, or the object's median point distance; each narrowing halves the radius.
RADII = {Frame.IMAGE: (0.25, 1 / 32), Frame.OBJECT: (1.0, 1 / 8)}


def narrowed(feature, frame: Frame) -> float | None:
    """The radius of the next region of ``feature`` in ``frame``: the frame's first where it has none
    there, else half its own; None below the smallest (general-to-specific, 3.6)."""
    first, smallest = RADII[frame]
    if not (isinstance(feature, Within) and feature.region.frame is frame):
        return first
    radius = feature.region.radius / 2
    return radius if radius >= smallest else None


def pick(items: list, generator: torch.Generator):
    """One of ``items``, uniformly."""
    return items[int(torch.randint(len(items), (1,), generator=generator))]


def in_use(networks: dict[Hashable, ClassNetwork]) -> list:
    """Every feature of every network, once, in network order."""
    return list(dict.fromkeys(f for net in networks.values() for f in net.features))


LOCATED_LIMIT = 20_000  # strongest occurrences a generator remembers (each a few scalars)


class CandidateGenerator:
    """Draws alg. 4.10's candidates with ``generator``; :attr:`sampled` counts the features sampled
    from images (methods 2 and 3), the quantity of figures 4.10 and 5.19."""

    def __init__(self, generator: torch.Generator):
        self.generator = generator
        self.sampled = 0
        # method 3's strongest occurrences (generate.strongest) by sample image and feature, for
        # one image set: a feature picked again on the same image is not measured again
        self._located: tuple[object, dict[int, dict]] = (None, {})

    def _occurrences(self, env: ImageSet, sample: int) -> dict:
        """The remembered strongest occurrences on image ``sample`` of ``env`` (``LOCATED_LIMIT`` at most in all)."""
        known, by_image = self._located
        if known is not env or sum(map(len, by_image.values())) >= LOCATED_LIMIT:
            by_image = {}
            self._located = (env, by_image)
        return by_image.setdefault(sample, {})

    def __call__(self, method: Method, n: int, settings: LearnerSettings, networks: dict[Hashable, ClassNetwork],
                 env: ImageSet, samples: list[int], characterized: Hashable, discriminated: frozenset, failed: list) -> list:
        """``n`` candidates of one method for characterizing ``characterized`` against ``discriminated``,
        drawn together, of the kinds ``settings`` allows (``primitives``, ``regions``, ``texture_parts``);
        the methods that sample images take the k-th draw from ``samples[k % len(samples)]`` (the thesis:
        one sample image); ``failed``: earlier candidates of this search."""
        generator = self.generator
        if method is Method.REUSE:  # reuse a feature of an unrelated class
            related = {characterized, *discriminated}
            own = {f for c in related if c in networks for f in networks[c].features}
            pool = [f for label, net in networks.items() if label not in related for f in net.features if f not in own]
            pool = list(dict.fromkeys(pool))
            return [pick(pool, generator) for _ in range(n)] if pool else []
        if method is Method.PRIMITIVE:  # new primitive from the sample image; with the thesis's two, rand < 1/2 draws a texel
            kinds = settings.primitives
            return self._sampled([_SAMPLERS[kinds[int(torch.rand(1, generator=generator) * len(kinds))]](
                env.record(samples[k % len(samples)]), 0, generator) for k in range(n)])
        pool = in_use(networks) + failed
        if method is Method.REGION:
            return self._regions(n, pool, env, samples, settings.regions) if settings.regions and pool else []
        if method is Method.EXPANSION:  # geometric expansion at the strongest occurrence
            local = [f for f in pool if isinstance(f, LocalFeature)]
            if not local:
                return []
            return self._sampled([expand_geometric(pick(local, generator), env.record(sample), 0, generator,
                                                   located=self._occurrences(env, sample), texture=settings.texture_parts)
                                  for sample in (samples[k % len(samples)] for k in range(n))])
        if len(pool) < 2:
            return []
        kind = Conjunction if method is Method.CONJUNCTION else Disjunction
        made = []
        for _ in range(n):
            a = pick(pool, generator)
            b = pick([f for f in pool if f != a], generator)
            made.append(kind(a, b))
        return made

    def _regions(self, n: int, pool: list, env: ImageSet, samples: list[int], regions: tuple[Frame, ...]) -> list:
        """Method 2b: features of ``pool`` each bounded to a region of a frame drawn from ``regions``,
        the disc :func:`narrowed` gives, around its strongest occurrence in its sample image."""
        made = []
        for k in range(n):
            feature = pick(pool, self.generator)
            frame = regions[int(torch.randint(len(regions), (1,), generator=self.generator))]
            radius = narrowed(feature, frame)
            sample = samples[k % len(samples)]
            if radius is not None:
                made.append(localize(feature, env.record(sample), 0, frame, radius, self._occurrences(env, sample)))
        return self._sampled(made)

    def _sampled(self, made: list) -> list:
        """The features an image gave (None: it offered no suitable point), counted in :attr:`sampled`."""
        made = [f for f in made if f is not None]
        self.sampled += len(made)
        return made


def search_order(candidates: list, cuts: np.ndarray, powers: np.ndarray, served: np.ndarray, t_ksd: float,
                 settings: LearnerSettings) -> list[tuple]:
    """(candidate, cut-point, power) in the order a search tests them: as drawn (alg. 4.10), those that
    serve more class distinctions (``served``: a candidate's distinctive power summed over the distinctions
    it is to make; shared distinctions) first; with ``contrast`` N > 1 those that fail the power test
    first, then the n_fgen most distinctive on the search's images, most served first, then most
    distinctive (ties in drawing order)."""
    drawn = list(zip(candidates, cuts.tolist(), powers.tolist(), (-served).tolist()))
    if settings.contrast == 1:
        return [item[:3] for item in sorted(drawn, key=lambda item: item[3])]
    fails = [power <= 0 or power < t_ksd for _, _, power, _ in drawn]
    weak = [item[:3] for item, failing in zip(drawn, fails) if failing]
    strong = [item for item, failing in zip(drawn, fails) if not failing]
    return weak + [item[:3] for item in sorted(strong, key=lambda item: (item[3], -item[2]))[:settings.n_fgen]]
