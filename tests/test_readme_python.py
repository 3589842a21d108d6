"""The README's "Python" section runs as written: discover, save, load, solve with the loaded set."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_section() -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Python\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the Python section has exactly one code block"
    return blocks[0]


def test_readme_python_section_runs_and_the_loaded_set_is_tight(tmp_path, monkeypatch):
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
