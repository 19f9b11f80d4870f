"""explain: a recognition's trace (alg. 4.4) as data and as a picture, and the explain command."""
import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ftorch import DistinctiveFeatureLearner, ImageSet
from ftorch.images import to_uint8
from ftorch.recognition import Evidence
from ftorch.recognition.explain import COLOURS, Effect, Explanation, Location, Step
from ftorch.space.evaluate import feature_values
from ftorch.space.features import Feature, Texel, Texture, Within
from ftorch.space.primitives import PartKind
from ftorch.space.region import Region
from training import run
from training.cli.outputs import Command, Ledger
from training.data.datasets import coil_task, plym_task


def _split(task):
    train, test = task.fold(1)
    pick = lambda views: ([task.images[i] for i in views], [task.labels[i] for i in views])  # noqa: E731
    return pick(train), pick(test)


@pytest.fixture(scope="module")
def plym():
    """A learner of three built-in solids (stage 0) and its test views."""
    (X, y), (X_test, y_test) = _split(plym_task(size=40, classes=3))
    return DistinctiveFeatureLearner(seed=0).fit(X, y, stages=0), X_test, y_test


def _strict(text: str):
    """json.loads that refuses NaN and the infinities."""
    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


def _coil():
    from tests.conftest import COIL
    if not COIL.is_dir():
        pytest.skip(f"COIL data (../shared/data/coil-20-32) not found at {COIL}")
    (X, y), (X_test, _) = _split(coil_task(COIL, classes=4, views=12))
    return DistinctiveFeatureLearner(seed=0).fit(X, y, stages=0), X_test


def _recognition(learner, image):
    return learner.recognize(ImageSet([image], space=learner.space), 0)


@pytest.mark.parametrize("task", ["plym", "coil"])
def test_explain_answers_as_predict_on_every_test_image(task, plym):
    learner, images = plym[:2] if task == "plym" else _coil()
    answers, proba = learner.predict(images), learner.predict_proba(images)  # as one block (24 images and more)
    tops = learner.predict(images, answer="top-1")
    for n, image in enumerate(images):
        explanation = learner.explain(image)
        assert explanation.recognized == answers[n] == learner.predict([image])[0]  # one image: image by image
        assert [explanation.posteriors[c] for c in learner.classes_] == proba[n].tolist()
        assert explanation.top == tops[n] is not None  # the top-1 answer too
    assert any(answers) and any(learner.explain(image).steps for image in images[:3])


@pytest.mark.parametrize("options", [{}, {"evidence": "positive", "test_information": 0.05}])
def test_the_steps_are_the_learners_own_recognition(options, plym):
    """The trace is recognize()'s, step by step, under the learner's evidence and test_information."""
    learner, images, _ = plym
    before = learner.settings
    learner.set_params(**options)
    try:
        for image in images[:8]:
            explanation, rec = learner.explain(image), _recognition(learner, image)
            assert [s.feature for s in explanation.steps] == rec.queried
            assert [s.value for s in explanation.steps] == [rec.values[f] for f in rec.queried]
            assert explanation.priors == rec.beliefs[0] and explanation.posteriors == rec.posteriors
            assert [s.before for s in explanation.steps] == rec.beliefs[:-1]
            assert [s.beliefs for s in explanation.steps] == rec.beliefs[1:]
            for step in explanation.steps:
                holders = [c for c, net in learner.networks.items() if step.feature in net]
                assert [node.label for node in step.nodes] == holders
                for node in step.nodes:
                    assert node.threshold == learner.networks[node.label].threshold[step.feature]
                    assert node.present == (step.value > node.threshold)
            assert explanation.evidence == learner.settings.evidence
            assert explanation.information == learner.settings.test_information
    finally:
        learner.settings = before
    if options:  # the settings change the trace: the test above would see a trace made with other ones
        default = [len(learner.explain(image).steps) for image in images[:8]]
        learner.set_params(**options)
        try:
            assert [len(learner.explain(image).steps) for image in images[:8]] != default
        finally:
            learner.settings = before


