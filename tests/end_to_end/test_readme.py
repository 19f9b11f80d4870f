"""The README's and the docs' examples run as written: every Python block, in order (the README's
first, then docs/usage.md's), and every command line parses."""
import re
import shlex
from pathlib import Path

import pytest

from training import run

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()
DOCS = [README] + [(ROOT / "docs" / f"{page}.md").read_text() for page in ("usage", "results", "decisions", "benchmark", "layout")]
CI = (ROOT / ".ci" / "run").read_text()


def blocks(language: str, pages: list[str] = DOCS) -> list[str]:
    return [b for page in pages for b in re.findall(rf"```{language}\n(.*?)```", page, re.S)]


def test_the_first_lines_say_what_it_is_then_give_the_two_set_up_commands():
    first = blocks("bash", [README])[0].strip().splitlines()
    assert len(first) == 2 and all(line.startswith("pip install torch==2.13.0 -e ") for line in first)
    assert first[0].endswith("&& python -m training.run")
    test_command = first[1]
    install, tests = test_command.split(" && ")
    assert "python -m " + install.replace("pip install", "pip install --quiet") in CI and tests in CI  # the same command
    assert README.index("ftorch learns") < README.index("```bash")


def test_every_python_example_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the examples write learner.json and state.json
    namespace = {}
    examples = blocks("python")
    assert len(examples) >= 4
    for n, example in enumerate(examples):
        exec(compile(example, f"README python block {n + 1}", "exec"), namespace)
    assert (tmp_path / "learner.json").is_file() and (tmp_path / "state.json").is_file()
    assert "variable class" in capsys.readouterr().out  # the BIF export printed


def _command_lines() -> list[str]:
    lines = [line.split("#")[0].strip() for b in blocks("bash") for line in b.splitlines()]
    return [line for line in lines if line.startswith("python -m training.run ")]


@pytest.mark.parametrize("line", _command_lines())
def test_every_command_line_example_parses(line):
    line = re.sub(r"\[[^\]]*\]", "", line)  # [optional] parts
    argv = [re.sub(r"\bS\b", "0", a) for a in shlex.split(line)[3:]]
    run.parser().parse_args(argv)  # argparse exits on anything it does not know


def _anchors(page: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in re.findall(r"^#+ (.*)$", page, re.M)}


def test_the_readme_is_a_front_page_whose_links_resolve():
    assert len(README) < 12_000  # the decisions and the full results live in docs/
    pattern = r"\]\(([\w/.-]+\.(?:md|png))?(?:#([\w-]+))?\)"
    links = [("", *link) for link in re.findall(pattern, README)]
    links += [(f"docs/{name}.md", *link) for name, page in zip(("usage", "results", "decisions", "benchmark", "layout"), DOCS[1:])
              for link in re.findall(pattern, page)]
    assert len(links) >= 12
    for source, target, anchor in links:
        page = ROOT / (source or "README.md")
        path = page.parent / target if target else page
        assert path.is_file(), f"{source or 'README.md'}: no {target}"
        if anchor:
            assert anchor in _anchors(path.read_text()), f"{source or 'README.md'}: no heading for #{anchor} in {path.name}"
