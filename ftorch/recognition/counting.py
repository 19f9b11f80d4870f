"""What the learner counts (4.4.1, alg. 4.7 step 3): the instance list, the classes each node was
learned to discriminate, node discretization by KSD (def. 4.2) and CPT estimation.

Nodes are discretized against the classes they were learned to discriminate (all other classes
where none is recorded); a node whose KSD has no cut-point keeps its threshold.

Calibrated counting (``calibrate``, cross-fitting): a feature is accepted because it separates
the few images its search measured it on (alg. 4.8: the misrecognized image, the sample, n_ex
examples per class), so on those images it looks better than on any other: its KSD and its CPT
are optimistic. With ``calibrate`` on, the cut-point and the CPT of a node are counted on the
instances *other* than its selection images, wherever those still hold at least ``HELD_OUT``
measured instances of its class and of the classes it is counted against; otherwise (a class
with few training views, a feature just added) on all, as the thesis counts.
"""
from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence

import numpy as np
import torch

from ..ksd import distinctive_at, ksd
from .bayes import ClassNetwork
from .environment import ImageSet
from .inference import Recognition
from .instances import InstanceList
from .settings import LearnerSettings

HELD_OUT = 2  # measured instances each side needs before a calibrated count leaves the selection images out


class Counting:
    """The instance list and the discriminated classes of every node, with the counts made from them.

    ``discriminates[(c, f)]``: the classes node f of c's network was learned to tell c from;
    ``selected[(c, f)]``: the images node f of c's network was selected on (its search's images), which a
    ``calibrate``-d count leaves out (module docstring).
    """

    def __init__(self):
        self.instances = InstanceList()
        self.discriminates: dict[tuple, frozenset] = {}
        self.selected: dict[tuple, frozenset] = {}

    def measure(self, env: ImageSet, features, images) -> None:
        """Enter the values of ``features`` on ``images`` (with their true classes) into the instance list."""
        for image in images:
            self.instances.add(image, env.labels[image])
        features = list(dict.fromkeys(features))
        if features:
            self.instances.set_block(list(images), features, env.values(features, list(images)))

    def record(self, image: int, rec: Recognition) -> None:
        """The values a training recognition measured join the instance list."""
        if rec.queried:
            self.instances.set_block([image], rec.queried, np.array([[rec.values[f]] for f in rec.queried]))

    def held_out(self, label, features: Sequence[Hashable], values: np.ndarray, present: np.ndarray,
                 against: np.ndarray, calibrate: bool) -> np.ndarray:
        """``values`` (F, n) of nodes ``features`` of class ``label``, with each node's selection images set to NaN (not
        counted) where ``calibrate`` is on and the other measured instances still hold ``HELD_OUT`` of
        ``present`` (n,) and of ``against`` (F, n) each; the values unchanged otherwise."""
        rows = [(k, self.selected[label, f]) for k, f in enumerate(features) if (label, f) in self.selected]
        if not calibrate or not rows:
            return values
        column = self.instances.column
        chosen = np.zeros(values.shape, dtype=bool)
        chosen[np.repeat([k for k, images in rows], [len(images) for _, images in rows]),
               [column(i) for _, images in rows for i in images]] = True
        kept = np.isfinite(values) & ~chosen
        enough = ((kept & present).sum(1) >= HELD_OUT) & ((kept & against).sum(1) >= HELD_OUT)
        return np.where(chosen & enough[:, None], np.nan, values)

    def discretize(self, label, features: Sequence[Hashable], settings: LearnerSettings,
                   against: frozenset | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(cut-points, distinctive powers) (F,) of nodes of class ``label``, each against the classes
        it discriminates (def. 4.2; ``against``, where given, for all of them), in one batched KSD;
        the cut-point lies at ``settings.cut_position`` between the two values where the KSD is reached."""
        present = self.instances.has(label)
        others = [against if against is not None else self.discriminates.get((label, f)) for f in features]
        others = [d or frozenset() for d in others]
        masks = {}
        for d in others:
            if d not in masks:
                masks[d] = (self.instances.has_any(d) if d else np.ones_like(present)) & ~present
        discriminated = np.stack([masks[d] for d in others])
        values = self.held_out(label, features, self.instances.block(features), present, discriminated, settings.calibrate)
        result = ksd(torch.from_numpy(values), torch.from_numpy(present), torch.from_numpy(discriminated),
                     settings.cut_position)
        return result.cutpoint.numpy(), result.distinctive.numpy()

    def estimate(self, net: ClassNetwork, settings: LearnerSettings) -> None:
        """Re-count the prior and every CPT of ``net`` at its thresholds: (n + a) / (N + 2a) with the
        ``pseudocount`` a, and the detection-failure ``leak`` of :meth:`ClassNetwork.estimate`."""
        present = self.instances.has(net.label)
        values = self.held_out(net.label, net.features, self.instances.block(net.features), present, ~present,
                               settings.calibrate)
        thresholds = np.array([net.threshold[f] for f in net.features])[:, None]
        coded = np.where(np.isnan(values), -1, (values > thresholds).astype(int))
        states = dict(zip(net.features, coded))
        net.estimate(present, states, settings.pseudocount, settings.leak)

    def reestimate(self, networks: dict[Hashable, ClassNetwork], settings: LearnerSettings) -> None:
        """Alg. 4.7 step 3: re-discretize every node by KSD and re-count every CPT and prior."""
        for label, net in networks.items():
            if net.features:
                cuts, _ = self.discretize(label, net.features, settings)
                for f, cut in zip(net.features, cuts.tolist()):
                    if np.isfinite(cut):
                        net.set_threshold(f, cut)
            self.estimate(net, settings)

    def pair_powers(self, networks: dict[Hashable, ClassNetwork], pairs: list[tuple],
                    cuts: np.ndarray | None = None) -> list[torch.Tensor]:
        """KSD_{c,d}(f) (len(others), len(features)) for each (c, others, features) of ``pairs`` (alg.
        5.2, ``ksd.distinctive_at``): node f at its cut-point in c's network (or at ``cuts``, one per
        feature of the pairs in turn), between instances of c and instances of d that are not of c, for
        every d in ``others``. All pairs are counted in one call (each row with its own class c); the
        counts are exact, as pair by pair."""
        if not pairs:
            return []
        member = {label: self.instances.has(label) for label in
                  dict.fromkeys(x for c, others, _ in pairs for x in (c, *others))}
        values = self.instances.block([f for _, _, features in pairs for f in features])
        if cuts is None:
            cuts = np.array([networks[c].threshold[f] for c, _, features in pairs for f in features], dtype=float)
        present = np.concatenate([np.broadcast_to(member[c], (len(features), len(member[c])))
                                  for c, _, features in pairs])
        against = np.concatenate([np.stack([member[d] for d in others]) & ~member[c] for c, others, _ in pairs])
        powers = distinctive_at(torch.from_numpy(values), torch.from_numpy(cuts), torch.from_numpy(present),
                                torch.from_numpy(against))  # every group against every row: keep each pair's block
        ends = np.cumsum([(len(others), len(features)) for _, others, features in pairs], 0)
        return [powers[d - len(others) : d, f - len(features) : f]
                for (_, others, features), (d, f) in zip(pairs, ends.tolist())]

    def forget(self, features: Iterable[Hashable], networks: dict[Hashable, ClassNetwork]) -> None:
        """Discarded features (alg. 5.3 step 4): their nodes, discriminated classes and instance columns go."""
        features = list(features)
        for f in features:
            for label, net in networks.items():
                if f in net:
                    net.remove_feature(f)
                    self.discriminates.pop((label, f), None)
                    self.selected.pop((label, f), None)
        self.instances.forget(features)
