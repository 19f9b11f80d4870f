"""The Plym task refuses what it cannot give before it renders a view (issue 52, item 13): rendering
all 8 x 15 views takes 43-100 s on two cores."""
import time

import pytest
import torch

from ftorch import InputError
from tests.end_to_end.test_hardening import exit_code, one_line
from training.data import plym
from training.data.datasets import load_task, plym_task
from training.data.plym import plym_images

BEYOND = [  # (classes, views, first_view), what the refusal names
    ((100, None, 0), "--classes 100: the plym task has 8 classes; expected 2 to 8"),
    ((9, None, 0), "the plym task has 8 classes; expected 2 to 8"),
    ((1, None, 0), "the plym task has 8 classes; expected 2 to 8"),
    ((None, 16, 0), "of the plym task has 15 views; --first-view 0 --views 16 needs views 0 to 15"),
    ((2, 4, 12), "of the plym task has 15 views; --first-view 12 --views 4 needs views 12 to 15"),
    ((2, None, 15), "of the plym task has 15 views; --first-view 15 --views all needs view 15 and on"),
]


@pytest.fixture
def no_rendering(monkeypatch):
    def render(*_args, **_kwargs):
        raise AssertionError("a view was rendered for a request the task refuses")
    monkeypatch.setattr(plym, "render", render)


@pytest.mark.parametrize("request_, message", BEYOND)
def test_load_task_refuses_a_plym_request_beyond_the_task_before_rendering(no_rendering, request_, message):
    classes, views, first_view = request_
    start = time.perf_counter()
    with pytest.raises(InputError, match=message.replace("(", r"\(")) as refused:
        load_task("plym", None, classes, views, 32, first_view=first_view)
    assert time.perf_counter() - start < 0.5 and "\n" not in str(refused.value)
    with pytest.raises(InputError, match="the plym task has"):
        plym_task(32, 0, classes, views, first_view)


def test_plym_task_refuses_a_size_below_nine_before_rendering(no_rendering):
    with pytest.raises(InputError, match="--size 8: expected at least 9 pixels"):
        plym_task(size=8)


@pytest.mark.parametrize("argv, message", [
    (["--classes", "100"], "the plym task has 8 classes; expected 2 to 8"),
    (["--views", "20"], "of the plym task has 15 views; --first-view 0 --views 20 needs views 0 to 19"),
])
def test_the_runner_refuses_a_plym_request_beyond_the_task_at_once(no_rendering, tmp_path, capsys, argv, message):
    start = time.perf_counter()
    assert exit_code(["recognize", "--task", "plym", *argv, "--quiet", "--out", str(tmp_path / "run")]) == 2
    assert time.perf_counter() - start < 5  # the runner's own checks, no rendering (that took 43-100 s)
    assert message in one_line(capsys)


def test_the_layout_is_that_of_the_rendered_views(monkeypatch):
    from training.data.plym import plym_layout
    monkeypatch.setattr(plym, "render", lambda name, view, size: torch.zeros(size, size))
    images, *layout = plym_images(9, 0)
    assert len(images) == 8 * 15 and tuple(layout) == plym_layout()
    labels, names, positions = layout
    assert labels[15] == "cube" and names[16] == "cube_v01" and positions[:3] == [0, 1, 2] and positions[15] == 0