def test_values_and_locations_are_feature_values_of_the_image(plym):
    learner, images, _ = plym
    flat = torch.full((40, 40), 0.5)  # no salient point: every feature without a texture has value 0 and no location
    for image in [*images[:6], flat]:
        explanation = learner.explain(image)
        features = [s.feature for s in explanation.steps]
        found = feature_values(features, learner.space.records([image]))
        assert [s.value for s in explanation.steps] == found.values[:, 0].tolist()
        expected = [Location(*point) for point in zip(*(t[:, 0].tolist() for t in (found.x, found.y, found.sigma, found.theta)))]
        assert len(expected) == len(explanation.steps) > 0
        for step, location in zip(explanation.steps, expected):
            assert np.array_equal(step.location, location, equal_nan=True)
            assert step.where[step.feature, ()] is step.location
    salient = [s for s in learner.explain(flat).steps if not _textured(s.feature)]
    assert salient and not any(s.location.found or s.value for s in salient)


def _textured(feature: Feature) -> bool:
    """Whether a feature holds a texture (a Texture leaf or a texture part): the texture grid covers
    every image, a flat one too (7.2.1), where no salient point lies."""
    parts = getattr(feature, "parts", ())
    return isinstance(feature, Texture) or any(p.kind is PartKind.TEXTURE for p in parts) or \
        any(_textured(sub) for sub in feature.subfeatures())


def test_the_json_form_is_strict_and_complete(plym):
    learner, images, _ = plym
    flat = learner.explain(torch.full((40, 40), 0.5))
    for explanation in (learner.explain(images[0]), flat):
        data = _strict(json.dumps(explanation.to_dict()))
        assert data["recognized"] == sorted(explanation.recognized) and data["top"] == explanation.top
        assert data["focus"] == explanation.focus and data["evidence"] == "both"
        assert data["priors"] == explanation.priors and data["posteriors"] == explanation.posteriors
        assert len(data["steps"]) == len(explanation.steps)
        for n, (row, step) in enumerate(zip(data["steps"], explanation.steps), 1):
            assert row["step"] == n and Feature.from_dict(row["feature"]) == step.feature
            assert row["describe"] == step.feature.describe() and row["value"] == step.value
            assert row["networks"] == [{"class": node.label, "threshold": node.threshold, "present": node.present}
                                       for node in step.nodes]
            assert row["beliefs"] == step.beliefs and row["region"] is None
            assert row["effect"] == step.effect(explanation.focus)
            x = row["location"]["x"]
            assert x is None if not step.location.found else x == step.location.x
    rows = [row for row, step in zip(flat.to_dict()["steps"], flat.steps) if not _textured(step.feature)]
    assert rows and all(row["location"] == dict.fromkeys(("x", "y", "sigma", "theta")) for row in rows)


_BOUND = Within(Texel([1.0] + [0.0] * 14), Region("image", 0.25, 0.75, 0.125))


def test_a_region_bound_feature_writes_its_region():
    nan = Location(math.nan, math.nan, math.nan, math.nan)
    step = Step(_BOUND, 0.0, (), nan, {"a": 0.5}, {"a": 0.5}, {})
    assert step.region == _BOUND.region
    assert step.to_dict()["region"] == {"frame": "image", "x": 0.25, "y": 0.75, "radius": 0.125}
    assert step.to_dict()["location"] == {"x": None, "y": None, "sigma": None, "theta": None}


def _explanation(posteriors: dict, recognized: set, top=None) -> Explanation:
    beliefs = dict.fromkeys(posteriors, 0.5)
    nan = Location(math.nan, math.nan, math.nan, math.nan)
    steps = (Step(_BOUND, 0.0, (), nan, beliefs, posteriors, {}),)
    return Explanation(frozenset(recognized), top, posteriors, beliefs, steps, Evidence.BOTH, 0.0, "x", torch.zeros(9, 9))


def test_the_focus_is_the_top_class_else_the_recognized_else_the_most_probable():
    posteriors = {"a": 0.9, "b": 0.7, "c": 0.4}
    assert _explanation(posteriors, {"a", "b"}, top="b").focus == "b"
    assert _explanation(posteriors, {"b"}).focus == "b"
    assert _explanation(posteriors, {"a", "b"}).focus == "a"
    assert _explanation({"a": 0.2, "b": 0.3, "c": 0.1}, set()).focus == "b"
    explanation = _explanation({"a": 0.2, "b": 0.5, "c": 0.1}, set())
    assert [explanation.steps[0].effect(c) for c in "abc"] == [Effect.LOWERED, Effect.UNCHANGED, Effect.LOWERED]


def _holds(picture: np.ndarray, colour) -> bool:
    return bool((picture == np.array(colour, np.uint8)).all(-1).any())


