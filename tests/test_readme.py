"""The README's quick start is what CI runs."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    cmd = 'python3 -m pip install -e ".[test]" && python3 -m pytest -n 2'
    assert cmd in readme
    assert cmd in ci


def test_readme_main_job_names_a_real_scenario():
    from refmap.scenarios import SCENARIOS

    readme = (ROOT / "README.md").read_text()
    assert "python3 -m refmap run rotor --n 128" in readme
    assert "rotor" in SCENARIOS
