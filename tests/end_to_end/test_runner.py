"""The command line: salient pictures, the default job, clear errors, and the benchmark's report."""
import json
import re
import subprocess
import sys

import cv2
import numpy as np

from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.exact import engine
from training import bench, run


def test_salient_writes_one_png_per_image_and_prints_counts(tmp_path, coil_dir, capsys):
    images = [str(coil_dir / "obj1__0.png"), str(coil_dir / "obj2__10.png")]
    assert run.main(["salient", *images, "--out", str(tmp_path), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out.splitlines()
    summary = json.loads((tmp_path / "salient.json").read_text())
    assert len(printed) == 2 and len(summary) == 2
    for line, row in zip(printed, summary):
        assert f"{row['edgels']} edgels, {row['texels']} texels" in line
        picture = cv2.imread(row["figure"])
        assert picture is not None and picture.shape[1] > 1.8 * picture.shape[0]  # two panels side by side, titled


def test_default_job_runs_the_builtin_plym_task(tmp_path):
    done = subprocess.run([sys.executable, "-m", "training.run"], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    report = json.loads((tmp_path / "runs/plym/report.json").read_text())
    assert report["task"] == "plym" and len(report["folds"]) == 2 and len(report["classes"]) == 8
    assert report["average"]["final"]["test"]["accuracy"] > 1 / 8  # well above chance
    assert "report: runs/plym/report.md" in done.stdout and "tensorboard --logdir runs/plym/tensorboard" in done.stdout
    assert all(len(f["stages"]) > 1 for f in report["folds"])  # expert stages follow stage 0
    assert re.search(r"fold 2: \d+cycle .*stage=\d+, t_ksd=", done.stderr)  # progress bars


def test_salient_draws_the_builtin_scene_without_images(tmp_path):
    assert run.main(["salient", "--out", str(tmp_path), "--device", "cpu"]) == 0
    assert (tmp_path / "builtin-scene_salient.png").is_file()


def test_bad_input_is_one_line_and_exit_code_2(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_text("no pixels here")
    done = subprocess.run([sys.executable, "-m", "training.run", "salient", str(bad), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip() == f"error: {bad}: not a readable image file"
    assert "Traceback" not in done.stderr


def test_unavailable_device_is_refused_clearly(tmp_path, monkeypatch):
    monkeypatch.setattr("torch.cuda.is_available", lambda: False)
    assert run.main(["salient", "--out", str(tmp_path), "--device", "cuda"]) == 2


def test_benchmark_quick_report_has_every_key(tmp_path):
    target = tmp_path / "bench.json"
    assert bench.main(["features", "--quick", "--json", str(target)]) == 0
    report = json.loads(target.read_text())
    p = report["pyramid"]
    for key in ("images_per_s", "opencv_images_per_s", "ratio_vs_opencv"):
        assert p[key] > 0
    assert p["within_tolerance"], "ftorch or OpenCV maps exceed the scipy tolerance"
    assert report["record"]["images_per_s"] > 0
    for section in ("texel", "edgel_pair", "edgel3", "geometric3", "boolean"):
        assert report[section]["evals_per_s"] > 0 and report[section]["ratio_vs_reference"] > 0
        assert report[section]["max_error_vs_reference"] < 1e-5  # float32 batched vs the float64 per-point loop


def test_recognition_benchmark_agrees_with_its_baselines(tmp_path):
    target = tmp_path / "bench.json"
    assert bench.main(["recognition", "--quick", "--json", str(target)]) == 0
    report = json.loads(target.read_text())
    assert report["evaluations_per_s"] > 0 and report["ratio_vs_pgmpy"] > 0 and report["ratio_vs_einsum"] > 0
    assert report["max_difference_vs_einsum"] < 1e-9 and report["max_difference_vs_pgmpy"] < 1e-9
    large = report["large_group"]
    assert max(large["groups"]) > ClassNetwork.TABLE_LIMIT and large["evaluations"] > large["recognitions"] > 0
    assert large["ratio_vs_without_memory"] > 0 and large["max_difference_vs_without_memory"] == 0  # the same sums
    small = report["small_groups"]
    assert max(small["groups"]) <= ClassNetwork.TABLE_LIMIT and small["evaluations"] > small["recognitions"] > 0
    assert small["ratio_vs_without_memory"] > 0 and small["max_difference_vs_without_memory"] == 0
    block = report["block"]  # alg. 4.4 for many images at once against one image at a time
    assert block["bitwise_equal"] and block["ratio_vs_one_by_one"] > 0 and block["queries"] > block["images"] > 1
    assert block["features"] == 6 * 17 - 5 * 2  # six networks of 17 nodes sharing two
    for limit in (ClassNetwork.TABLE_LIMIT, 0):  # the tables and the einsum baseline remember nothing from before
        net = bench.learned_like_network(np.random.default_rng(0), table_limit=limit)
        unobserved, observed = np.full(len(net.features), -1), np.ones(len(net.features), dtype=np.int64)
        engine(net).infer(unobserved)
        assert bench.infer_afresh(net, observed)[0] == engine(net).infer(observed)[0]
        for group in engine(net).groups:
            remembered = list(group.given) + [key for key, _ in group.contracted]
            assert remembered and set(remembered) == {observed[group.positions].tobytes()}


def test_batching_benchmark_replays_the_value_cache_bit_for_bit(tmp_path):
    """One fold's value computations made again as the cache made them give the same bits (the
    premise), and merged per search every value is compared bit by bit."""
    one = np.array([[0.5, np.nan], [0.25, 1.0]], dtype=np.float32)
    other = one.copy()
    other[0, 0] = np.nextafter(np.float32(0.5), np.float32(1))
    assert bench._differing(one, one.copy()) == 0 and bench._differing(one, other) == 1  # NaN equals NaN; one ulp counts
    assert bench._differing(one.T, other.T) == 1  # not contiguous
    target = tmp_path / "bench.json"
    assert bench.main(["batching", "--classes", "3", "--json", str(target)]) == 0
    r = json.loads(target.read_text())
    assert r["replay_differing"] == 0
    assert r["calls"] >= r["merged_calls"] >= r["searches"] > 0 and r["values"] > 0
    assert 0 <= r["values_differing"] <= r["values"] and r["seconds_one_by_one"] > 0 and r["seconds_per_search"] > 0


def test_contrast_benchmark_counts_changed_answers_against_float32_steps(tmp_path):
    target = tmp_path / "contrast.json"
    assert bench.main(["contrast", "--trials", "3", "--json", str(target)]) == 0
    report = json.loads(target.read_text())
    assert report["min_levels"] == 2**15 and report["views"] == 24 and len(report["trials"]) == 3
    for trial in report["trials"]:
        assert 0 < trial["steps"] < 1e6 and 0 <= trial["changed"] <= report["views"]
    assert (report["most_steps_with_a_change"] is None) == all(t["changed"] == 0 for t in report["trials"])