def test_the_picture_colours_each_step_by_its_effect_on_the_answer(plym):
    learner, images, _ = plym
    explanation = next(e for e in map(learner.explain, images)
                       if {s.effect(e.focus) for s in e.steps} >= {Effect.RAISED, Effect.LOWERED})
    (r, g, b), (R, G, B) = COLOURS["raised"], COLOURS["lowered"]
    assert g > max(r, b) and R > max(G, B) and Effect.RAISED.colour == COLOURS["raised"]  # green raised, red lowered
    assert len(set(COLOURS["unchanged"])) == 1 and Effect.UNCHANGED.colour == COLOURS["unchanged"]  # grey
    picture = explanation.picture()
    assert picture.dtype == np.uint8 and picture.ndim == 3 and picture.shape[2] == 3
    assert min(picture.shape[:2]) > 384  # the 40-pixel image enlarged to 384, a title above it
    assert _holds(picture, COLOURS["raised"]) and _holds(picture, COLOURS["lowered"])
    raised = tuple(s for s in explanation.steps if s.effect(explanation.focus) is Effect.RAISED)
    only = replace(explanation, steps=raised).picture()
    assert _holds(only, COLOURS["raised"]) and not _holds(only, COLOURS["lowered"])


# -- the command -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def saved(plym, tmp_path_factory):
    """The learner saved, and its first test views as PNG files in a folder."""
    learner, images, _ = plym
    root = tmp_path_factory.mktemp("explain")
    learner.save(root / "learner.json")
    (root / "views").mkdir()
    for n, image in enumerate(images[:3]):
        cv2.imwrite(str(root / "views" / f"view{n}.png"), to_uint8(torch.as_tensor(image)))
    return root


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_the_command_writes_one_json_and_one_png_per_image(saved, tmp_path, capsys):
    learner = DistinctiveFeatureLearner.load(saved / "learner.json")
    other = tmp_path / "other"
    other.mkdir()
    (other / "view0.png").write_bytes((saved / "views" / "view1.png").read_bytes())  # the same stem as a view
    out = tmp_path / "out"
    argv = ["explain", "--learner", str(saved / "learner.json"), str(saved / "views"), str(other / "view0.png"),
            "--out", str(out), "--device", "cpu"]
    assert run.main(argv) == 0
    printed = capsys.readouterr().out.splitlines()
    images = [*(saved / "views" / f"view{n}.png" for n in range(3)), other / "view0.png"]
    stems = [f"{n}-{p.stem}" for n, p in enumerate(images, 1)]  # two stems alike: every one numbered
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted(
        f"{s}.{e}" for s in stems for e in ("json", "png"))
    assert len(printed) == len(images) and all(str(p) in line for p, line in zip(images, printed))
    for image, stem in zip(images, stems):
        data = _strict((out / f"{stem}.json").read_text())
        assert data["image"] == str(image)
        assert data["recognized"] == sorted(learner.predict([image])[0])
        assert data == _strict(json.dumps(replace(learner.explain(image), name=str(image)).to_dict()))
        picture = cv2.imread(str(out / f"{stem}.png"))
        assert picture is not None and picture.shape[0] > 384
    assert Ledger(str(out)).command() is Command.EXPLAIN
    assert run.main(argv) == 0  # its own earlier output is replaced


@pytest.mark.parametrize("case", ["damaged", "missing", "unreadable", "too small", "unmeasurable"])
def test_bad_input_is_refused_in_one_line_and_writes_nothing(case, saved, tmp_path, capsys):
    learner, image = saved / "learner.json", saved / "views" / "view0.png"
    if case == "unmeasurable":  # a learner file that does not record its image size: the scale space refuses 6 pixels
        learner = tmp_path / "unsized.json"
        data = json.loads((saved / "learner.json").read_text())
        data["learner"]["sides"] = None
        learner.write_text(json.dumps(data))
        image = tmp_path / "tiny.png"
        cv2.imwrite(str(image), np.full((6, 6), 128, np.uint8))
    elif case == "damaged":
        learner = tmp_path / "learner.json"
        learner.write_text((saved / "learner.json").read_text()[:-40])
    elif case == "missing":
        learner = tmp_path / "nothing.json"
    elif case == "unreadable":
        image = tmp_path / "broken.png"
        image.write_bytes(b"\x89PNG not really")
    else:  # 20 pixels: more than a scale step below the 40 the learner learned from
        image = tmp_path / "small.png"
        cv2.imwrite(str(image), np.full((20, 20), 128, np.uint8))
    out = tmp_path / "out"
    assert run.main(["explain", "--learner", str(learner), str(image), "--out", str(out), "--device", "cpu"]) == 2
    if case == "unmeasurable":
        note, message = capsys.readouterr().err.strip().splitlines()
        assert note.startswith(f"note: {learner} does not record the image size it learned from")
    else:
        message = _one_line(capsys)
    expected = {"damaged": f"{learner}: not a readable checkpoint", "missing": f"{learner}: no such checkpoint file",
                "unreadable": f"{image}: not a readable image file", "too small": "learned from images whose shorter side is 40",
                "unmeasurable": f"{image}: image of 6x6 pixels is too small for the scale range"}
    assert message.startswith("error: ") and expected[case] in message, message
    assert not out.exists()


