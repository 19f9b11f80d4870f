"""One Bayesian network per class (4.4.1), held as a pgmpy model of record, with fast exact inference.

Every node is binary (0 = absent, 1 = present): the class node "class" and one node per feature.
Arcs run from the class node to every feature and between features as the feature structure
asks (see :func:`compound_arcs`): geometric and conjunctive compounds -> their components that
are in the network, and components -> disjunctive compounds.

Probabilities are counted from the instance list (:meth:`ClassNetwork.estimate`): maximum
likelihood, so a configuration seen only with one outcome gets probability 0 or 1 (the text
relies on this: a feature can drive its class entropy to zero, 4.4.4); a parent configuration
never seen gets 1/2 (no information). The prior of the class node is counted the same way.

Inference (:meth:`ClassNetwork.joint`) is exact: nodes that are neither evidence, query nor an
ancestor of either are barren and dropped; nodes without feature arcs contribute their CPT
column directly (closed form); the CPTs of the remaining linked nodes, sliced at the evidence,
are contracted with one ``einsum``. Tests prove it equal to pgmpy's VariableElimination.
"""
from __future__ import annotations

import math
from collections.abc import Hashable

import numpy as np

from .features import Conjunction, Disjunction, Feature, Geometric, Texel

CLASS = "class"
_LETTERS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"


def _information(joint: np.ndarray) -> np.ndarray:
    """Mutual information in bits of joint tables (k, 2, 2); 0 where a table is NaN."""
    outer = joint.sum(2, keepdims=True) * joint.sum(1, keepdims=True)
    ratio = np.where(joint > 0, joint / np.where(outer > 0, outer, 1), 1)
    info = np.sum(np.where(joint > 0, joint * np.log2(ratio), 0), axis=(1, 2))
    return np.where(np.isfinite(info), info, 0.0)


def components(feature: Feature) -> list[Feature]:
    """Direct and indirect sub-features a compound is built from (3.5)."""
    if isinstance(feature, (Conjunction, Disjunction)):
        return [feature.a, feature.b, *components(feature.a), *components(feature.b)]
    if isinstance(feature, Geometric):
        parts = feature.parts
        found: list[Feature] = [Geometric(parts[:k]) for k in range(2, len(parts))]
        if parts[0].kind == "texel":
            found.append(Texel(parts[0].vector))
        return found
    return []


def compound_arcs(feature: Feature, present) -> tuple[list, list]:
    """(parents, children) of ``feature`` among the ``present`` features, by the rules of 4.4.1."""
    parents, children = [], []
    own = set(components(feature))
    for other in present:
        if other == feature:
            continue
        if other in own:  # other is a component of feature
            (parents if isinstance(feature, Disjunction) else children).append(other)
        elif feature in set(components(other)):  # feature is a component of other
            (children if isinstance(other, Disjunction) else parents).append(other)
    return parents, children


