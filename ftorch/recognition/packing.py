"""What recognition needs, packed as binary: the bytes a learner stores per class.

Alg. 4.4 needs the class networks (4.4.1) and the parameters of every feature they hold, nothing
else (no instance list, no value cache, no images). :func:`pack` writes exactly that, little-endian:

- a header: ``uint16`` feature count, ``uint16`` network count;
- the feature table, each feature once however many networks hold it, sub-features before their
  compounds: a ``uint8`` type code (:data:`CODES`), then
  texel: its 15 ``float32``; geometric: ``uint8`` part count, per part a ``uint8`` kind
  (:data:`KINDS`) and its vector (15, 2 or 8 ``float32`` for a texel, an edgel, a texture part),
  and for every part after the first its placement phi, dtheta, d, dsigma (4 ``float32``; the
  first part's is never used, alg. 3.6); texture: ``uint8`` level k
  (sigma = 2^(k/2)) and its 8 ``float32``; conjunction, disjunction: two ``uint16`` positions of
  their sub-features in the table; within (a feature bounded to a region, ``ftorch.space.region``):
  ``uint8`` frame code (:data:`FRAMES`), its x, y and radius (3 ``float32``) and the ``uint16``
  table position of its inner feature;
- per network, in class order: P(class) as ``float32``, ``uint16`` node count, then per node its
  feature's ``uint16`` table position, its cut-point (``float32``), ``uint8`` parent count with the
  parents' ``uint16`` node positions, and P(node present | class, parents) for each of the
  2^(1 + parents) conditions (``float32``; P(absent) is its complement).

Class names are not stored (a class is its network's position); :func:`unpack` takes them back.
Recognition with the unpacked networks answers from exactly the bytes counted.
"""
from __future__ import annotations

import struct
from collections.abc import Hashable, Sequence
from typing import cast

import numpy as np

from ..errors import InputError
from ..space.features import Conjunction, Disjunction, Feature, Geometric, Part, Texel, Texture, Within
from ..space.primitives import PartKind
from ..space.region import Frame, Region
from ..space.texture import BINS, level_sigma
from .bayes import ClassNetwork

CODES: dict[type[Feature], int] = {Texel: 0, Geometric: 1, Conjunction: 2, Disjunction: 3, Texture: 4, Within: 5}
KINDS = (PartKind.TEXEL, PartKind.EDGEL, PartKind.TEXTURE)  # a part kind's code is its position
FRAMES = (Frame.IMAGE, Frame.OBJECT)  # a region frame's code is its position
LIMIT = 1 << 16  # features per table and nodes per network that a uint16 position can name


class _Writer:
    def __init__(self) -> None:
        self.chunks: list[bytes] = []

    def put(self, form: str, *values) -> None:
        self.chunks.append(struct.pack("<" + form, *values))

    def floats(self, values) -> None:
        self.chunks.append(np.asarray(values, dtype="<f4").tobytes())


class _Reader:
    def __init__(self, data: bytes):
        self.data, self.at = memoryview(data), 0

    def get(self, form: str) -> tuple:
        size = struct.calcsize("<" + form)
        if self.at + size > len(self.data):
            raise ValueError(f"packed networks end at byte {len(self.data)}, a field needs {self.at + size}")
        values = struct.unpack_from("<" + form, self.data, self.at)
        self.at += size
        return values

    def floats(self, n: int) -> np.ndarray:
        return np.array(self.get(f"{n}f"), dtype=np.float32)


def _table(networks: Sequence[ClassNetwork]) -> dict[Feature, int]:
    """Every feature the networks hold and every sub-feature of theirs, sub-features first."""
    positions: dict[Feature, int] = {}

    def add(feature: Hashable) -> None:
        if feature in positions:
            return
        for sub in feature.subfeatures() if isinstance(feature, Feature) else ():
            add(sub)
        if not isinstance(feature, Feature) or type(feature) not in CODES:
            raise InputError(f"no packed form for {type(feature).__name__} features: add it to ftorch.recognition.packing")
        positions[feature] = len(positions)
    for net in networks:
        for feature in net.features:
            add(feature)
    if len(positions) > LIMIT:
        raise InputError(f"{len(positions)} features: a packed table holds at most {LIMIT}")
    return positions


def _put_feature(out: _Writer, feature: Feature, positions: dict[Feature, int]) -> None:
    out.put("B", CODES[type(feature)])
    if isinstance(feature, Texel):
        out.floats(feature.vector)
    elif isinstance(feature, Geometric):
        out.put("B", len(feature.parts))
        for k, part in enumerate(feature.parts):
            out.put("B", KINDS.index(part.kind))
            out.floats(part.vector)
            if k:
                out.floats((part.phi, part.dtheta, part.d, part.dsigma))
    elif isinstance(feature, Texture):
        out.put("B", feature.level)
        out.floats(feature.histogram)
    elif isinstance(feature, Within):
        region = feature.region
        disc = np.asarray((region.x, region.y, region.radius), dtype="<f4")
        if not (np.isfinite(disc).all() and disc[2] > 0):
            raise InputError(f"{region.describe()}: its x, y or radius has no float32 form (overflow, or radius 0)")
        out.put("B", FRAMES.index(region.frame))
        out.floats(disc)
        out.put("H", positions[feature.feature])
    else:
        out.put("HH", *(positions[sub] for sub in feature.subfeatures()))


