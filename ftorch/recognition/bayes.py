"""One Bayesian network per class (4.4.1): the model (structure, CPTs, thresholds, validation,
estimation), inferred exactly by its engine (ftorch/recognition/exact.py), checked against and
exported through pgmpy.

Every node is binary (0 = absent, 1 = present): the class node "class" and one node per feature.
Arcs run from the class node to every feature and between features as the feature structure
asks (see :func:`compound_arcs`): geometric and conjunctive compounds -> their components that
are in the network, and components -> disjunctive compounds.

Probabilities are counted from the instance list (:meth:`ClassNetwork.estimate`): maximum
likelihood, so a configuration seen only with one outcome gets probability 0 or 1 (the text
relies on this: a feature can drive its class entropy to zero, 4.4.4); a parent configuration
never seen gets 1/2 (no information). The prior of the class node is counted the same way.

The model changes only through its methods; each change drops its :class:`Snapshot`, the
immutable network as it stands that the inference engine consumes (ftorch/recognition/exact.py,
:func:`~ftorch.recognition.exact.engine`, which keeps the engines outside the model).
"""
from __future__ import annotations

import re
from collections.abc import Hashable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from ..space.features import Feature

CLASS = "class"  # the class node's name


def _identifier(text: str) -> str:
    """``text`` as an identifier of the exported formats (BIF): runs of other characters become one '_'."""
    return re.sub(r"\W+", "_", text).strip("_")


def _check_distribution(name: str, table: np.ndarray, shape: tuple) -> None:
    """ValueError unless ``table`` has ``shape`` and holds distributions over its last axis."""
    if table.shape != shape:
        raise ValueError(f"{name} has shape {table.shape}, expected {shape}")
    if not (np.all(np.isfinite(table)) and np.all((table >= 0) & (table <= 1))):
        raise ValueError(f"{name} has entries that are not probabilities (NaN, infinite or outside [0, 1])")
    if not np.allclose(table.sum(-1), 1.0, rtol=0, atol=1e-6):
        raise ValueError(f"{name} does not sum to 1 over the node's states")


def compound_arcs(feature: Feature, present) -> tuple[list, list]:
    """(parents, children) of ``feature`` among the ``present`` features, by the rules of 4.4.1:
    each compound type says which way the arcs to its components run (``ARCS_TO_COMPONENTS``)."""
    parents: list[Feature] = []
    children: list[Feature] = []
    own = set(feature.components())
    for other in present:
        if other == feature:
            continue
        if other in own:  # other is a component of feature
            (children if feature.ARCS_TO_COMPONENTS else parents).append(other)
        elif feature in set(other.components()):  # feature is a component of other
            (parents if other.ARCS_TO_COMPONENTS else children).append(other)
    return parents, children


@dataclass(frozen=True)
class Snapshot:
    """A class network as it stands, immutable (its CPTs are read-only arrays): what its exact inference
    engine consumes. A change to the network makes a new one; a threshold is no part of it."""

    label: Hashable
    features: tuple[Hashable, ...]
    parents: Mapping[Hashable, tuple[Hashable, ...]]
    cpt: Mapping[Hashable, np.ndarray]  # P(F | class, parents...) indexed [c, p1..pk, f]
    prior: np.ndarray  # P(class) as (absent, present)
    table_limit: int


def _same(old: np.ndarray | None, new: np.ndarray) -> bool:
    """Whether ``new`` repeats ``old`` byte for byte (shape included; None: there was none)."""
    return old is not None and old.shape == new.shape and old.tobytes() == new.tobytes()


