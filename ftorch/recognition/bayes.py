"""One Bayesian network per class (4.4.1), validated and inferred exactly by ftorch itself, checked against and
exported through pgmpy.

Every node is binary (0 = absent, 1 = present): the class node "class" and one node per feature.
Arcs run from the class node to every feature and between features as the feature structure
asks (see :func:`compound_arcs`): geometric and conjunctive compounds -> their components that
are in the network, and components -> disjunctive compounds.

Probabilities are counted from the instance list (:meth:`ClassNetwork.estimate`): maximum
likelihood, so a configuration seen only with one outcome gets probability 0 or 1 (the text
relies on this: a feature can drive its class entropy to zero, 4.4.4); a parent configuration
never seen gets 1/2 (no information). The prior of the class node is counted the same way.

Inference is exact and factorised. Given the class node, the feature nodes fall into
independent *groups*, the connected components of the feature arcs:
P(C, e) = P(C) prod_groups P(e_group | C). A node without feature arcs is a group of one
(closed form: its CPT column). A linked group of m <= ``TABLE_LIMIT`` nodes is compiled, once
per estimate, into the table P(configuration | C) over its 2^m configurations; then the
likelihood of any evidence is a masked sum, and P(F = 1, e_group | C) for every node of the
group at once is one matrix product with the configuration bits. Larger groups are contracted
with ``einsum`` (variable elimination). Tests prove all paths equal to pgmpy's VariableElimination.
"""
from __future__ import annotations

import functools
import math
import re
from collections.abc import Hashable
from types import MappingProxyType

import numpy as np

from ..space.features import Feature

CLASS = "class"
_LETTERS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"


def _identifier(text: str) -> str:
    """``text`` as an identifier of the exported formats (BIF): runs of other characters become one '_'."""
    return re.sub(r"\W+", "_", text).strip("_")


def information(joint: np.ndarray) -> np.ndarray:
    """Mutual information in bits of normalised joint tables (k, 2, 2); 0 where a table is NaN."""
    joint = np.where(joint > 0, joint, 0.0)  # NaN (impossible evidence) and zeros contribute nothing
    outer = joint.sum(2, keepdims=True) * joint.sum(1, keepdims=True)
    ratio = np.divide(joint, outer, out=np.ones_like(joint), where=joint > 0)
    return (joint * np.log2(ratio)).sum((1, 2))


def _check_distribution(name: str, table: np.ndarray, shape: tuple) -> None:
    """ValueError unless ``table`` has ``shape`` and holds distributions over its last axis."""
    if table.shape != shape:
        raise ValueError(f"{name} has shape {table.shape}, expected {shape}")
    if not (np.all(np.isfinite(table)) and np.all((table >= 0) & (table <= 1))):
        raise ValueError(f"{name} has entries that are not probabilities (NaN, infinite or outside [0, 1])")
    if not np.allclose(table.sum(-1), 1.0, rtol=0, atol=1e-6):
        raise ValueError(f"{name} does not sum to 1 over the node's states")


def _normalised(tables: np.ndarray) -> np.ndarray:
    """Each table (k, ...) divided by its sum; NaN where the sum is zero (impossible evidence)."""
    axes = tuple(range(1, tables.ndim))
    total = tables.sum(axis=axes, keepdims=True)
    return np.where(total > 0, tables / np.where(total > 0, total, 1), math.nan)


def compound_arcs(feature: Feature, present) -> tuple[list, list]:
    """(parents, children) of ``feature`` among the ``present`` features, by the rules of 4.4.1:
    each compound type says which way the arcs to its components run (``ARCS_TO_COMPONENTS``)."""
    parents, children = [], []
    own = set(feature.components())
    for other in present:
        if other == feature:
            continue
        if other in own:  # other is a component of feature
            (children if feature.ARCS_TO_COMPONENTS else parents).append(other)
        elif feature in set(other.components()):  # feature is a component of other
            (parents if other.ARCS_TO_COMPONENTS else children).append(other)
    return parents, children


