"""The Python examples of the README and of the getting-started guide run as written."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks
    monkeypatch.chdir(tmp_path)
    for code in blocks:
        exec(compile(code, str(README), "exec"), {"__name__": "readme"})
    assert (tmp_path / "out" / "py" / "summary.json").exists()


def test_getting_started_python_blocks_run(tmp_path, monkeypatch):
    guide = README.parent / "docs" / "guide" / "getting-started.md"
    blocks = re.findall(r"```python\n(.*?)```", guide.read_text(), flags=re.S)
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    for code in blocks:
        exec(compile(code, str(guide), "exec"), {"__name__": "guide"})
    assert (tmp_path / "out" / "first" / "summary.json").exists()
