"""A grasp seed study where a seed had no poor haptic grasps: its reduction is not available, not 0 %
(issue 52, item 7). Hand-made per-seed results; no grasp experiment runs."""
import json
from dataclasses import asdict

import pytest

from training.grasping.figures import reduction_figure
from training.grasping.records import FoldTests, Grasp, GraspReport, Mode, RunConfig
from training.grasping.report import _seed_table, _spread, results, seed_study
from training.recognition.report import write_json


def _grasps(mu0s: list[float]) -> list[Grasp]:
    return [Grasp("square", 0, 3, 0.0, 0.0, m, 4, True, recommended=True) for m in mu0s]


def _seed(seed: int, haptic: list[float], cued: list[float],
          online: tuple[list[float], list[float]] | None = None) -> GraspReport:
    """One seed's report as the grasp command writes it (:func:`results` over hand-made grasps)."""
    def pooled(h, c):
        return results([FoldTests([3.0, 8.0], _grasps(h), _grasps(c))])
    both = None if online is None else {Mode.OFFLINE: pooled(haptic, cued), Mode.ONLINE: pooled(*online)}
    return GraspReport(RunConfig(seed=seed), "cpu", {}, 1.0, pooled(haptic, cued), both)


GOOD = [0.1, 0.2, 0.9, 0.8]      # half the haptic grasps poor (mu_0 > 0.4)
NONE_POOR = [0.1, 0.2, 0.3, 0.1]


def test_a_seed_without_poor_haptic_grasps_has_no_reduction_and_is_left_out_of_the_spread():
    assert results([FoldTests([1.0], _grasps(NONE_POOR), _grasps(NONE_POOR))]).poor_grasp_fraction.reduction is None
    study = seed_study([_seed(4, GOOD, [0.1, 0.2, 0.9, 0.1]), _seed(5, NONE_POOR, NONE_POOR)])
    assert [r.poor_grasp_fraction.reduction for r in study.runs] == [0.5, None]
    offline = study.reduction[Mode.OFFLINE]
    assert asdict(offline) == {"mean": 0.5, "sd": 0.0, "worst": 0.5, "worst_seed": 4, "n": 1, "not_available": 1}
    # the other spreads have a value for every seed
    assert study.poor_cued[Mode.OFFLINE].not_available == 0 and study.poor_cued[Mode.OFFLINE].n == 2


def test_spread_over_values_some_not_available():
    assert asdict(_spread([0.9, None, 0.5, 0.7], [0, 1, 2, 3])) == pytest.approx(
        {"mean": 0.7, "sd": 0.2, "worst": 0.5, "worst_seed": 2, "n": 3, "not_available": 1})
    assert asdict(_spread([None, None], [0, 1])) == {"mean": None, "sd": None, "worst": None, "worst_seed": None,
                                                     "n": 0, "not_available": 2}
    assert _spread([0.1, 0.3], [7, 8], worse_is_lower=False).worst_seed == 8


def test_the_seed_table_shows_n_a_and_the_mean_over_the_seeds_that_count():
    study = seed_study([_seed(4, GOOD, [0.1, 0.2, 0.9, 0.1]), _seed(5, NONE_POOR, NONE_POOR)])
    lines = _seed_table(study)
    rows = [line for line in lines if line.startswith("| 4 ") or line.startswith("| 5 ")]
    assert "| 50% |" in rows[0] and "| n/a |" in rows[1] and "0%" not in rows[1]
    summary = next(line for line in lines if line.startswith("offline:"))
    assert ("poor-grasp reduction mean 50%, sd 0%, worst 50% (seed 4; mean over 1 of 2 seeds; "
            "1 seed had no poor haptic grasps to reduce)") in summary
    # the command's last lines say the same
    from training.grasping.report import reduction_words
    assert reduction_words(study.reduction[Mode.OFFLINE], " +- ").startswith("poor-grasp reduction mean 50% +- 0%, worst 50%")


def test_no_seed_with_poor_haptic_grasps_gives_null_and_says_so(tmp_path):
    study = seed_study([_seed(s, NONE_POOR, NONE_POOR, (NONE_POOR, NONE_POOR)) for s in (0, 1, 2)])
    for mode in Mode:
        r = study.reduction[mode]
        assert (r.mean, r.sd, r.worst, r.worst_seed, r.not_available) == (None, None, None, None, 3)
    lines = _seed_table(study)
    assert sum("| n/a | " in line for line in lines) == 3 and all(line.count("n/a") == 2 for line in lines if line.startswith("| 0 "))
    for mode in ("offline", "online"):
        assert any(line.startswith(f"{mode}: poor-grasp reduction not available (none of the 3 seeds had poor "
                                   "haptic grasps to reduce)") for line in lines)
    write_json(tmp_path / "report.json", {"seeds": study.to_json()})

    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")
    written = json.loads((tmp_path / "report.json").read_text(), parse_constant=refuse)
    assert written["seeds"]["reduction"]["offline"]["mean"] is None
    assert written["seeds"]["runs"][0]["poor_grasp_fraction"]["reduction"] is None


def test_the_reductions_figure_leaves_out_seeds_without_a_reduction_and_says_how_many():
    study = seed_study([_seed(0, GOOD, [0.1, 0.2, 0.9, 0.1], (GOOD, GOOD)),
                        _seed(1, NONE_POOR, NONE_POOR, (NONE_POOR, NONE_POOR)),
                        _seed(2, GOOD, [0.1, 0.2, 0.3, 0.1], (GOOD, [0.1, 0.2, 0.9, 0.1]))])
    ax = reduction_figure(study, "cue, seeds 0-2").axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["offline (n=2 seeds; 1 left out: no poor haptic grasps)",
                      "online (n=2 seeds; 1 left out: no poor haptic grasps)"]
    # off-line reductions 50 % and 100 %, on-line 0 % and 50 %: two seeds each, the third in no bin (not at 0 %)
    assert [sum(p.get_height() for p in bars) for bars in ax.containers] == [2, 2]
    study = seed_study([_seed(s, NONE_POOR, NONE_POOR) for s in (0, 1)])
    ax = reduction_figure(study, "t").axes[0]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["offline (n=0 seeds; 2 left out: no poor haptic grasps)"]
    assert sum(p.get_height() for p in ax.patches) == 0
