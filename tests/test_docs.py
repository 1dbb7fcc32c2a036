"""The documentation site builds without a warning and its doctests pass (issue 30).

``sphinx-build -W --keep-going -b html`` (strict: any warning fails) into a temporary
folder, then the doctest builder. No network is needed: intersphinx is not used and
mathjax is rendered by the reader's browser. The gallery examples are small (the
100,000-agent one runs only with ``NETSIM_DOCS_FULL=1``); the doctest build skips the
gallery (``-D plot_gallery=0``), which the html build has executed.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

pytest.importorskip("sphinx")
pytest.importorskip("numpydoc")
pytest.importorskip("sphinx_gallery")


def _sphinx(builder: str, out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("NETSIM_DOCS_FULL", None)
    cmd = [sys.executable, "-m", "sphinx", "-b", builder, "-q", "-d", str(out / ".doctrees"),
           *extra, str(DOCS), str(out / builder)]
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=900)


def test_the_site_builds_without_warnings_and_its_doctests_pass(tmp_path):
    html = _sphinx("html", tmp_path, "-W", "--keep-going")
    assert html.returncode == 0, html.stdout[-3000:] + html.stderr[-5000:]
    assert "WARNING" not in html.stderr and "ERROR" not in html.stderr, html.stderr[-5000:]
    for page in ("index", "getting-started", "cli", "scenarios", "api", "findings",
                 "concepts/architecture", "estimators/compensated", "install", "notebook",
                 "live", "auto_examples/plot_delay_sweep", "auto_examples/plot_notebook",
                 "auto_examples/plot_estimator_listing", "estimators/baselines", "calibrate",
                 "auto_examples/plot_baselines", "time",
                 "auto_examples/plot_clocks_and_triggers"):
        assert (tmp_path / "html" / f"{page}.html").is_file(), page
    notebook = (tmp_path / "html" / "auto_examples" / "plot_notebook.html").read_text(
        encoding="utf-8")
    assert "<b>RunResult</b>" in notebook  # the executed example shows _repr_html_
    cli = (tmp_path / "html" / "cli.html").read_text(encoding="utf-8")
    assert "cmdoption-netsim-run-steps" in cli  # generated from the parser
    assert "cmdoption-netsim-calibrate-evaluations" in cli  # netsim calibrate is picked up
    doctest = _sphinx("doctest", tmp_path, "-D", "plot_gallery=0")
    assert doctest.returncode == 0, doctest.stdout[-5000:] + doctest.stderr[-3000:]
    assert "0 failures in tests" in (tmp_path / "doctest" / "output.txt").read_text()
