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


def _scenario_block() -> str:
    """The README's example scenario: the first YAML block of its Scenarios section."""
    section = README.read_text().split("## Scenarios", 1)[1]
    return re.search(r"```yaml\n(.*?)```", section, flags=re.S).group(1)


def test_readme_scenario_runs_as_written(tmp_path):
    import geofix

    path = tmp_path / "alaska.yaml"
    path.write_text(_scenario_block())
    scenario = geofix.load_scenario(path)
    assert scenario.map.path.startswith("builtin:")  # runs without a file of one's own
    out = tmp_path / "out"
    result = geofix.run_campaign(scenario, ["tercom", "ins"], trials=2, jobs=1, out_dir=out)
    stats = result.summary.methods
    assert stats["tercom"].failures == 0 and stats["ins"].failures == 0
    assert stats["tercom"].mean_error_m < stats["ins"].mean_error_m  # a fix, not the INS
    assert result.summary.crlb_m is not None
