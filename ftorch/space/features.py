"""Features of the unbounded feature space (3.4-3.5) as plain, JSON-exact data objects.

- :class:`Texel`: a 15-d texel response vector (3.4.2), canonical (steered to its own orientation).
- :class:`Geometric`: n >= 2 primitive :class:`Part` s with attitudes phi_i, angle differences
  dtheta_i, distances d_i (in units of sigma_{i-1}) and scale ratios dsigma_i (alg. 3.6); a part
  may be a statistical texture placed relative to an oriented part (3.5 with 7.2.1).
- :class:`Texture`: a statistical texture primitive (7.2.1), the intensity histogram around a
  point at a scale (``ftorch.space.texture``); it has no parts and no orientation.
- :class:`Conjunction` (product) and :class:`Disjunction` (max) of any two features (3.5.2).
- :class:`Within`: any feature whose maximum (eq. 3.14) runs over the reference points inside a
  :class:`~ftorch.space.region.Region` only (beyond the thesis: where a feature looks).

Each type carries its own behaviour: its JSON form (``TYPE``, ``to_dict``, ``_from_dict``), its
parts (a :class:`LocalFeature`, measured at reference points by ``ftorch.space.evaluate``) or the
sub-features whose values it combines (``subfeatures``, ``combine``), the components its class
network links to it and the direction of those arcs (``components``, ``ARCS_TO_COMPONENTS``;
4.4.1), and its name in legends (``describe``). So a new type is one subclass: defining it
registers its ``TYPE`` for :meth:`Feature.from_dict`.

A part's vector is its response at its own location and scale, steered to its orientation:
15 numbers for a texel, 2 for an edgel (the first-order pair, eq. 3.5); a texture part's is the
square-rooted histogram there (``BINS`` numbers >= 0, no orientation). ``to_json`` /
``from_json`` round-trip every float exactly (Python writes the shortest exact repr).
"""
from __future__ import annotations

import json
import math
from dataclasses import Field, dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import torch
from torch import Tensor

from ..checkpoint import Memo, decode_text, encode_text
from ..errors import InputError
from .primitives import PartKind
from .region import Region
from .texture import BINS, sigma_level


def _vector(values, kind: PartKind) -> tuple[float, ...]:
    vec = tuple(float(v) for v in values)
    if len(vec) != kind.size:
        raise InputError(f"{kind} vector must have {kind.size} numbers, got {len(vec)}")
    if not all(math.isfinite(v) for v in vec):
        raise InputError(f"{kind} vector has NaN or infinite entries")
    if not any(vec):
        raise InputError(f"{kind} vector is all zeros: it matches nothing")
    if kind is PartKind.TEXTURE and min(vec) < 0:
        raise InputError(f"{kind} vector is a square-rooted histogram: it has a negative entry")
    return vec


class _CachedHash:
    """Features are dictionary keys everywhere (networks, instance list): hash each one once."""

    __dataclass_fields__: ClassVar[dict[str, Field[Any]]]  # what hashes is a dataclass

    def __hash__(self) -> int:
        cached = self.__dict__.get("_hash")
        if cached is None:
            cached = hash((type(self).__name__, *(getattr(self, f) for f in self.__dataclass_fields__)))
            object.__setattr__(self, "_hash", cached)
        return cached