def test_an_out_inside_the_images_folder_is_refused(saved, tmp_path, capsys):
    views = saved / "views"
    before = sorted(views.iterdir())
    for out, given, why in ((views / "explained", views, f"lies inside IMAGE {views}"),
                            (views, views / "view0.png", f"holds the image {views / 'view0.png'}")):
        argv = ["explain", "--learner", str(saved / "learner.json"), str(given), "--out", str(out), "--device", "cpu"]
        assert run.main(argv) == 2
        message = _one_line(capsys)
        assert message.startswith(f"error: --out {out} {why}"), message
    assert sorted(views.iterdir()) == before and not (views / "explained").exists()


def test_a_folder_holding_another_commands_run_is_refused(saved, tmp_path, capsys):
    out = tmp_path / "evaluated"
    out.mkdir()
    ledger = Ledger(str(out))
    ledger.start(Command.EVALUATE)
    ledger.files(out / "evaluate.json")
    (out / "evaluate.json").write_text("{}")
    argv = ["explain", "--learner", str(saved / "learner.json"), str(saved / "views"), "--out", str(out), "--device", "cpu"]
    assert run.main(argv) == 2
    assert f"--out {out} holds a run of evaluate" in _one_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == [".ftorch-lock", ".ftorch-run", "evaluate.json"]


def test_a_folder_stands_for_its_images_in_name_order(saved, tmp_path, capsys):
    folder = tmp_path / "mixed"
    (folder / "b").mkdir(parents=True)
    for name in ("b/2.png", "a.png", "c.png"):
        (folder / name).write_bytes((saved / "views" / "view0.png").read_bytes())
    (folder / "notes.txt").write_text("not an image")
    (folder / ".hidden.png").write_bytes((saved / "views" / "view0.png").read_bytes())
    out = tmp_path / "out"
    assert run.main(["explain", "--learner", str(saved / "learner.json"), str(folder), "--out", str(out), "--device", "cpu"]) == 0
    captured = capsys.readouterr()
    assert [Path(line.split(":")[0]) for line in captured.out.splitlines()] == [folder / "a.png", folder / "c.png", folder / "b/2.png"]
    assert "1 file(s)" in captured.err and "notes.txt" in captured.err


def test_a_region_bound_feature_is_located_and_drawn_inside_its_region():
    """A learner with regions (the task of tests/recognition/test_search.py where only the place tells the classes
    apart): each bounded step is found inside its disc, drawn there, and the JSON names the region."""
    from tests.recognition.test_search import _spot
    rng = np.random.default_rng(0)
    images = [_spot(rng) if k % 2 == 0 else np.ascontiguousarray(np.rot90(_spot(rng), 2)) for k in range(12)]
    labels = ["upper left" if k % 2 == 0 else "lower right" for k in range(12)]
    learner = DistinctiveFeatureLearner(seed=0, primitives="texture", contrast=4, regions="image").fit(
        images, labels, stages=0, max_cycles=5)
    bounded = 0
    for image in images[:4]:
        explanation = learner.explain(image)
        for step, entry in zip(explanation.steps, explanation.to_dict()["steps"]):
            if not isinstance(step.feature, Within) or not step.location.found:
                continue
            bounded += 1
            region = step.feature.region
            u, v = (step.location.x + 0.5) / 48, (step.location.y + 0.5) / 48
            assert (u - region.x) ** 2 + (v - region.y) ** 2 <= region.radius ** 2 + 1e-12
            assert step.where[step.feature.feature, (region,)] is step.location  # its part, located inside
            assert entry["region"] == region.to_dict()
        assert explanation.picture().ndim == 3
    assert bounded