class _Group:
    """A connected component of feature arcs: node positions, and its table or None (einsum);
    ``contracted``: einsum results by the group's own evidence and query (:meth:`ClassNetwork._contract`);
    ``given``: a compiled group's likelihood and open-node tables by its own evidence (:meth:`evidence`)."""

    def __init__(self, network: "ClassNetwork", keys: list):
        self.keys = keys
        self.contracted: dict[tuple, np.ndarray] = {}
        self.given: dict[bytes, tuple] = {}
        self.positions = np.array([network.features.index(k) for k in keys], dtype=np.int64)
        m = len(keys)
        self.table = None
        self.weights = 1 << np.arange(m)
        if m <= network.table_limit:
            self.codes = np.arange(2**m)
            self.bits = (self.codes[:, None] >> np.arange(m)[None, :]) & 1  # (2^m, m)
            local = {k: i for i, k in enumerate(keys)}
            table = np.ones((2, 2**m))
            for key in keys:
                index = tuple(self.bits[:, local[p]] for p in network.parents[key]) + (self.bits[:, local[key]],)
                table = table * network.cpt[key][(slice(None), *index)]
            self.table = table

    def evidence(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A compiled group under the evidence ``state`` holds for its own nodes: P(e_group | C) (2,),
        its open nodes (k,) (positions in the group) and P(F_j = f, e_group | C) for each open node
        j (k, 2, 2), indexed [j, C, f]. They depend on nothing else, so they are remembered by that
        evidence (``given``), as the network remembers whole states; the arrays must not be modified."""
        own = state[self.positions]
        return _remembered(self.given, own.tobytes(), lambda: self._evidence(own))

    def _evidence(self, own: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        observed = own >= 0
        mask = (self.codes & self.weights[observed].sum()) == (self.weights * (own > 0)).sum()  # agreeing configurations
        likelihood = self.table @ mask
        open_nodes = np.flatnonzero(own < 0)
        present = (self.table * mask) @ self.bits[:, open_nodes]  # P(F_j = 1, e_g | C) (2, k)
        # laid out (C, F_j, F) and viewed as (F_j, C, F): information sums each table in the
        # order its layout gives, so this layout is part of the result's last bit
        both = np.empty((2, len(open_nodes), 2))
        both[:, :, 0], both[:, :, 1] = likelihood[:, None] - present, present
        return likelihood, open_nodes, both.transpose(1, 0, 2)


MEMO_LIMIT = 4096  # evidence states remembered per compiled network, and per large group


def _remembered(memo: dict, key, compute):
    """``memo[key]``, computed by ``compute()`` where missing; a full memo is emptied first."""
    if key not in memo:
        if len(memo) >= MEMO_LIMIT:
            memo.clear()
        memo[key] = compute()
    return memo[key]


class _Compiled:
    """Arc-free nodes stacked for the closed form; linked groups compiled (see module doc); the
    results of :meth:`ClassNetwork.evaluate` by evidence state (``memo``)."""

    def __init__(self, network: "ClassNetwork"):
        self.memo: dict[bytes, tuple[float, np.ndarray]] = {}
        linked = {p for ps in network.parents.values() for p in ps} | {f for f, ps in network.parents.items() if ps}
        self.singles = np.array([i for i, k in enumerate(network.features) if k not in linked], dtype=np.int64)
        self.single_cpt = (np.stack([network.cpt[network.features[i]] for i in self.singles])
                           if len(self.singles) else np.zeros((0, 2, 2)))
        neighbours = {k: set() for k in linked}
        for key, parents in network.parents.items():
            for p in parents:
                neighbours[key].add(p)
                neighbours[p].add(key)
        self.groups, seen = [], set()
        for key in network.features:
            if key in linked and key not in seen:
                component, todo = [], [key]
                seen.add(key)
                while todo:
                    node = todo.pop()
                    component.append(node)
                    for other in neighbours[node] - seen:
                        seen.add(other)
                        todo.append(other)
                order = {k: i for i, k in enumerate(network.features)}
                self.groups.append(_Group(network, sorted(component, key=order.__getitem__)))


@functools.lru_cache(maxsize=4096)
def _contraction_path(expression: str) -> list:
    """numpy's greedy einsum path for ``expression`` over binary axes, found once per expression
    (finding it costs more than contracting)."""
    inputs = expression.split("->")[0].split(",")
    return np.einsum_path(expression, *(np.ones((2,) * len(sub)) for sub in inputs), optimize="greedy")[0]


class ClassNetwork:
    """The Bayesian network of one class: prior, feature nodes, arcs, CPTs and thresholds.

    Evidence is a dict feature -> state (0 or 1), or for the fast path a state array over
    ``features`` with -1 for unobserved nodes. ``features`` (a tuple), ``parents`` (tuples),
    ``threshold`` and ``cpt`` are read-only views: the network changes only through its methods
    (:meth:`add_feature`, :meth:`remove_feature`, :meth:`add_arc`, :meth:`set_threshold`,
    :meth:`set_cpt`, :meth:`estimate`, the ``prior`` setter), which keep the compiled inference
    tables valid. CPTs are replaced, never edited in place (they are read-only arrays).
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
        self.parents, self.threshold, self.cpt = (MappingProxyType(d) for d in (self._parents, self._threshold, self._cpt))
        self._compiled: _Compiled | None = None
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
        self._cpt[key] = table
        self._compiled = None

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
        self._threshold[key] = float(value)

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
        self._prior = np.asarray(value, dtype=float)
        self._compiled = None

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
        self._compiled = None
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

    # -- exact inference -----------------------------------------------------------------------
    def compiled(self) -> _Compiled:
        if self._compiled is None:
            self._compiled = _Compiled(self)
        return self._compiled

    def state(self, evidence: dict[Hashable, int]) -> np.ndarray:
        """Evidence dict -> state array over ``features`` (-1 = unobserved)."""
        out = np.full(len(self.features), -1, dtype=np.int64)
        for key, value in evidence.items():
            out[self.features.index(key)] = int(value)
        return out

    def _factors(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
        """(P(C) prod_singles P(e_i | C)) (2,), each group's likelihood P(e_group | C) (G, 2) and
        each compiled group's :meth:`_Group.evidence` (None for a group contracted by einsum)."""
        c = self.compiled()
        weight = self.prior
        observed = state[c.singles] >= 0
        if observed.any():
            weight = weight * c.single_cpt[observed, :, state[c.singles[observed]]].prod(0)
        likes = np.ones((len(c.groups), 2))
        given = [group.evidence(state) if group.table is not None else None for group in c.groups]
        for g, (group, known) in enumerate(zip(c.groups, given)):
            likes[g] = known[0] if known is not None else self._contract(group, state)
        return weight, likes, given

    def _contract(self, group: _Group, state: np.ndarray, query=None) -> np.ndarray:
        """P(e_group | C) (2,), or P(e_group, query | C) (2, 2), of a large group by einsum.

        It depends only on the evidence of the group's own nodes, so it is remembered by that
        (``group.contracted``, as the network remembers whole states): a recognition observes one
        node at a time, mostly outside any one group, and the evidence states of the whole network
        it meets differ where a large group's do not. The returned array must not be modified."""
        return _remembered(group.contracted, (state[group.positions].tobytes(), query),
                           lambda: self._contract_afresh(group, state, query))

    def _contract_afresh(self, group: _Group, state: np.ndarray, query=None) -> np.ndarray:
        """:meth:`_contract` computed: variable elimination over the ancestors of evidence and query."""
        evidence = {k: int(state[i]) for k, i in zip(group.keys, group.positions) if state[i] >= 0}
        todo, relevant = [*evidence, *([query] if query is not None else [])], set()
        while todo:  # ancestors of evidence and query; other nodes are barren and sum to one
            node = todo.pop()
            if node not in relevant:
                relevant.add(node)
                todo.extend(self.parents[node])
        nodes = [k for k in group.keys if k in relevant]
        if len(nodes) + 1 > len(_LETTERS):
            raise ValueError(f"network of class {self.label!r} is too large for exact inference ({len(nodes)} nodes)")
        letter = {CLASS: _LETTERS[0], **{k: _LETTERS[i + 1] for i, k in enumerate(nodes)}}
        operands, subscripts = [np.ones(2)], [letter[CLASS]]
        for key in nodes:
            axes = [CLASS, *self.parents[key], key]
            index = tuple(evidence[a] if a in evidence else slice(None) for a in axes)
            operands.append(self.cpt[key][index])
            subscripts.append("".join(letter[a] for a in axes if a not in evidence))
        output = letter[CLASS] + (letter[query] if query is not None else "")
        expression = ",".join(subscripts) + "->" + output
        return np.einsum(expression, *operands, optimize=_contraction_path(expression) if len(operands) > 3 else False)

    def evaluate(self, state: np.ndarray) -> tuple[float, np.ndarray]:
        """(P(class present | e), I(C, F | e) in bits for every feature node (F,), 0 where observed), eq. 4.2.

        Results are remembered per evidence state until the prior or a CPT changes (recognition
        meets the same states again and again); the returned array must not be modified.
        """
        return _remembered(self.compiled().memo, state.tobytes(), lambda: self.infer(state))

    def infer(self, state: np.ndarray) -> tuple[float, np.ndarray]:
        """:meth:`evaluate` computed afresh: the exact factorised inference of the module docstring."""
        c = self.compiled()
        weight, likes, given = self._factors(state)
        joint = weight * likes.prod(0)
        total = joint.sum()
        out = np.zeros(len(self.features))
        if not total > 0:
            return math.nan, out
        posterior = joint / total
        open_rows = state[c.singles] < 0
        if open_rows.any():
            out[c.singles[open_rows]] = information(posterior[None, :, None] * c.single_cpt[open_rows])
        # the products of the groups before g and after g, each multiplied in the order of a
        # cumulative product (a few groups: rows multiplied one by one cost less than np.cumprod)
        before, after, product = [], [None] * len(c.groups), np.ones(2)
        for like in likes:
            before.append(product)
            product = product * like
        product = np.ones(2)
        for g in reversed(range(len(c.groups))):
            after[g] = product
            product = product * likes[g]
        for g, (group, known) in enumerate(zip(c.groups, given)):
            if known is not None:
                _, open_nodes, both = known
            else:
                open_nodes = np.flatnonzero(state[group.positions] < 0)
            if not len(open_nodes):
                continue
            rest = weight * before[g] * after[g] / total
            if known is None:
                both = np.stack([self._contract(group, state, group.keys[i]) for i in open_nodes])
            out[group.positions[open_nodes]] = information(rest[None, :, None] * both)
        return float(posterior[1]), out

    def joint(self, evidence: dict[Hashable, int], query: Hashable | None = None) -> np.ndarray:
        """P(class | evidence) (2,), or P(class, query | evidence) (2, 2) for an unobserved feature.

        NaN where the evidence has probability zero under the network.
        """
        if query is not None and query in evidence:
            raise ValueError(f"query {query!r} is already observed")
        state = self.state(evidence)
        weight, likes, _ = self._factors(state)
        if query is None:
            return _normalised((weight * likes.prod(0))[None])[0]
        c = self.compiled()
        at = self.features.index(query)
        if at in c.singles:
            table = (weight * likes.prod(0))[:, None] * self.cpt[query]
            return _normalised(table[None])[0]
        g = next(g for g, group in enumerate(c.groups) if at in group.positions)
        rest = weight * np.prod(np.delete(likes, g, 0), 0)
        return _normalised((rest[:, None] * self._contract(c.groups[g], state, query))[None])[0]

    def posterior(self, evidence: dict[Hashable, int]) -> float:
        """P(class present | evidence)."""
        return self.evaluate(self.state(evidence))[0]

    def mutual_information(self, query: Hashable, evidence: dict[Hashable, int]) -> float:
        """I(C, F_query | evidence) in bits, eq. 4.2; 0 for an observed feature (alg. 4.4)."""
        if query in evidence:
            return 0.0
        return float(information(self.joint(evidence, query)[None])[0])

    def informations(self, evidence: dict[Hashable, int]) -> dict[Hashable, float]:
        """I(C, F | evidence) for every unobserved feature (dict form of :meth:`evaluate`)."""
        info = self.evaluate(self.state(evidence))[1]
        return {k: float(info[i]) for i, k in enumerate(self.features) if k not in evidence}

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