def pack(networks: dict[Hashable, ClassNetwork]) -> bytes:
    """The networks and their features' parameters as binary (the module's layout)."""
    nets = list(networks.values())
    positions = _table(nets)
    out = _Writer()
    out.put("HH", len(positions), len(nets))
    for feature in positions:
        _put_feature(out, feature, positions)
    for net in nets:
        if len(net.features) > LIMIT:
            raise InputError(f"network of class {net.label!r}: {len(net.features)} nodes, at most {LIMIT} pack")
        out.floats([net.prior[1]])
        out.put("H", len(net.features))
        nodes = {f: k for k, f in enumerate(net.features)}
        for feature in cast(tuple[Feature, ...], net.features):  # a class network's nodes; _table made sure they are features
            parents = cast(tuple[Feature, ...], net.parents[feature])
            out.put("H", positions[feature])
            out.floats([net.threshold[feature]])
            out.put(f"B{len(parents)}H", len(parents), *(nodes[p] for p in parents))
            out.floats(np.asarray(net.cpt[feature])[..., 1].reshape(-1))
    return b"".join(out.chunks)


def _get_feature(source: _Reader, table: list[Feature]) -> Feature:
    (code,) = source.get("B")
    kind = {v: k for k, v in CODES.items()}.get(code)
    if kind is Texel:
        return Texel(source.floats(15).tolist())
    if kind is Geometric:
        parts = []
        for k in range(source.get("B")[0]):
            (code,) = source.get("B")
            if code >= len(KINDS):
                raise ValueError(f"part kind code {code} is not one of {list(range(len(KINDS)))}")
            part = KINDS[code]
            vector = source.floats(part.size).tolist()
            parts.append(Part(part, vector, *(source.floats(4).tolist() if k else ())))
        return Geometric(tuple(parts))
    if kind is Texture:
        (level,) = source.get("B")
        return Texture(level_sigma(level), source.floats(BINS).tolist())
    if kind is None:
        raise ValueError(f"feature type code {code} is not one of {sorted(CODES.values())}")
    if kind is Within:
        (frame,) = source.get("B")
        if frame >= len(FRAMES):
            raise ValueError(f"region frame code {frame} is not one of {list(range(len(FRAMES)))}")
        x, y, radius = source.floats(3).tolist()
        (inner,) = source.get("H")
        if inner >= len(table):
            raise ValueError(f"a within refers to feature {inner} before it is defined")
        return Within(table[inner], Region(FRAMES[frame], x, y, radius))  # a bad radius: InputError, a ValueError
    assert issubclass(kind, (Conjunction, Disjunction)), kind  # the codes left
    a, b = source.get("HH")
    if max(a, b) >= len(table):
        raise ValueError(f"a {kind.TYPE} refers to feature {max(a, b)} before it is defined")
    return kind(table[a], table[b])


def unpack(data: bytes, labels: Sequence[Hashable]) -> dict[Hashable, ClassNetwork]:
    """The networks :func:`pack` wrote, named ``labels`` in their order; ValueError where ``data``
    is not such a packing."""
    source = _Reader(data)
    n_features, n_nets = source.get("HH")
    if n_nets != len(labels):
        raise ValueError(f"{n_nets} packed networks but {len(labels)} class names")
    table: list[Feature] = []
    for _ in range(n_features):
        table.append(_get_feature(source, table))
    networks = {}
    for label in labels:
        prior = float(source.floats(1)[0])
        features, parent_nodes, thresholds, cpts = [], [], [], []
        for _ in range(source.get("H")[0]):
            (position,) = source.get("H")
            if position >= len(table):
                raise ValueError(f"a node of class {label!r} refers to feature {position} of {len(table)}")
            features.append(table[position])
            thresholds.append(float(source.floats(1)[0]))
            (count,) = source.get("B")
            parent_nodes.append(source.get(f"{count}H"))
            present = source.floats(2 ** (1 + count)).astype(float).reshape((2,) * (1 + count))
            cpts.append(np.stack([1 - present, present], axis=-1))
        if any(k >= len(features) for ps in parent_nodes for k in ps):
            raise ValueError(f"a node of class {label!r} has a parent beyond its {len(features)} nodes")
        parents = [[features[k] for k in ps] for ps in parent_nodes]
        networks[label] = ClassNetwork.of(label, features, parents, thresholds, [1 - prior, prior], cpts)
    if source.at != len(data):
        raise ValueError(f"{len(data) - source.at} bytes left after the packed networks")
    return networks
