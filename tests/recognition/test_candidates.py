"""Alg. 4.10's five methods (ftorch/recognition/candidates.py), each against its definition."""
import numpy as np
import torch

from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.candidates import CandidateGenerator, Method, in_use, pick
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.settings import LearnerSettings
from ftorch.space.features import Conjunction, Disjunction, Geometric, LocalFeature, Texel
from ftorch.space.generate import expand_geometric
from ftorch.space.primitives import PartKind
from tests.recognition.test_learner import shape

THESIS = LearnerSettings.thesis()  # what a candidate generator draws: texels and edgel pairs, no regions


def _setting():
    rng = np.random.default_rng(0)
    env = ImageSet([shape(k % 3, rng.uniform(0, 6.3), rng) for k in range(6)], [{k % 3} for k in range(6)])
    texel = lambda x: Texel([x] + [0.0] * 14)  # noqa: E731
    networks = {c: ClassNetwork(c) for c in range(3)}
    for c, features in ((0, [texel(1.0), texel(2.0)]), (1, [texel(2.0), texel(3.0)]), (2, [texel(4.0)])):
        for f in features:
            networks[c].add_feature(f, [], [], threshold=0.5)
    return env, networks, texel


def test_method_1_reuses_only_features_of_unrelated_classes():
    env, networks, texel = _setting()
    generate = CandidateGenerator(torch.Generator().manual_seed(0))
    made = generate(Method.REUSE, 50, THESIS, networks, env, [0], 0, frozenset({1}), [])
    assert len(made) == 50 and set(made) == {texel(4.0)}  # 1.0-3.0 belong to class 0 or 1
    assert generate(Method.REUSE, 5, THESIS, networks, env, [0], 0, frozenset({1, 2}), []) == [] and generate.sampled == 0


def test_methods_2_and_3_sample_from_the_sample_image_and_count_what_they_sample():
    env, networks, texel = _setting()
    generate = CandidateGenerator(torch.Generator().manual_seed(1))
    primitives = generate(Method.PRIMITIVE, 40, THESIS, networks, env, [3], 0, frozenset({1}), [])
    kinds = {f.parts[0].kind if isinstance(f, Geometric) else PartKind.TEXEL for f in primitives}
    assert all(isinstance(f, LocalFeature) for f in primitives) and kinds == {PartKind.TEXEL, PartKind.EDGEL}
    assert generate.sampled == len(primitives) > 30
    assert np.allclose(env.values(primitives, [3]), 1.0, atol=1e-5)  # each is found at its own point in image 3
    expanded = generate(Method.EXPANSION, 10, THESIS, networks, env, [3], 0, frozenset({1}), primitives[:2])
    assert expanded and all(isinstance(f, Geometric) for f in expanded)
    assert generate.sampled == len(primitives) + len(expanded)


def test_methods_4_and_5_combine_two_different_features_in_use_or_failed():
    env, networks, texel = _setting()
    generate = CandidateGenerator(torch.Generator().manual_seed(2))
    pool = set(in_use(networks)) | {texel(9.0)}
    for method, kind in ((Method.CONJUNCTION, Conjunction), (Method.DISJUNCTION, Disjunction)):
        made = generate(method, 30, THESIS, networks, env, [0], 0, frozenset({1}), [texel(9.0)])
        assert len(made) == 30 and all(isinstance(f, kind) and f.a != f.b and {f.a, f.b} <= pool for f in made)
    assert generate.sampled == 0 and generate(Method.CONJUNCTION, 5, THESIS, {0: ClassNetwork(0)}, env, [0], 0, frozenset(), []) == []


def test_same_generator_state_same_candidates():
    env, networks, _ = _setting()
    runs = [CandidateGenerator(torch.Generator().manual_seed(3)) for _ in range(2)]
    first, second = ([g(m, 10, THESIS, networks, env, [1], 0, frozenset({1}), []) for m in Method] for g in runs)
    assert first == second


def test_method_3_measures_a_feature_once_per_sample_image_and_expands_as_without_the_memory(monkeypatch):
    """The generator remembers where each picked feature is strongest on each sample image: the same
    candidates as measuring it every time (the same generator state), and each (image, feature) measured once."""
    import ftorch.space.generate as generate_module

    env, networks, texel = _setting()
    pool = CandidateGenerator(torch.Generator().manual_seed(2))(Method.PRIMITIVE, 6, THESIS, networks, env, [3], 0, frozenset({1}), [])
    measured, now = [], []
    strongest = generate_module.strongest
    monkeypatch.setattr(generate_module, "strongest", lambda f, r, n: measured.append((now[-1], f)) or strongest(f, r, n))
    remembering = CandidateGenerator(torch.Generator().manual_seed(5))
    made = []
    for sample in (3, 3, 4):
        now.append(sample)
        made.append(remembering(Method.EXPANSION, 20, THESIS, networks, env, [sample], 0, frozenset({1}), pool))
    assert len(measured) == len(set(measured)) < 60  # each (image, feature) once; 60 picks in all
    assert {image for image, _ in measured} == {3, 4}
    fresh = []
    generator = torch.Generator().manual_seed(5)
    for sample in (3, 3, 4):
        local = [f for f in in_use(networks) + pool if isinstance(f, LocalFeature)]
        fresh.append([f for f in (expand_geometric(pick(local, generator), env.record(sample), 0, generator)
                                  for _ in range(20)) if f is not None])
    assert made == fresh and any(made)
    other = ImageSet(env.images, env.labels)  # another image set: its own memory
    remembering(Method.EXPANSION, 5, THESIS, networks, other, [3], 0, frozenset({1}), pool)
    assert remembering._located[0] is other
