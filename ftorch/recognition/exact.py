"""Exact inference in a class network (4.4.1, eq. 4.2): the engine that consumes a
:class:`~ftorch.recognition.bayes.ClassNetwork`'s :class:`~ftorch.recognition.bayes.Snapshot`, and
:func:`engine`, which keeps one engine per network outside the model, keyed by the network and its
snapshot (a change to the network makes a new snapshot, hence a new engine).

Inference is exact and factorised. Given the class node, the feature nodes fall into
independent *groups*, the connected components of the feature arcs:
P(C, e) = P(C) prod_groups P(e_group | C). A node without feature arcs is a group of one
(closed form: its CPT column). A linked group of m <= ``TABLE_LIMIT`` nodes is compiled, once
per engine (that is, per estimate), into the table P(configuration | C) over its 2^m
configurations; then the likelihood of any evidence is a masked sum, and P(F = 1, e_group | C)
for every node of the group at once is one matrix product with the configuration bits. Larger
groups are contracted with ``einsum`` (variable elimination). Tests prove all paths equal to
pgmpy's VariableElimination.
"""
from __future__ import annotations

import math
from collections.abc import Hashable
from weakref import WeakKeyDictionary

import numpy as np

from .bayes import CLASS, ClassNetwork, Snapshot

_LETTERS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"


def information(joint: np.ndarray) -> np.ndarray:
    """Mutual information in bits of normalised joint tables (k, 2, 2); 0 where a table is NaN."""
    joint = np.where(joint > 0, joint, 0.0)  # NaN (impossible evidence) and zeros contribute nothing
    outer = joint.sum(2, keepdims=True) * joint.sum(1, keepdims=True)
    ratio = np.divide(joint, outer, out=np.ones_like(joint), where=joint > 0)
    return (joint * np.log2(ratio)).sum((1, 2))


def normalised(tables: np.ndarray) -> np.ndarray:
    """Each table (k, ...) divided by its sum; NaN where the sum is zero (impossible evidence)."""
    axes = tuple(range(1, tables.ndim))
    total = tables.sum(axis=axes, keepdims=True)
    return np.where(total > 0, tables / np.where(total > 0, total, 1), math.nan)


class _Group:
    """A connected component of feature arcs: node positions, and its table or None (einsum);
    ``contracted``: einsum results by the group's own evidence and query (:meth:`ExactInference._contract`);
    ``given``: a compiled group's likelihood and open-node tables by its own evidence (:meth:`evidence`)."""

    def __init__(self, network: Snapshot, keys: list):
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
                index: tuple[slice | np.ndarray, ...] = (slice(None), *(self.bits[:, local[p]] for p in network.parents[key]),
                                                         self.bits[:, local[key]])
                table = table * network.cpt[key][index]
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


