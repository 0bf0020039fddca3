"""The campaign report: a self-contained HTML page, checked as HTML and as a browser shows it."""

from __future__ import annotations

import base64
import io
import json
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest
from typer.testing import CliRunner

from geofix.cli import app
from geofix.errors import ConfigError
from geofix.evaluate.campaign import run_campaign
from geofix.report import campaign_report, rms_error_m, spec_settings, write_report
from geofix.sim.scenario import scenario_from_dict

SPECS = ["tercom", "tercom:metric=mad,window_sigma=2"]
SUMMARY_TABLES = ("accuracy", "success", "integrity", "bound")
#: matplotlib's first two colours: only the figures paint them.
FIGURE_COLOURS = {"blue": (31, 119, 180), "orange": (255, 127, 14)}


def _scenario(seed: int):
    return scenario_from_dict(
        {
            "name": "report-small",
            "map": {"path": "builtin:mb_1km"},
            "track": {
                "start_cell": [60, 60],
                "heading_deg": 45,
                "speed_m_s": 10,
                "interval_s": 60,
                "samples": 20,
            },
            "sensor": {"type": "singlebeam", "noise_std": 2.0},
            "ins": {"initial_error_m": [1500, -1000], "velocity_error_m_s": 0.05},
            "trials": 3,
            "seed": seed,
        }
    )


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory):
    """A folder that holds two campaigns of one scenario name (seeds 3, then 4)."""
    out = tmp_path_factory.mktemp("campaign")
    run_campaign(_scenario(3), SPECS, jobs=1, out_dir=out)
    run_campaign(_scenario(4), SPECS, jobs=1, out_dir=out)
    return out


@pytest.fixture(scope="module")
def page_html(campaign_dir) -> str:
    """The report of :func:`campaign_dir`, rendered once."""
    return campaign_report(campaign_dir)


