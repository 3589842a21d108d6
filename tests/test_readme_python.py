"""The README runs as written: its Python section (discover, save, load, solve with the loaded set), then
its command-line examples in the same folder (one uses the saved set), and the worked toy's script."""

from __future__ import annotations

import re
import runpy
import shlex
from pathlib import Path

import pytest

from autotight.cli import main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _section(title: str) -> str:
    text = README.read_text(encoding="utf-8")
    return text.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


def _python_section() -> str:
    blocks = re.findall(r"```python\n(.*?)```", _section("Python"), flags=re.S)
    assert len(blocks) == 1, "the Python section has exactly one code block"
    return blocks[0]


def _cli_commands() -> list[list[str]]:
    """Every line of the "Command line" section's sh blocks, as argv after ``.venv/bin/autotight``."""
    out = []
    for block in re.findall(r"```sh\n(.*?)```", _section("Command line"), flags=re.S):
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            if words:
                assert words[0] == ".venv/bin/autotight", line
                out.append(words[1:])
    return out


def test_readme_stays_short():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 200


def test_readme_python_section_and_command_lines_run(tmp_path, monkeypatch, capsys):
    code = _python_section()
    assert len([ln for ln in code.splitlines() if ln.strip()]) <= 10
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(code, str(README), "exec"), scope)  # noqa: S102 - the README's own example
    out = scope["out"]
    assert (tmp_path / "pose_set.json").is_file()
    assert out.tight and out.log_svr > 5
    assert abs(out.upper - out.sdp.primal_cost) <= 1e-6 * abs(out.upper)
    assert len(scope["pose_set"]) == len(scope["found"].discovered.pairs) > 0

    commands = _cli_commands()
    assert len(commands) >= 3
    for argv in commands:  # in the folder where the Python section saved pose_set.json
        capsys.readouterr()
        rc = main(argv)
        text = capsys.readouterr().out
        assert rc == 0, (argv, text)
        if argv[0] == "solve":
            assert re.search(r"\btight\b", text) and "not tight" not in text, (argv, text)
        if argv[0] == "certify":
            assert "CERTIFIED" in text and "NOT CERTIFIED" not in text, text
        if argv[0] == "check":
            assert "PASSED" in text, text


def test_toy_script_gives_the_readme_figures(capsys):
    pytest.importorskip("cvxpy")
    figures = runpy.run_path(str(ROOT / "docs" / "toy_lifting.py"))["main"]()
    assert figures["null_dim"] == 3
    assert figures["cost_primary"] < 1e-3 * figures["f_min"]  # the primary constraints alone: far below
    assert figures["cost_tight"] == pytest.approx(figures["f_min"], rel=1e-4)  # ac = b²: the global minimum
    assert figures["log_svr_tight"] > 5


def test_performance_tables_are_those_the_results_give():
    """docs/performance.md's tables are generated from benchmarks/results/*.json (a results file changed
    without `python benchmarks/performance_table.py` fails here)."""
    table = runpy.run_path(str(ROOT / "benchmarks" / "performance_table.py"))
    assert table["main"](["--check"]) == 0
