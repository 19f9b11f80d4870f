"""Alg. 5.2: the least-well-discriminated class pair of a correct recognition (expert learning).

KSD_{c,d}(f) is the distinctive power of node f at the cut-point it has in c's network, between
instances of c and instances of d that are not of c (``ksd.distinctive_at``); a class with no
consulted feature of its own scores 0 against every d.

With ``redundancy`` k > 1 (7.2.4) a pair's score is its support, the k-th largest KSD_{c,d}(f)
over all features f of c's network (0 with fewer than k); c ranges over the uncertain classes
and the true classes (a certain recognition may rest on a single feature); and the k strongest
carriers of every pair scored count as used (alg. 5.3 step 4), since recognition stops
consulting once a class is certain. k = 1 is alg. 5.2 as printed.

Support already counts one feature for every distinction it makes: any feature of c's network
counts against every d it separates. Shared distinctions (``distinctions`` shared, an option) go one
step further in the search: once a pair (c, d) is chosen, c is often short of support against several
classes at once (:meth:`Weakest.short`, by :func:`makes`), and the expert search for (c, d) then
also measures its candidates on examples of those classes and tries first the candidates whose
distinctive power, summed over these distinctions, is largest; the acceptance test stays alg. 5.1's
against d. Measured on the selection seeds, it neither shrinks the networks nor keeps the accuracy
(docs/decisions.md), so the default is the thesis's one pair per search.
"""
from __future__ import annotations

from collections.abc import Hashable
from typing import NamedTuple

import numpy as np

from .bayes import ClassNetwork
from .counting import Counting
from .inference import Recognition


class Weakest(NamedTuple):
    """Alg. 5.2's least-well-discriminated pair (c, d) with its support KSD_{c,d} (eq. 5.1, the k-th
    largest with redundancy k), and c's support against every class d' scored with it (``support``)."""

    characterized: Hashable
    discriminated: Hashable
    ksd: float
    support: dict

    def short(self, t_ksd: float, redundancy: int) -> frozenset:
        """The classes d' whose distinction from c lacks support at the KSD target (:func:`makes`)."""
        return frozenset(d for d, score in self.support.items() if not makes(score, t_ksd, redundancy))


def makes(support, t_ksd: float, redundancy: int):
    """Whether ``support`` (a KSD_{c,d}, or an array of them) makes the distinction at the target t_KSD
    (alg. 5.1); with redundancy k > 1 it must also exceed 0 (a carried pair needs distinctive power)."""
    return (support >= t_ksd) & (support > 0) if redundancy > 1 else support >= t_ksd


def choose_pair(networks: dict[Hashable, ClassNetwork], counting: Counting, rec: Recognition, true: frozenset,
                entropy: dict, redundancy: int = 1) -> tuple[Weakest | None, list[set]]:
    """(:class:`Weakest`: the least-well-discriminated pair of a class c with residual entropy and a
    class d on the other side of the truth (eq. 5.1), or None if no class is uncertain or no such
    pair exists; the carriers that count as used, one set per pair scored (k > 1 only))."""
    k = redundancy
    labels = list(networks)
    pairs = []  # (c, the classes d, c's carriers)
    for c in labels:
        if entropy.get(c, 0.0) <= 0 and not (k > 1 and c in true):
            continue
        others = [d for d in labels if (d in true) != (c in true)]
        if others:
            pairs.append((c, others, [f for f in networks[c].features if k > 1 or f in rec.values]))
    powers = iter(counting.pair_powers(networks, [pair for pair in pairs if pair[2]]))  # (others, carriers) each
    best, used = None, []
    for c, others, carriers in pairs:
        if carriers:
            block = next(powers)
            strongest = [p.topk(min(k, len(p))) for p in block]
            scores = [float(top.values[-1]) if len(top.values) == k else 0.0 for top in strongest]
            if k > 1:
                used.append({carriers[i] for top in strongest for i in top.indices.tolist()})
        else:
            scores = [0.0] * len(others)
        j = int(np.argmin(scores))
        if best is None or scores[j] < best.ksd:
            best = Weakest(c, others[j], scores[j], dict(zip(others, scores)))
    return best, used