class _Page(HTMLParser):
    """Tables (by ``data-caption``: rows of ``(cells, row class)``) and image sources."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: dict[str, list[tuple[list[str], str]]] = {}
        self.images: list[str] = []
        self.tags: set[str] = set()
        self.links: list[str] = []
        self._table = self._row = self._cell = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.add(tag)
        self.links += [attrs[k] for k in ("href",) if k in attrs]
        if tag == "table":
            self._table = self.tables.setdefault(attrs.get("data-caption", ""), [])
        elif tag == "tr" and self._table is not None:
            self._row = ([], attrs.get("class") or "")
        elif tag in ("td", "th") and self._row is not None:
            self._cell = []
        elif tag == "img":
            self.images.append(attrs.get("src", ""))

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._row[0].append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self._table.append(self._row)
            self._row = None
        elif tag == "table":
            self._table = None


def _parse(page: str) -> _Page:
    parser = _Page()
    parser.feed(page)
    return parser


def _decode_png(src: str) -> np.ndarray:
    import matplotlib.image as mpimg

    prefix = "data:image/png;base64,"
    assert src.startswith(prefix)
    data = base64.b64decode(src[len(prefix) :], validate=True)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return mpimg.imread(io.BytesIO(data), format="png")


def test_summary_tables_have_one_row_per_method(campaign_dir, page_html):
    page = _parse(page_html)
    for caption in SUMMARY_TABLES:
        rows = page.tables[caption]
        assert rows[0][0][0] == "method"
        assert [cells[0] for cells, _ in rows[1:]] == SPECS, caption


def test_numbers_are_those_of_the_last_campaign_written(campaign_dir, page_html):
    summary = json.loads((campaign_dir / "summary.json").read_text())
    page = _parse(page_html)
    for (cells, _), spec in zip(page.tables["accuracy"][1:], SPECS, strict=True):
        stats = summary["methods"][spec]
        assert cells[1:4] == [str(stats["trials"]), "0", f"{stats['mean_error_m']:.1f}"]
    for (cells, _), spec in zip(page.tables["bound"][1:], SPECS, strict=True):
        assert cells[1] == f"{rms_error_m(summary['methods'][spec]):.1f}"
    assert f"{summary['crlb_m']:.2f} m" in page_html


def test_rms_error_from_mean_and_population_std():
    errors = np.array([3.0, 4.0, 12.0])
    stats = {"mean_error_m": errors.mean(), "std_error_m": errors.std()}
    assert rms_error_m(stats) == pytest.approx(np.sqrt(np.mean(errors**2)))


def test_the_page_is_self_contained_and_its_figures_decode(campaign_dir, page_html):
    page = _parse(page_html)
    assert not page.tags & {"script", "link", "iframe", "object"}
    assert page.links == []
    assert len(page.images) == 3  # histograms, CDF, error per trial
    for src in page.images:
        image = _decode_png(src)
        assert image.shape[0] > 200 and image.shape[1] > 400
        assert np.ptp(image[..., :3]) > 0.5  # something drawn, not a blank canvas


def test_campaign_png_is_embedded_when_present(campaign_dir, tmp_path):
    for name in ("summary.json", "results.sqlite"):
        shutil.copy(campaign_dir / name, tmp_path / name)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "campaign.png")
    plt.close(fig)
    page = _parse(campaign_report(tmp_path))
    assert len(page.images) == 4
    assert _decode_png(page.images[-1]).shape[:2] == (300, 400)


def test_settings_show_every_setting_and_mark_the_changed_ones(campaign_dir, page_html):
    page = _parse(page_html)
    rows = page.tables[f"settings {SPECS[1]}"][1:]
    names = [s.name for s in spec_settings(SPECS[1])]
    assert [cells[0] for cells, _ in rows] == names
    changed = {cells[0]: cells[1] for cells, cls in rows if cls == "changed"}
    assert changed == {"metric": "'mad'", "window_sigma": "2"}
    assert all(cls == "" for _, cls in page.tables["settings tercom"][1:])


def test_missing_folder_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"summary\.json"):
        campaign_report(tmp_path / "nowhere")


def test_summary_without_its_rows_is_a_config_error(campaign_dir, tmp_path):
    shutil.copy(campaign_dir / "results.sqlite", tmp_path / "results.sqlite")
    summary = json.loads((campaign_dir / "summary.json").read_text())
    summary["trials"] = 50
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(ConfigError, match="no complete results"):
        campaign_report(tmp_path)


def test_cli_writes_the_page_and_fails_without_traceback(campaign_dir, tmp_path):
    runner = CliRunner()
    target = tmp_path / "page" / "r.html"
    result = runner.invoke(app, ["report", str(campaign_dir), "--out", str(target)])
    assert result.exit_code == 0, result.output
    assert target.read_text().startswith("<!DOCTYPE html>")
    bad = runner.invoke(app, ["report", str(tmp_path / "nowhere")])
    assert bad.exit_code == 2
    assert "no campaign summary" in bad.output and "Traceback" not in bad.output


# --------------------------------------------------------------------------- a real browser
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _chromium(tmp_path, *args: str) -> subprocess.CompletedProcess:
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--hide-scrollbars",
        f"--user-data-dir={tmp_path / 'profile'}",
    ]
    cmd = [CHROMIUM, *flags, *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True)


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed")
def test_chromium_shows_the_tables_and_draws_the_figures(campaign_dir, tmp_path):
    import matplotlib.image as mpimg

    path = write_report(campaign_dir, tmp_path / "report.html")
    dom = _parse(_chromium(tmp_path, "--dump-dom", path.as_uri()).stdout)
    for caption in SUMMARY_TABLES:
        assert [c[0] for c, _ in dom.tables[caption][1:]] == SPECS
    assert len(dom.images) == 3
    shot = tmp_path / "shot.png"
    _chromium(tmp_path, "--window-size=1200,2600", f"--screenshot={shot}", path.as_uri())
    pixels = mpimg.imread(shot)[..., :3]
    assert pixels.shape[:2] == (2600, 1200)
    for name, rgb in FIGURE_COLOURS.items():
        painted = np.all(np.abs(pixels - np.array(rgb) / 255) < 0.03, axis=-1).sum()
        assert painted > 500, name  # bars and lines of both methods decoded and visible
