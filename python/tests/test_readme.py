"""The README's Python quick start runs as written."""

import os
import re

from conftest import ROOT


def test_the_readme_python_quick_start_runs(tmp_path, capsys):
    text = (ROOT / "README.md").read_text()
    marker = text.index("<!-- python quick start")
    block = re.search(r"```python\n(.*?)```", text[marker:], re.S)
    assert block, "the README has no Python quick start block after its marker"
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        exec(compile(block.group(1), "README.md (python quick start)", "exec"), {})
    finally:
        os.chdir(here)
    out = capsys.readouterr().out
    assert "30 frames tracked" in out, out
