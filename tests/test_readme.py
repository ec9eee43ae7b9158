"""The README's quick start is what CI runs."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

VENV = "python3 -m venv --system-site-packages .venv && . .venv/bin/activate"
MAIN = f"{VENV} && python3 -m pip install -e . && python3 -m refmap run rotor --n 128"
TEST = f'{VENV} && python3 -m pip install -e ".[test]" && python3 -m pytest -n 2'


def _code_lines(text):
    return [ln.strip() for ln in text.splitlines()]


def test_ci_runs_the_readme_test_command():
    """The README's quick start is two commands, each a line of its own that makes (or
    reuses) the virtual environment (a PEP 668 system Python refuses a bare `pip install`);
    CI runs the test command exactly as written."""
    readme = _code_lines((ROOT / "README.md").read_text())
    ci = _code_lines((ROOT / ".ci" / "run").read_text())
    assert MAIN in readme
    assert TEST in readme
    assert TEST in ci


def test_readme_main_job_names_a_real_scenario():
    from refmap.scenarios import SCENARIOS

    readme = (ROOT / "README.md").read_text()
    assert "python3 -m refmap run rotor --n 128" in readme
    assert "rotor" in SCENARIOS
