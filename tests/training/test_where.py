"""``python -m training.where``: a py-spy profile summed by the learner's phases."""
from training import where


def test_each_sample_counts_once_towards_its_innermost_phase(tmp_path, capsys):
    stack = "<module> (training/run.py:90);Fold.run (training/recognition/protocol.py:257)"
    learn = f"{stack};Learning.learn (ftorch/recognition/learning.py:120)"
    search = f"{learn};Learning._search (ftorch/recognition/learning.py:260)"
    lines = [
        f"{search};Counting.measure (ftorch/recognition/counting.py:51);values_only (ftorch/space/evaluate.py:181) 30",
        f"{search};Learning._learning_recognition (ftorch/recognition/learning.py:190);"
        "ExactInference.evaluate (ftorch/recognition/exact.py:196) 20",
        f"{learn};Recognizer.first (ftorch/recognition/recognizer.py:120);"
        "recognize_block (ftorch/recognition/inference.py:190) 10",
        f"{search} 5",
        f"{stack} 5",
        "_find_and_load (<frozen importlib._bootstrap>:1165) 30",
        "not a sample",
    ]
    phases, across, total = where.summed(lines)
    assert total == 100
    assert phases == {"measuring candidates (alg. 4.8)": 30, "recognitions inside a search (alg. 4.8 step 8)": 20,
                      "first recognitions of presentations (alg. 4.7 step 1)": 10,
                      "rest of the search (adding, removing nodes)": 5, "other": 5, "start-up (imports)": 30}
    assert across == {"feature values (values_only)": 30, "exact inference (ExactInference.evaluate)": 20}
    profile = tmp_path / "run.txt"
    profile.write_text("\n".join(lines) + "\n")
    assert where.main([str(profile), "--rate", "10"]) == 0
    printed = capsys.readouterr().out
    assert "| measuring candidates (alg. 4.8) | 3.0 | 30.0% |" in printed and "| **all** | **10.0** | |" in printed
    profile.write_text("no samples here\n")
    assert where.main([str(profile)]) == 2
    assert "no py-spy samples" in capsys.readouterr().err
    assert where.main([str(tmp_path / "missing.txt")]) == 2