@dataclass(frozen=True)
class Part(_CachedHash):
    """One primitive of a local feature, placed relative to the previous part (alg. 3.6 step 3).

    A texture part (3.5 with 7.2.1) has no orientation of its own: its dtheta must be 0, so the
    orientation carried along the chain stays the previous part's, and a later part is placed from
    the texture part's location and scale and that orientation."""
    __hash__ = _CachedHash.__hash__  # dataclass would replace an inherited one

    kind: PartKind
    vector: tuple[float, ...]
    phi: float = 0.0
    dtheta: float = 0.0
    d: float = 0.0
    dsigma: float = 1.0

    def __post_init__(self):
        try:
            object.__setattr__(self, "kind", PartKind(self.kind))
        except (ValueError, TypeError):
            raise InputError(f"part kind must be 'texel', 'edgel' or 'texture', got {self.kind!r}") from None
        object.__setattr__(self, "vector", _vector(self.vector, self.kind))
        for name in ("phi", "dtheta", "d", "dsigma"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise InputError(f"part {name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.d < 0 or self.dsigma <= 0:
            raise InputError(f"part needs d >= 0 and dsigma > 0, got d={self.d}, dsigma={self.dsigma}")
        if self.kind is PartKind.TEXTURE and self.dtheta != 0:
            raise InputError(f"a texture part has no orientation: its dtheta must be 0, got {self.dtheta}")

    def to_dict(self) -> dict:
        return {"kind": self.kind, "vector": list(self.vector), "phi": self.phi, "dtheta": self.dtheta,
                "d": self.d, "dsigma": self.dsigma}


class Feature(_CachedHash):
    """Base of all features: JSON round trip, structure, value rule, network arcs, legend name.

    A subclass that sets ``TYPE`` is registered for :meth:`from_dict`; a frozen dataclass subclass
    keeps the cached hash with ``__hash__ = _CachedHash.__hash__`` (dataclass would replace it).
    """

    TYPE: ClassVar[str] = ""  # the "type" of its JSON form
    ARCS_TO_COMPONENTS: ClassVar[bool] = True  # arcs run compound -> component (4.4.1); False: component -> compound
    _types: ClassVar[dict[str, type[Feature]]] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("TYPE"):
            Feature._types[cls.TYPE] = cls

    def to_dict(self) -> dict:
        raise NotImplementedError

    @classmethod
    def _from_dict(cls, data: dict) -> "Feature":
        """The feature of this type that ``data`` (its ``to_dict``) describes."""
        raise NotImplementedError

    def subfeatures(self) -> tuple["Feature", ...]:
        """The features whose values this one combines (none for a local feature)."""
        return ()

    def combine(self, *values: tuple[Tensor, ...]) -> tuple[Tensor, ...]:
        """(value, x, y, sigma, theta) from those of :meth:`subfeatures` (for compounds)."""
        raise NotImplementedError

    def components(self) -> list["Feature"]:
        """The direct and indirect sub-features a class network links to this one (4.4.1)."""
        return [c for sub in self.subfeatures() for c in (sub, *sub.components())]

    def describe(self) -> str:
        """A short name of the type and make-up, for legends."""
        raise NotImplementedError

    def to_json(self) -> str:
        """The feature as JSON text (features are immutable: written once, then kept)."""
        cached = self.__dict__.get("_json")
        if cached is None:
            cached = json.dumps(self.to_dict(), separators=(",", ":"))
            object.__setattr__(self, "_json", cached)
        return cached

    @staticmethod
    def from_dict(data: dict) -> "Feature":
        try:
            kind = data["type"]
            cls = Feature._types.get(kind) if isinstance(kind, str) else None
            if cls is not None:
                return cls._from_dict(data)
        except (KeyError, TypeError) as err:
            raise InputError(f"not a feature description: {data!r:.200} ({err})") from None
        raise InputError(f"unknown feature type {kind!r}")

    @staticmethod
    def from_json(text: str) -> "Feature":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise InputError(f"feature JSON is not valid JSON: {err}") from None
        if not isinstance(data, dict):
            raise InputError("feature JSON must be an object")
        return Feature.from_dict(data)

    @property
    def primitives(self) -> int:
        """Number of primitives in the feature (its structural complexity, 3.6)."""
        raise NotImplementedError


class LocalFeature(Feature):
    """A feature measured at one reference point: a texel or a geometric compound."""

    if TYPE_CHECKING:  # a geometric compound stores its parts, a texel makes its one part from its vector
        @property
        def parts(self) -> tuple[Part, ...]: ...

    @property
    def primitives(self) -> int:
        return len(self.parts)

    def attitudes(self) -> list[tuple[float, float, float, float]]:
        """(phi, dtheta, d, dsigma) of each part after the first: its placement (alg. 3.6 step 3)."""
        return [(p.phi, p.dtheta, p.d, p.dsigma) for p in self.parts[1:]]


@dataclass(frozen=True)
class Texel(LocalFeature):
    __hash__ = _CachedHash.__hash__
    TYPE = "texel"
    vector: tuple[float, ...]

    def __post_init__(self):
        object.__setattr__(self, "vector", _vector(self.vector, PartKind.TEXEL))

    @property
    def parts(self) -> tuple[Part, ...]:
        return (Part(PartKind.TEXEL, self.vector),)

    def to_dict(self) -> dict:
        return {"type": self.TYPE, "vector": list(self.vector)}

    @classmethod
    def _from_dict(cls, data: dict) -> "Texel":
        return cls(data["vector"])

    def describe(self) -> str:
        return "texel"


@dataclass(frozen=True)
class Geometric(LocalFeature):
    __hash__ = _CachedHash.__hash__
    TYPE = "geometric"
    parts: tuple[Part, ...]

    def __post_init__(self):
        parts = tuple(self.parts)
        if len(parts) < 2 or not all(isinstance(p, Part) for p in parts):
            raise InputError(f"a geometric compound needs at least two Parts, got {len(parts)}")
        if parts[0].kind is PartKind.TEXTURE:
            raise InputError("a texture part cannot be a geometric compound's first part: it has no orientation to "
                             "place the next part from (3.5 with 7.2.1: placed relative to an oriented part)")
        object.__setattr__(self, "parts", parts)

    def to_dict(self) -> dict:
        return {"type": self.TYPE, "parts": [p.to_dict() for p in self.parts]}

    @classmethod
    def _from_dict(cls, data: dict) -> "Geometric":
        return cls(tuple(Part(**p) for p in data["parts"]))

    def components(self) -> list[Feature]:
        """Its shorter prefixes of two parts or more, and its first part where that is a texel."""
        found: list[Feature] = [Geometric(self.parts[:k]) for k in range(2, len(self.parts))]
        if self.parts[0].kind == PartKind.TEXEL:
            found.append(Texel(self.parts[0].vector))
        return found

    def describe(self) -> str:
        return "geometric: " + "-".join(p.kind for p in self.parts)


@dataclass(frozen=True)
class Texture(Feature):
    """The square-rooted intensity histogram (BINS numbers) of a window of scale ``sigma``, one of
    the scale space's levels from sigma = 2 (7.2.1; ``ftorch.space.texture``)."""
    __hash__ = _CachedHash.__hash__
    TYPE = "texture"
    sigma: float
    histogram: tuple[float, ...]

    def __post_init__(self):
        sigma = self.sigma if isinstance(self.sigma, float) else float(self.sigma) \
            if isinstance(self.sigma, int) and not isinstance(self.sigma, bool) else None
        if sigma is None or sigma_level(sigma) is None:
            raise InputError(f"texture sigma must be a level of the scale space, 2^(k/2) for k >= 2, got {self.sigma!r}")
        hist = tuple(float(v) for v in self.histogram)
        if len(hist) != BINS or not all(math.isfinite(v) and v >= 0 for v in hist) or not any(hist):
            raise InputError(f"texture histogram must be {BINS} finite numbers >= 0, not all zero")
        object.__setattr__(self, "sigma", sigma)
        object.__setattr__(self, "histogram", hist)

    @property
    def level(self) -> int:
        level = sigma_level(self.sigma)
        assert level is not None, "__post_init__ admits the scale space's levels only"
        return level

    @property
    def primitives(self) -> int:
        return 1

    def to_dict(self) -> dict:
        return {"type": self.TYPE, "sigma": self.sigma, "histogram": list(self.histogram)}

    @classmethod
    def _from_dict(cls, data: dict) -> "Texture":
        return cls(data["sigma"], data["histogram"])

    def describe(self) -> str:
        return "texture"


@dataclass(frozen=True)
class _Boolean(Feature):
    """Two features whose values combine by :meth:`value`; reported where the stronger one is."""
    __hash__ = _CachedHash.__hash__
    WORD: ClassVar[str] = ""  # its name in legends
    a: Feature
    b: Feature

    def __post_init__(self):
        if not (isinstance(self.a, Feature) and isinstance(self.b, Feature)):
            raise InputError(f"{type(self).__name__} combines two features")

    @property
    def primitives(self) -> int:
        return self.a.primitives + self.b.primitives

    def to_dict(self) -> dict:
        return {"type": self.TYPE, "a": self.a.to_dict(), "b": self.b.to_dict()}

    @classmethod
    def _from_dict(cls, data: dict) -> "_Boolean":
        return cls(Feature.from_dict(data["a"]), Feature.from_dict(data["b"]))

    def subfeatures(self) -> tuple[Feature, ...]:
        return self.a, self.b

    @staticmethod
    def value(a: Tensor, b: Tensor) -> Tensor:
        raise NotImplementedError

    def combine(self, *values: tuple[Tensor, ...]) -> tuple[Tensor, ...]:
        a, b = values
        take_b = b[0] > a[0]
        return (self.value(a[0], b[0]), *(torch.where(take_b, fb, fa) for fa, fb in zip(a[1:], b[1:])))

    def describe(self) -> str:
        return f"{self.WORD}({self.a.describe()}, {self.b.describe()})"


class Conjunction(_Boolean):
    """Value = product of the two sub-feature values (3.5.2)."""
    TYPE, WORD = "conjunction", "and"

    @staticmethod
    def value(a: Tensor, b: Tensor) -> Tensor:
        return a * b


class Disjunction(_Boolean):
    """Value = maximum of the two sub-feature values (3.5.2); its components point to it (4.4.1)."""
    TYPE, WORD = "disjunction", "or"
    ARCS_TO_COMPONENTS = False

    @staticmethod
    def value(a: Tensor, b: Tensor) -> Tensor:
        return torch.maximum(a, b)


@dataclass(frozen=True)
class Within(Feature):
    """``feature`` bounded to ``region``: its value is its best match over the reference points
    inside the region only (eq. 3.14 over fewer points; ``ftorch.space.region``), 0 where none is.

    Every leaf of ``feature`` (texel, geometric compound, texture) is restricted by the region: a
    Boolean compound inside a Within combines its bounded sides, a Boolean of Withins bounds each
    side by its own region, and Within(Within(f, r1), r2) is f bounded by both (their intersection).
    Only the reference point must lie inside: a geometric compound's later parts may reach beyond.

    Its components (4.4.1) are ``feature``, the unbounded feature it was refined from, and the
    components of ``feature`` bounded by the same region. Arcs run from it to them, as from a
    conjunction (a bounded feature present is its unbounded one present): one direction per type,
    as :func:`~ftorch.recognition.bayes.compound_arcs` reads it, also where ``feature`` is a
    disjunction (decision: the arcs only shape the class network, 4.4.1, and stay acyclic, since
    every component is smaller than its compound).
    ``subfeatures`` is ``(feature,)``: tables store it first (packing, checkpoints); its values are
    not a function of the feature's values (``combine``), and ``ftorch.space.evaluate`` measures it.
    """
    __hash__ = _CachedHash.__hash__
    TYPE = "within"
    feature: Feature
    region: Region

    def __post_init__(self):
        if not (isinstance(self.feature, Feature) and isinstance(self.region, Region)):
            raise InputError("Within bounds a Feature to a Region")

    @property
    def primitives(self) -> int:
        return self.feature.primitives

    def to_dict(self) -> dict:
        return {"type": self.TYPE, "feature": self.feature.to_dict(), "region": self.region.to_dict()}

    @classmethod
    def _from_dict(cls, data: dict) -> "Within":
        return cls(Feature.from_dict(data["feature"]), Region.from_dict(data["region"]))

    def subfeatures(self) -> tuple[Feature, ...]:
        return (self.feature,)

    def components(self) -> list[Feature]:
        return [self.feature, *(Within(c, self.region) for c in self.feature.components())]

    def describe(self) -> str:
        return f"{self.feature.describe()} in {self.region.describe()}"


CHUNK = 1024  # features per compressed block of a packed table
MAX_FEATURE_BYTES = 1 << 16  # a feature's JSON is far shorter (a few hundred bytes): bounds what a block may declare


class FeatureTable:
    """Features written once and referred to by position, as checkpoints store them.

    :meth:`index` gives a feature's position (adding it if new); :meth:`pack` writes the table as
    compressed JSON blocks of ``CHUNK`` features; :func:`unpack_features` reads it back. A table
    that grows between checkpoints (the value cache's does) re-packs only its last block where it
    is given the grower's ``memo`` (:class:`~ftorch.checkpoint.Memo`): packed blocks are remembered
    by their features, and so are the blocks read, so that the first checkpoint of a resumed run
    does not compress its whole table again.
    """

    def __init__(self, positions: dict[Feature, int] | None = None, memo: Memo | None = None):
        """An empty table, or one holding the features of ``positions`` (feature -> 0, 1, 2, ...,
        in order, as a value cache keeps its rows), taken over without hashing them again."""
        self._index: dict[Feature, int] = {} if positions is None else positions.copy()
        self.features: list[Feature] = list(self._index)
        self.memo = memo

    def __len__(self) -> int:
        return len(self.features)

    def index(self, feature: Feature) -> int:
        at = self._index.get(feature)
        if at is None:
            at = self._index[feature] = len(self.features)
            self.features.append(feature)
        return at

    def pack(self) -> dict:
        blocks = []
        for start in range(0, len(self.features), CHUNK):
            chunk = tuple(self.features[start : start + CHUNK])
            block = None if self.memo is None else self.memo.feature_block(chunk)
            if block is None:
                block = encode_text("[" + ",".join(f.to_json() for f in chunk) + "]")
                if self.memo is not None:
                    self.memo.remember_features(chunk, block)
            blocks.append(block)
        return {"blocks": blocks}


def unpack_features(data: dict, memo: Memo | None = None) -> list[Feature]:
    """The features of a :meth:`FeatureTable.pack` table; ValueError where it is damaged. ``memo``:
    where the blocks read are remembered as packed already (a resumed run writes them as they are)."""
    if not isinstance(data, dict) or not isinstance(data.get("blocks"), list):
        raise ValueError("damaged feature table (no blocks)")
    features: list[Feature] = []
    for block in data["blocks"]:
        try:
            items = json.loads(decode_text(block, CHUNK * MAX_FEATURE_BYTES))
        except (json.JSONDecodeError, RecursionError) as err:
            raise ValueError(f"damaged feature table ({type(err).__name__})") from None
        if not isinstance(items, list):
            raise ValueError("damaged feature table (not a list)")
        try:
            chunk = tuple(Feature.from_dict(d) for d in items)
        except RecursionError:
            raise ValueError("damaged feature table (nested too deeply)") from None
        if memo is not None:
            memo.remember_features(chunk, block)
        features += chunk
    return features