class ExactInference:
    """The exact inference engine of one class network's :class:`~ftorch.recognition.bayes.Snapshot`:
    arc-free nodes stacked for the closed form, linked groups compiled or contracted (module doc),
    and the results of :meth:`evaluate` by evidence state (``memo``). :func:`engine` makes a new one
    after any change; ``paths``: the einsum paths found so far, which depend on the structure only,
    handed from one engine of the network to the next."""

    def __init__(self, network: Snapshot, paths: dict[str, list] | None = None):
        self.network = network
        self.paths = {} if paths is None else paths
        self.memo: dict[bytes, tuple[float, np.ndarray]] = {}
        # evidence can decide the class (P(C = c, e) = 0 exactly) only through a zero in the prior or a CPT
        self.can_decide = not (network.prior > 0).all() or any(not (t > 0).all() for t in network.cpt.values())
        linked = {p for ps in network.parents.values() for p in ps} | {f for f, ps in network.parents.items() if ps}
        self.singles = np.array([i for i, k in enumerate(network.features) if k not in linked], dtype=np.int64)
        self.single_cpt = (np.stack([network.cpt[network.features[i]] for i in self.singles])
                           if len(self.singles) else np.zeros((0, 2, 2)))
        neighbours: dict[Hashable, set[Hashable]] = {k: set() for k in linked}
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

    def _path(self, expression: str) -> list:
        """numpy's greedy einsum path for ``expression`` over binary axes, found once per expression
        (finding it costs more than contracting; ``paths``, shared by the network's engines)."""
        if expression not in self.paths:
            inputs = expression.split("->")[0].split(",")
            self.paths[expression] = np.einsum_path(expression, *(np.ones((2,) * len(sub)) for sub in inputs),
                                                    optimize="greedy")[0]
        return self.paths[expression]

    def state(self, evidence: dict[Hashable, int]) -> np.ndarray:
        """Evidence dict -> state array over the network's features (-1 = unobserved)."""
        out = np.full(len(self.network.features), -1, dtype=np.int64)
        for key, value in evidence.items():
            out[self.network.features.index(key)] = int(value)
        return out

    def _factors(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
        """(P(C) prod_singles P(e_i | C)) (2,), each group's likelihood P(e_group | C) (G, 2) and
        each compiled group's :meth:`_Group.evidence` (None for a group contracted by einsum)."""
        weight = self.network.prior
        observed = state[self.singles] >= 0
        if observed.any():
            weight = weight * self.single_cpt[observed, :, state[self.singles[observed]]].prod(0)
        likes = np.ones((len(self.groups), 2))
        given = [group.evidence(state) if group.table is not None else None for group in self.groups]
        for g, (group, known) in enumerate(zip(self.groups, given)):
            likes[g] = known[0] if known is not None else self._contract(group, state)
        return weight, likes, given

    def _contract(self, group: _Group, state: np.ndarray, query=None) -> np.ndarray:
        """P(e_group | C) (2,), or P(e_group, query | C) (2, 2), of a large group by einsum.

        It depends only on the evidence of the group's own nodes, so it is remembered by that
        (``group.contracted``, as :meth:`evaluate` remembers whole states): a recognition observes one
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
                todo.extend(self.network.parents[node])
        nodes = [k for k in group.keys if k in relevant]
        if len(nodes) + 1 > len(_LETTERS):
            raise ValueError(f"network of class {self.network.label!r} is too large for exact inference ({len(nodes)} nodes)")
        letter = {CLASS: _LETTERS[0], **{k: _LETTERS[i + 1] for i, k in enumerate(nodes)}}
        operands, subscripts = [np.ones(2)], [letter[CLASS]]
        for key in nodes:
            axes = [CLASS, *self.network.parents[key], key]
            index = tuple(evidence[a] if a in evidence else slice(None) for a in axes)
            operands.append(self.network.cpt[key][index])
            subscripts.append("".join(letter[a] for a in axes if a not in evidence))
        output = letter[CLASS] + (letter[query] if query is not None else "")
        expression = ",".join(subscripts) + "->" + output
        return np.einsum(expression, *operands, optimize=self._path(expression) if len(operands) > 3 else False)

    def evaluate(self, state: np.ndarray) -> tuple[float, np.ndarray]:
        """(P(class present | e), I(C, F | e) in bits for every feature node (F,), 0 where observed), eq. 4.2.

        Results are remembered per evidence state until the prior or a CPT changes (recognition
        meets the same states again and again); the returned array must not be modified.
        """
        return _remembered(self.memo, state.tobytes(), lambda: self.infer(state))

    def infer(self, state: np.ndarray) -> tuple[float, np.ndarray]:
        """:meth:`evaluate` computed afresh: the exact factorised inference of the module docstring."""
        weight, likes, given = self._factors(state)
        joint = weight * likes.prod(0)
        total = joint.sum()
        out = np.zeros(len(self.network.features))
        if not total > 0:
            return math.nan, out
        posterior = joint / total
        open_rows = state[self.singles] < 0
        if open_rows.any():
            out[self.singles[open_rows]] = information(posterior[None, :, None] * self.single_cpt[open_rows])
        # the products of the groups before g and after g, each multiplied in the order of a
        # cumulative product (a few groups: rows multiplied one by one cost less than np.cumprod)
        product = np.ones(2)
        before, after = [], [product] * len(self.groups)  # after: every entry set below
        for like in likes:
            before.append(product)
            product = product * like
        product = np.ones(2)
        for g in reversed(range(len(self.groups))):
            after[g] = product
            product = product * likes[g]
        for g, (group, known) in enumerate(zip(self.groups, given)):
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

    def log_odds(self, state: np.ndarray) -> float:
        """The log posterior odds log P(C=1, e) - log P(C=0, e) (natural logs) under the evidence ``state``.

        Summed, per class value, as log P(C) + sum over arc-free nodes of log P(e_i | C) + sum over
        groups of log P(e_group | C), so it does not saturate where the posterior (a quotient of
        products) is 1.0 or 0.0 in float: it tells such networks apart (the top label's ties, alg. 4.4
        continued). A group's own likelihood is its sum over configurations, as :meth:`evaluate`
        computes it. +-inf where one class value makes the evidence impossible, NaN where both do.
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            logs = np.log(self.network.prior)
            observed = state[self.singles] >= 0
            if observed.any():
                logs = logs + np.log(self.single_cpt[observed, :, state[self.singles[observed]]]).sum(0)
            for group in self.groups:
                like = group.evidence(state)[0] if group.table is not None else self._contract(group, state)
                logs = logs + np.log(like)
            return float(logs[1] - logs[0])

    def joint(self, evidence: dict[Hashable, int], query: Hashable | None = None) -> np.ndarray:
        """P(class | evidence) (2,), or P(class, query | evidence) (2, 2) for an unobserved feature.

        NaN where the evidence has probability zero under the network.
        """
        if query is not None and query in evidence:
            raise ValueError(f"query {query!r} is already observed")
        state = self.state(evidence)
        weight, likes, _ = self._factors(state)
        if query is None:
            return normalised((weight * likes.prod(0))[None])[0]
        at = self.network.features.index(query)
        if at in self.singles:
            table = (weight * likes.prod(0))[:, None] * self.network.cpt[query]
            return normalised(table[None])[0]
        g = next(g for g, group in enumerate(self.groups) if at in group.positions)
        rest = weight * np.prod(np.delete(likes, g, 0), 0)
        return normalised((rest[:, None] * self._contract(self.groups[g], state, query))[None])[0]

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
        return {k: float(info[i]) for i, k in enumerate(self.network.features) if k not in evidence}


_ENGINES: WeakKeyDictionary[ClassNetwork, ExactInference] = WeakKeyDictionary()  # the latest engine of each network


def engine(network: ClassNetwork) -> ExactInference:
    """The exact inference engine of ``network`` as it stands: the one made of its current snapshot,
    made now where the network has changed since (the engine and its memories then start afresh; the
    einsum paths found for the network carry over)."""
    snapshot = network.snapshot()
    found = _ENGINES.get(network)
    if found is None or found.network is not snapshot:
        found = _ENGINES[network] = ExactInference(snapshot, None if found is None else found.paths)
    return found
