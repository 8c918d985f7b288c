"""`stella export-findings`: a campaign's failure modes as bug-report bundles."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys

import pytest

from conftest import ROOT

STELLA = (sys.executable, "-m", "harness.tools.cli")


@pytest.mark.slow
def test_each_failure_mode_becomes_a_bundle_whose_command_flies_the_violation_again(tmp_path):
    store = tmp_path / "c.db"
    # The store named relative to where the campaign ran; triage and export run from elsewhere.
    subprocess.run([*STELLA, "campaign", str(ROOT / "tests/data/scenarios/wall_range_off_baro_off.json"), "--algorithm", "RANDOM", "--evaluations", "3",
                    "--seed", "3", "--executor", "sequential", "--store", store.name], check=True, capture_output=True, cwd=tmp_path)
    triage = json.loads(subprocess.run([*STELLA, "triage", str(store), "--json"], check=True, capture_output=True, text=True).stdout)
    assert triage["modes"], "with its range sensor off, the UAV meets the wall in one of these candidates"
    out = tmp_path / "findings"
    exported = json.loads(subprocess.run([*STELLA, "export-findings", str(store), "--out", str(out), "--json"], check=True, capture_output=True,
                                         text=True).stdout)
    assert len(exported["findings"]) == len(triage["modes"])
    index = (out / "FINDINGS.md").read_text()
    for mode in triage["modes"]:
        assert mode["mode"] in index
    first = out / exported["findings"][0]
    assert {"FINDING.md", "concrete.json", "case.regression.json", "flight.mcap", "flight.png", "explanation.txt"} <= {p.name for p in first.iterdir()}
    assert json.loads((first / "explanation.json").read_text())["mechanism"] == triage["modes"][0]["mechanism"]
    assert (first / "flight.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    finding = (first / "FINDING.md").read_text()
    assert "git describe" in finding  # the bundled autopilot's tree is this checkout
    # The bundle's own command, run in its folder, flies the worst violation of the mode again.
    command = re.search(r"^(stella run --concrete .*)$", finding, re.MULTILINE).group(1)
    flown = subprocess.run([*STELLA, *shlex.split(command)[1:], "--out", str(tmp_path / "again"), "--json"], capture_output=True, text=True, cwd=first)
    assert flown.returncode == 0, flown.stderr[-2000:]
    assert json.loads(flown.stdout)["fitness"] == triage["modes"][0]["worst"]["fitness"] < 0
    # And its regression case fails while the violation is there.
    case = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts=", "case.regression.json"],
                          capture_output=True, text=True, cwd=first)
    assert case.returncode == 1, case.stdout[-2000:]
