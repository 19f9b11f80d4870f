import pytest

from tests.end_to_end.test_hardening import RUN
from tests.end_to_end.test_run_folders import files
from training import run


@pytest.fixture(scope="session")
def finished_run(tmp_path_factory):
    """A finished recognize run (``RUN``, one fold) and every file in it, made once per test run: the
    tests that take it only read it, or copy it before they change anything."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert run.main([*RUN, "--out", str(out)]) == 0
    return out, files(out)