class ClassNetwork:
    """The Bayesian network of one class: prior, feature nodes, arcs, CPTs and thresholds.

    Queries (posteriors, informations, joints) go to the exact inference engine of its :meth:`snapshot`.
    ``features`` (a tuple), ``parents`` (tuples), ``threshold`` and ``cpt`` are read-only views:
    the network changes only through its methods (:meth:`add_feature`, :meth:`remove_feature`,
    :meth:`add_arc`, :meth:`set_threshold`, :meth:`set_cpt`, :meth:`estimate`, the ``prior``
    setter), each of which drops the snapshot, so that the next query's engine is built from the
    network as it then stands. CPTs are replaced, never edited in place (they are read-only arrays).
    ``revision`` counts those changes (thresholds included): equal revisions of one network object
    mean the same network, so a recognition made at one still holds (the learner's blocks). A CPT or
    prior replaced by the same bytes, or a threshold by an equal value, is no change: the snapshot,
    its engine and the engine's memories stay.
    ``table_limit``: linked groups up to this many nodes are compiled to tables (0: all by einsum).
    """

    TABLE_LIMIT = 14

    def __init__(self, label: Hashable, table_limit: int = TABLE_LIMIT):
        self.label = label
        self.table_limit = table_limit
        self._features: tuple[Hashable, ...] = ()
        self._parents: dict[Hashable, tuple[Hashable, ...]] = {}
        self._threshold: dict[Hashable, float] = {}
        self._cpt: dict[Hashable, np.ndarray] = {}  # P(F | class, parents...) indexed [c, p1..pk, f]
        self.parents: Mapping[Hashable, tuple[Hashable, ...]] = MappingProxyType(self._parents)
        self.threshold: Mapping[Hashable, float] = MappingProxyType(self._threshold)
        self.cpt: Mapping[Hashable, np.ndarray] = MappingProxyType(self._cpt)
        self._snapshot: Snapshot | None = None
        self.revision = 0
        self.prior = np.array([0.5, 0.5])

    @classmethod
    def of(cls, label: Hashable, features: list, parents: list[list], thresholds: list[float], prior,
           cpts: list) -> "ClassNetwork":
        """The network given node by node, as a file stores it; ValueError where it is not valid."""
        if not len(features) == len(parents) == len(thresholds) == len(cpts):
            raise ValueError(f"network of class {label!r}: {len(features)} features but {len(parents)} parent lists, "
                             f"{len(thresholds)} thresholds and {len(cpts)} CPTs")
        net = cls(label)
        net._features = tuple(features)
        net._parents.update((k, tuple(ps)) for k, ps in zip(features, parents))
        net._threshold.update(zip(features, thresholds))
        net.prior = prior
        for key, table in zip(features, cpts):
            net._put(key, table)
        net.validate()
        return net

    @property
    def features(self) -> tuple[Hashable, ...]:
        return self._features

    def __contains__(self, key) -> bool:
        return key in self._parents

    def _put(self, key, table) -> None:
        table = np.array(table, dtype=float)
        table.flags.writeable = False
        old = self._cpt.get(key)
        self._cpt[key] = table
        if not _same(old, table):
            self._changed()  # the same bytes again (a re-count that found the same) change nothing

    def _changed(self) -> None:
        """Any change: the snapshot is dropped and the revision counted."""
        self._snapshot = None
        self.revision += 1

    def set_cpt(self, key: Hashable, table) -> None:
        """Replace node ``key``'s CPT, P(F | class, parents...) indexed [c, p1..pk, f]."""
        shape = (2,) * (len(self._parents[key]) + 2)
        if np.shape(table) != shape:
            raise ValueError(f"CPT of {key!r} has shape {np.shape(table)}, expected {shape}")
        self._put(key, table)

    def set_threshold(self, key: Hashable, value: float) -> None:
        """Node ``key`` is present where its feature's value exceeds ``value`` (its KSD cut-point)."""
        if key not in self:
            raise ValueError(f"feature {key!r} is not in the network of class {self.label!r}")
        old, self._threshold[key] = self._threshold[key], float(value)
        if old != value:  # recognition only compares values with it
            self.revision += 1

    def add_arc(self, parent: Hashable, child: Hashable) -> None:
        """A feature arc parent -> child; the child's CPT returns to 1/2 until re-estimated."""
        if parent not in self or child not in self:
            raise ValueError(f"an arc needs two nodes of the network of class {self.label!r}")
        if parent == child or parent in self._parents[child] or parent in self._descendants(child):
            raise ValueError(f"an arc {parent!r} -> {child!r} would repeat an arc or make a cycle")
        self._parents[child] += (parent,)
        self._put(child, np.full((2,) * (len(self._parents[child]) + 2), 0.5))

    @property
    def prior(self) -> np.ndarray:
        """P(class) as (absent, present)."""
        return self._prior

    @prior.setter
    def prior(self, value) -> None:
        old, self._prior = getattr(self, "_prior", None), np.asarray(value, dtype=float)
        if not _same(old, self._prior):
            self._changed()

    def add_feature(self, key: Hashable, parents=(), children=(), threshold: float = 0.5) -> None:
        """Add a feature node with an arc from the class node and the given feature arcs."""
        if key in self:
            raise ValueError(f"feature {key!r} is already in the network of class {self.label!r}")
        for other in (*parents, *children):
            if other not in self:
                raise ValueError(f"arc to {other!r}, which is not in the network of class {self.label!r}")
        if set(parents) & set(children) or any(p in self._descendants(c) for c in children for p in parents):
            raise ValueError(f"adding {key!r} would make a cycle in the network of class {self.label!r}")
        self._features += (key,)
        self._parents[key] = tuple(parents)
        self._threshold[key] = float(threshold)
        for child in children:
            self._parents[child] += (key,)
        for node in (key, *children):
            self._put(node, np.full((2,) * (len(self._parents[node]) + 2), 0.5))

    def remove_feature(self, key: Hashable) -> None:
        """Remove a feature node and its arcs; its children's CPTs return to 1/2 until re-estimated."""
        self._features = tuple(k for k in self._features if k != key)
        for table in (self._parents, self._threshold, self._cpt):
            del table[key]
        self._changed()
        for node, parents in self._parents.items():
            if key in parents:
                self._parents[node] = tuple(p for p in parents if p != key)
                self._put(node, np.full((2,) * (len(self._parents[node]) + 2), 0.5))

    def validate(self) -> None:
        """ValueError unless this is a valid network: a prior and CPTs that are distributions
        (finite entries in [0, 1] summing to 1 over the node's own states), CPTs of the shape
        their parents give, thresholds in [0, 1], arcs between distinct nodes of the network and
        no cycle. Loaders call it, so a damaged file never recognizes with wrong tables."""
        name = f"network of class {self.label!r}"
        if len(set(self.features)) != len(self.features) or set(self.features) != set(self.parents):
            raise ValueError(f"{name}: a feature node appears twice")
        if set(self.threshold) != set(self.features) or set(self.cpt) != set(self.features):
            raise ValueError(f"{name}: thresholds or CPTs do not match its feature nodes")
        _check_distribution(f"{name}: prior", self.prior, (2,))
        for i, key in enumerate(self.features):
            parents = self.parents[key]
            if len(set(parents)) != len(parents) or key in parents or any(p not in self for p in parents):
                raise ValueError(f"{name}: node {i} has an arc from itself, twice, or from outside the network")
            if key in self._descendants(key):
                raise ValueError(f"{name}: node {i} lies on a cycle")
            if not 0.0 <= self.threshold[key] <= 1.0:  # also refuses NaN
                raise ValueError(f"{name}: node {i} has threshold {self.threshold[key]}, outside [0, 1]")
            _check_distribution(f"{name}: CPT of node {i}", self.cpt[key], (2,) * (len(parents) + 2))

    def _descendants(self, key) -> set:
        out, todo = set(), [key]
        while todo:
            node = todo.pop()
            for child, parents in self.parents.items():
                if node in parents and child not in out:
                    out.add(child)
                    todo.append(child)
        return out

    def estimate(self, present: np.ndarray, states: dict[Hashable, np.ndarray], pseudocount: float = 0.0,
                 leak: float = 0.0) -> None:
        """Count prior and CPTs from instances: ``present`` (n,) bool, ``states`` key -> (n,) in {0, 1, -1 unknown}.

        CPT entries are relative frequencies (4.4.1; ``pseudocount`` 0) or, with a pseudocount a > 0,
        (count + a) / (total + 2a) (Laplace's rule for a = 1), so that no state seen zero times in
        training makes a class impossible; a parent configuration never seen gives 1/2 either way.
        A ``leak`` l > 0 models detection failure: each entry p becomes l + (1 - 2l) p, so a feature
        is missed (or found by chance) with probability at least l whatever the counts said."""
        present = np.asarray(present, dtype=bool)
        self.prior = np.array([0.5, 0.5]) if len(present) == 0 else np.array([1 - present.mean(), present.mean()])
        by_parents: dict[int, list] = {}
        for key in self.features:
            by_parents.setdefault(len(self.parents[key]), []).append(key)
        for k, keys in by_parents.items():  # nodes with k parents: all counted in one bincount
            columns = np.stack([np.stack([present.astype(np.int64), *(np.asarray(states[p]) for p in self.parents[key]),
                                          np.asarray(states[key])]) for key in keys])  # (nodes, class + parents + node, n)
            known = (columns >= 0).all(1)
            index = np.zeros(known.shape, dtype=np.int64)
            for j in range(k + 2):
                index = index * 2 + columns[:, j]
            cells = 2 ** (k + 2)
            index += np.arange(len(keys))[:, None] * cells  # each node its own cells
            counts = np.bincount(index[known], minlength=cells * len(keys)).reshape(len(keys), *(2,) * (k + 2)).astype(float)
            total = counts.sum(-1, keepdims=True)
            tables = np.where(total > 0, (counts + pseudocount) / np.maximum(total + 2 * pseudocount, 1e-300), 0.5)
            if leak:
                tables = leak + (1 - 2 * leak) * tables
            for key, table in zip(keys, tables):
                self._put(key, table)

    def snapshot(self) -> Snapshot:
        """The network as it stands, made at first use after any change (thresholds aside)."""
        if self._snapshot is None:
            prior = self._prior.copy()
            prior.flags.writeable = False
            self._snapshot = Snapshot(self.label, self._features, MappingProxyType(dict(self._parents)),
                                      MappingProxyType(dict(self._cpt)), prior, self.table_limit)
        return self._snapshot

    def node_names(self) -> dict:
        """The exported name of every node: 'class', and per feature its position and kind
        ('f0_texel', 'f1_geometric_edgel_edgel', ...), identifiers as BIF requires."""
        kinds = [_identifier(k.describe() if hasattr(k, "describe") else str(k)) for k in self.features]
        return {CLASS: CLASS, **{k: f"f{i}_{kind}".rstrip("_") for i, (k, kind) in enumerate(zip(self.features, kinds))}}

    def to_pgmpy(self):
        """The network as a pgmpy ``DiscreteBayesianNetwork`` named after its class, nodes named by
        :meth:`node_names`."""
        from pgmpy.factors.discrete import TabularCPD
        from pgmpy.models import DiscreteBayesianNetwork

        name = self.node_names()
        model = DiscreteBayesianNetwork()
        label = _identifier(str(self.label))
        model.name = label if label[:1].isalpha() else f"class_{label}"
        model.add_node(CLASS)
        for key in self.features:
            model.add_node(name[key])
            model.add_edges_from([(name[p], name[key]) for p in [CLASS, *self.parents[key]]])
        states = {v: [0, 1] for v in name.values()}
        cpds = [TabularCPD(CLASS, 2, self.prior.reshape(2, 1), state_names={CLASS: [0, 1]})]
        for key in self.features:
            evidence = [name[p] for p in [CLASS, *self.parents[key]]]
            values = self.cpt[key].reshape(-1, 2).T
            cpds.append(TabularCPD(name[key], 2, values, evidence=evidence, evidence_card=[2] * len(evidence),
                                   state_names={v: states[v] for v in [name[key], *evidence]}))
        model.add_cpds(*cpds)
        return model

    def to_bif(self) -> str:
        """The network in BIF, via pgmpy."""
        from pgmpy.readwrite import BIFWriter

        return str(BIFWriter(self.to_pgmpy()))

    def to_xmlbif(self) -> str:
        """The network in XMLBIF, via pgmpy."""
        from pgmpy.readwrite import XMLBIFWriter

        return str(XMLBIFWriter(self.to_pgmpy()))

