"""The README's Python example runs as written and relights within a stated error."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_readme_python_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert len(blocks) == 1
    namespace: dict = {}
    exec(compile(blocks[0], str(README), "exec"), namespace)
    assert namespace["result"].report.chosen_model == "dielectric"  # the family it was rendered with
    assert namespace["error"] < 0.01, namespace["error"]
    assert "measured relighting error under the sunset" in capsys.readouterr().out
