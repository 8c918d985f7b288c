"""The campaign report opens in a real headless browser without console errors and shows its plots."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import pytest

from conftest import ROOT

pytestmark = pytest.mark.slow
CHROMIUM = shutil.which("chromium")


def test_the_report_loads_in_chromium_and_every_plot_is_shown(tmp_path):
    assert CHROMIUM, "Debian's chromium is needed; `make test` installs it"
    store = tmp_path / "c.db"
    campaign = [sys.executable, "-m", "harness.tools.cli", "campaign", str(ROOT / "tests" / "data" / "scenarios" / "one_dynamic_sphere.json"),
                "--algorithm", "NSGAII", "--algorithm", "RANDOM", "--evaluations", "3", "--population", "2", "--executor", "sequential", "--store", str(store), "--json"]
    subprocess.run(campaign, cwd=ROOT, check=True, capture_output=True, timeout=300)
    report = tmp_path / "report.html"
    subprocess.run([sys.executable, "-m", "harness.tools.cli", "report", str(store), "--out", str(report), "--worst", "2"], cwd=ROOT, check=True, timeout=120)
    browser = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0",
         "--virtual-time-budget=5000", "--dump-dom", report.as_uri()],
        capture_output=True, text=True, timeout=120,
    )
    dom = browser.stdout
    shown = re.search(r'data-plots-shown="(\d+)"', dom)
    total = re.search(r'data-plots="(\d+)"', dom)
    assert shown and total, "the page's load handler did not run"
    assert int(total.group(1)) == 3  # one convergence plot and two worst-case top views
    assert shown.group(1) == total.group(1)
    console = [line for line in browser.stderr.splitlines() if "CONSOLE" in line or "Uncaught" in line]
    assert console == []
    assert "Table III" not in dom and "one dynamic sphere" in dom
