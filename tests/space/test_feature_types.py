"""A new feature type is one class: a toy single-edgel feature, defined in this file only, goes
through feature values (against the per-point reference), compounds, a class network with its
arcs and pgmpy export, legends and drawings, and JSON, as the built-in types do."""
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from ftorch import FeatureSpace
from ftorch.errors import InputError
from ftorch.recognition.bayes import ClassNetwork, compound_arcs
from ftorch.space.draw import draw_features, feature_legend
from ftorch.space.evaluate import feature_values
from ftorch.space.features import Conjunction, Disjunction, Feature, FeatureTable, LocalFeature, Part, _CachedHash, unpack_features
from ftorch.space.generate import random_texel
from ftorch.space.primitives import PartKind
from ftorch.space.reference import reference_values
from tests.conftest import random_image


@dataclass(frozen=True)
class Edgel(LocalFeature):
    """One edgel's first-order pair (3.4.1), measured at the salient edgels: the smallest local feature."""
    __hash__ = _CachedHash.__hash__
    TYPE = "toy-edgel"
    vector: tuple[float, ...]

    @property
    def parts(self) -> tuple[Part, ...]:
        return (Part(PartKind.EDGEL, self.vector),)

    def to_dict(self) -> dict:
        return {"type": self.TYPE, "vector": list(self.vector)}

    @classmethod
    def _from_dict(cls, data: dict) -> "Edgel":
        return cls(tuple(data["vector"]))

    def describe(self) -> str:
        return "edgel"


@pytest.fixture(scope="module")
def records():
    return FeatureSpace().records([random_image(48, 48, seed=21), random_image(56, 48, seed=22)])  # float64


def edgel_of(records, n: int) -> tuple[Edgel, int]:
    """The toy feature of image n's first salient edgel, and that edgel's slot."""
    p = int(PartKind.EDGEL.mask(records)[n].nonzero()[0])
    return Edgel(tuple(records.canonical[n, p, PartKind.EDGEL.slots].tolist())), p


def test_a_new_type_is_measured_like_the_built_in_ones(records):
    edgel, _ = edgel_of(records, 0)
    texel = random_texel(records, 1, torch.Generator().manual_seed(0))
    features = [edgel, Conjunction(edgel, texel), Disjunction(texel, edgel)]
    values = feature_values(features, records)
    np.testing.assert_allclose(values.values.numpy(), reference_values(features, records), rtol=0, atol=1e-9)
    assert float(values.values[0, 0]) == pytest.approx(1.0)  # its own edgel matches exactly
    both = feature_values([edgel, texel], records).values
    torch.testing.assert_close(values.values[1], both[0] * both[1], rtol=0, atol=0)  # the compounds' own rules
    torch.testing.assert_close(values.values[2], torch.maximum(both[0], both[1]), rtol=0, atol=0)


def test_a_new_type_joins_class_networks_with_the_arcs_of_4_4_1(records):
    edgel, _ = edgel_of(records, 0)
    texel = random_texel(records, 1, torch.Generator().manual_seed(0))
    both, either = Conjunction(edgel, texel), Disjunction(edgel, texel)
    assert compound_arcs(both, [edgel, texel]) == ([], [edgel, texel])  # the conjunction points to its parts
    assert compound_arcs(edgel, [both, either]) == ([both], [either])  # the toy part points to the disjunction
    net = ClassNetwork("duck")
    for feature in (edgel, both, either):
        net.add_feature(feature, *compound_arcs(feature, net.features))
    assert net.parents[both] == () and net.parents[edgel] == (both,) and net.parents[either] == (edgel,)
    net.to_pgmpy().check_model()
    assert "variable class" in net.to_bif()


def test_a_new_type_round_trips_through_json_and_packed_tables(records):
    edgel, _ = edgel_of(records, 1)
    nested = Disjunction(Conjunction(edgel, edgel), edgel)
    assert Feature.from_json(edgel.to_json()) == edgel and Feature.from_json(nested.to_json()) == nested
    table = FeatureTable()
    for feature in (edgel, nested):
        table.index(feature)
    assert unpack_features(table.pack()) == [edgel, nested]
    with pytest.raises(InputError, match="unknown feature type 'toy-edgels'"):
        Feature.from_dict({"type": "toy-edgels", "vector": [1.0, 0.0]})


def test_a_new_type_is_named_and_drawn(records):
    edgel, p = edgel_of(records, 0)
    legend = feature_legend([edgel, Conjunction(edgel, edgel)], [0, 1], 300)
    assert legend.shape[1] == 300 and (legend < 255).any()
    assert Conjunction(edgel, edgel).describe() == "and(edgel, edgel)"
    image = torch.zeros(48, 48)
    plain = draw_features(records, 0, image, [])
    drawn = draw_features(records, 0, image, [edgel])
    assert drawn.shape == plain.shape and (drawn != plain).any()  # a marker at its edgel
