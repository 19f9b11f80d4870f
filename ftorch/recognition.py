"""Sequential recognition across class networks (alg. 4.4) and its evaluation (def. 4.5, 4.6).

Recognition repeatedly queries the feature with the largest mutual information with any class
node, measures it in the image, and enters presence or absence (value above the node's
threshold) into every network that holds it: positive and negative evidence both count. It
stops when no unqueried feature is informative (I_max <= ``tolerance``). Evidence that a
network deems impossible (probability 0 under its counted CPTs) is not entered there; that
network keeps its belief. Ties in I_max go to the first network, then the first feature.
"""
from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field

from .bayes import ClassNetwork

def outcome(recognized: Iterable[Hashable], true: Iterable[Hashable]) -> str:
    """Category of a recognition result (def. 4.5)."""
    recognized, true = set(recognized), set(true)
    hits, false = recognized & true, recognized - true
    if recognized == true:
        return "correct"
    if not false:
        return "ignorant"
    if hits == true:
        return "ambiguous"
    return "wrong" if len(recognized) == len(true) else "confused"


def accuracy(recognized: Iterable[Hashable], true: Iterable[Hashable], n_classes: int) -> float:
    """Accuracy of one recognition result (def. 4.6)."""
    recognized, true = set(recognized), set(true)
    n_t, n_f = len(recognized & true), len(recognized - true)
    if n_t + n_f == 0:
        return len(true) / n_classes
    return n_t / (len(true) + n_f)


@dataclass
class Recognition:
    """posteriors per class; recognized (> 0.5); features queried in order with their values;
    beliefs after each step (beliefs[0] are the priors), which alg. 4.8 consults."""

    posteriors: dict
    recognized: set
    queried: list = field(default_factory=list)
    values: dict = field(default_factory=dict)
    beliefs: list = field(default_factory=list)


def recognize(networks: dict[Hashable, ClassNetwork], measure: Callable[[Hashable], float],
              tolerance: float = 1e-12) -> Recognition:
    """Alg. 4.4: ``measure(feature)`` returns the feature's value in the current image (eq. 3.14)."""
    evidence = {label: {} for label in networks}
    belief = {label: net.posterior({}) for label, net in networks.items()}
    informative = {label: net.informations({}) for label, net in networks.items()}  # only changed nets are redone
    beliefs = [dict(belief)]
    queried, values = [], {}
    while True:
        best, best_info = None, tolerance
        for label, net in networks.items():
            for key in net.features:
                info = informative[label].get(key, 0.0)
                if info > best_info and key not in values:
                    best, best_info = key, info
        if best is None:
            break
        value = float(measure(best))
        values[best] = value
        queried.append(best)
        for label, net in networks.items():
            if best in net:
                trial = {**evidence[label], best: int(value > net.threshold[best])}
                posterior = net.posterior(trial)
                if posterior == posterior:  # not NaN: the evidence is possible
                    evidence[label], belief[label] = trial, posterior
                    informative[label] = net.informations(trial)
        beliefs.append(dict(belief))
    posteriors = beliefs[-1]
    return Recognition(posteriors, {c for c, p in posteriors.items() if p > 0.5}, queried, values, beliefs)