class ClassNetwork:
    """The Bayesian network of one class: prior, feature nodes, arcs, CPTs and thresholds."""

    def __init__(self, label: Hashable):
        self.label = label
        self.features: list[Hashable] = []
        self.parents: dict[Hashable, list[Hashable]] = {}
        self.threshold: dict[Hashable, float] = {}
        self.prior = np.array([0.5, 0.5])
        self.cpt: dict[Hashable, np.ndarray] = {}  # P(F | class, parents...) indexed [c, p1..pk, f]

    def __contains__(self, key) -> bool:
        return key in self.parents

    def add_feature(self, key: Hashable, parents=(), children=(), threshold: float = 0.5) -> None:
        """Add a feature node with an arc from the class node and the given feature arcs."""
        if key in self:
            raise ValueError(f"feature {key!r} is already in the network of class {self.label!r}")
        for other in (*parents, *children):
            if other not in self:
                raise ValueError(f"arc to {other!r}, which is not in the network of class {self.label!r}")
        if set(parents) & set(children) or any(p in self._descendants(c) for c in children for p in parents):
            raise ValueError(f"adding {key!r} would make a cycle in the network of class {self.label!r}")
        self.features.append(key)
        self.parents[key] = list(parents)
        self.threshold[key] = float(threshold)
        for child in children:
            self.parents[child].append(key)
        for node in (key, *children):
            self.cpt[node] = np.full((2,) * (len(self.parents[node]) + 2), 0.5)

    def remove_feature(self, key: Hashable) -> None:
        """Remove a feature node and its arcs; its children's CPTs return to 1/2 until re-estimated."""
        self.features.remove(key)
        for table in (self.parents, self.threshold, self.cpt):
            del table[key]
        for node, parents in self.parents.items():
            if key in parents:
                parents.remove(key)
                self.cpt[node] = np.full((2,) * (len(parents) + 2), 0.5)

    def _descendants(self, key) -> set:
        out, todo = set(), [key]
        while todo:
            node = todo.pop()
            for child, parents in self.parents.items():
                if node in parents and child not in out:
                    out.add(child)
                    todo.append(child)
        return out

    def _ancestors(self, keys) -> set:
        out, todo = set(), list(keys)
        while todo:
            for parent in self.parents[todo.pop()]:
                if parent not in out:
                    out.add(parent)
                    todo.append(parent)
        return out | set(keys)

    def estimate(self, present: np.ndarray, states: dict[Hashable, np.ndarray]) -> None:
        """Count prior and CPTs from instances: ``present`` (n,) bool, ``states`` key -> (n,) in {0, 1, -1 unknown}."""
        present = np.asarray(present, dtype=bool)
        self.prior = np.array([0.5, 0.5]) if len(present) == 0 else np.array([1 - present.mean(), present.mean()])
        for key in self.features:
            columns = [present.astype(np.int64)] + [np.asarray(states[p]) for p in self.parents[key]] + [np.asarray(states[key])]
            known = np.all([c >= 0 for c in columns], axis=0)
            index = np.zeros(int(known.sum()), dtype=np.int64)
            for c in columns:
                index = index * 2 + c[known]
            counts = np.bincount(index, minlength=2 ** len(columns)).reshape((2,) * len(columns)).astype(float)
            total = counts.sum(-1, keepdims=True)
            self.cpt[key] = np.where(total > 0, counts / np.maximum(total, 1), 0.5)

    def joint(self, evidence: dict[Hashable, int], query: Hashable | None = None) -> np.ndarray:
        """P(class | evidence) (2,), or P(class, query | evidence) (2, 2) for an unobserved feature.

        NaN where the evidence has probability zero under the network.
        """
        if query is not None and query in evidence:
            raise ValueError(f"query {query!r} is already observed")
        linked = self._linked()
        # arc-free nodes hang off the class node alone: their factors multiply in directly
        weight = self.prior.copy()
        for key in evidence:
            if key not in linked:
                weight = weight * self.cpt[key][:, evidence[key]]
        relevant = self._ancestors([*evidence, *([query] if query is not None else [])]) if linked else set()
        nodes = [k for k in self.features if k in relevant and k in linked]
        if nodes:
            weight = self._contract(weight, nodes, evidence, query if query in linked else None)
        if query is not None and query not in linked:
            weight = weight[:, None] * self.cpt[query]
        total = weight.sum()
        return weight / total if total > 0 else np.full_like(weight, math.nan)

    def _linked(self) -> set:
        """Feature nodes with a feature parent or a feature child."""
        return {p for ps in self.parents.values() for p in ps} | {f for f, ps in self.parents.items() if ps}

    def _contract(self, weight: np.ndarray, nodes: list, evidence: dict, query) -> np.ndarray:
        """Exact marginal over the class (and query) of the linked part of the network, by einsum."""
        if len(nodes) + 1 > len(_LETTERS):
            raise ValueError(f"network of class {self.label!r} is too large for exact inference ({len(nodes)} nodes)")
        letter = {CLASS: _LETTERS[0], **{k: _LETTERS[i + 1] for i, k in enumerate(nodes)}}
        operands, subscripts = [weight], [letter[CLASS]]
        for key in nodes:
            axes = [CLASS, *self.parents[key], key]
            index = tuple(evidence[a] if a in evidence else slice(None) for a in axes)
            operands.append(self.cpt[key][index])
            subscripts.append("".join(letter[a] for a in axes if a not in evidence))
        output = letter[CLASS] + (letter[query] if query is not None else "")
        return np.einsum(",".join(subscripts) + "->" + output, *operands, optimize=len(operands) > 3)

    def posterior(self, evidence: dict[Hashable, int]) -> float:
        """P(class present | evidence)."""
        return float(self.joint(evidence)[1])

    def mutual_information(self, query: Hashable, evidence: dict[Hashable, int]) -> float:
        """I(C, F_query | evidence) in bits, eq. 4.2; 0 for an observed feature (alg. 4.4)."""
        if query in evidence:
            return 0.0
        return float(_information(self.joint(evidence, query)[None])[0])

    def informations(self, evidence: dict[Hashable, int]) -> dict[Hashable, float]:
        """I(C, F | evidence) for every unobserved feature at once.

        A node without feature arcs is d-separated from all evidence by the class node, so
        P(C, F | e) = P(C | e) P(F | C): one inference serves all such nodes (closed form);
        nodes with feature arcs take the exact einsum path.
        """
        open_nodes = [f for f in self.features if f not in evidence]
        if not open_nodes:
            return {}
        linked = self._linked()
        naive = [f for f in open_nodes if f not in linked]
        out = {}
        if naive:
            posterior = self.joint(evidence)
            tables = np.stack([self.cpt[f] for f in naive])  # (k, class, state)
            info = _information(posterior[None, :, None] * tables)
            out.update(zip(naive, info.tolist()))
        for f in open_nodes:
            if f in linked:
                out[f] = self.mutual_information(f, evidence)
        return out

    def to_pgmpy(self):
        """The network as a pgmpy ``DiscreteBayesianNetwork`` (nodes 'class', 'f0', 'f1', ...)."""
        from pgmpy.factors.discrete import TabularCPD
        from pgmpy.models import DiscreteBayesianNetwork

        name = {CLASS: CLASS, **{k: f"f{i}" for i, k in enumerate(self.features)}}
        model = DiscreteBayesianNetwork()
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

