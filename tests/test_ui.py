"""`stella ui`: the API's guards (path traversal, upload size, malformed uploads, the token) with
FastAPI's test client, and the page driven end to end in Debian's chromium with Playwright."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from conftest import ROOT
from harness.tools.ui.campaigns import MAX_UPLOAD_BYTES
from harness.tools.ui.server import create_app

CHROMIUM = "/usr/bin/chromium"
ARTIFACTS = Path(os.environ.get("STELLA_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "ui"
BROKEN = json.loads((ROOT / "scenarios" / "examples" / "fig4.json").read_text())
BROKEN["environment"]["weather"]["wind force"] = "gale"
WIND_ERROR = 'broken.json: /environment/weather/wind force: "gale" is not allowed; allowed values: '


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(tmp_path / "store")) as test_client:
        yield test_client


def launch_spec(**changes):
    return {"name": "c1", "scenarios": ["scenarios/examples/fig4.json"], "algorithms": ["RANDOM"], "evaluations": 2, "population": 2,
            "runs": 1, "seed": 0, "executor": "sequential", **changes}


def test_a_malformed_upload_gets_located_errors_and_nothing_is_kept(client, tmp_path):
    response = client.post("/api/scenarios", files={"file": ("broken.json", json.dumps(BROKEN).encode(), "application/json")})
    assert response.status_code == 422
    texts = [p["text"] for p in response.json()["problems"]]
    assert len(texts) == 1 and texts[0].startswith(WIND_ERROR), texts
    assert "uploads/broken.json" not in client.get("/api/setup").json()["scenarios"]
    response = client.post("/api/scenarios", files={"file": ("syntax.json", b"{\"name\": ", "application/json")})
    assert response.json()["problems"][0]["text"].startswith("syntax.json: /: invalid JSON at line 1")


def test_a_valid_upload_is_offered_and_can_be_launched(client):
    document = (ROOT / "scenarios" / "examples" / "fig4.json").read_bytes()
    response = client.post("/api/scenarios", files={"file": ("../../my scenario.json", document, "application/json")})
    assert response.json() == {"scenario": "uploads/my_scenario.json"}
    assert "uploads/my_scenario.json" in client.get("/api/setup").json()["scenarios"]


def test_oversized_uploads_are_refused(client):
    response = client.post("/api/scenarios", files={"file": ("big.json", b" " * (MAX_UPLOAD_BYTES + 1), "application/json")})
    assert response.status_code == 413


@pytest.mark.parametrize("choice", ["scenarios/../pyproject.toml", "scenarios/../../etc/passwd", "uploads/../../c1.json", "/etc/passwd",
                                    "scenarios//etc/passwd", "elsewhere/fig4.json"])
def test_scenario_paths_outside_scenarios_and_uploads_are_refused(client, choice):
    response = client.post("/api/campaigns", json=launch_spec(scenarios=[choice]))
    assert response.status_code == 422
    assert {p["file"] for p in response.json()["problems"]} == {"scenarios"}
    assert client.get("/api/campaigns").json() == []


@pytest.mark.parametrize("path", ["/static/..%2F..%2Fcli.py", "/static/index.html", "/api/campaigns/..%2F..%2Fetc/report.html",
                                  "/api/campaigns/nope/evaluations/1/log.mcap", "/api/campaigns/nope/evaluations/..%2F1/plot.png"])
def test_nothing_outside_the_store_directory_is_served(client, path):
    assert client.get(path).status_code in (404, 422)


def test_a_log_path_pointing_outside_the_store_directory_is_not_served(client, tmp_path):
    import sqlite3

    assert client.post("/api/campaigns", json=launch_spec()).status_code == 200
    campaigns = client.app.state.campaigns
    deadline = time.monotonic() + 120
    while campaigns.state("c1") == "running" and time.monotonic() < deadline:
        time.sleep(0.5)
    with sqlite3.connect(tmp_path / "store" / "c1.db") as db:
        db.execute("UPDATE evaluations SET log_path = '/etc/passwd'")
    details = client.get("/api/campaigns/c1").json()
    assert "Test Scenario #1 RANDOM run 0: best fitness" in details["console"]  # the campaign's own output, shown on the page
    [evaluation_id] = [e["id"] for e in details["evaluations"]][:1]
    assert client.get(f"/api/campaigns/c1/evaluations/{evaluation_id}/log.mcap").status_code == 404


def test_triage_of_an_unknown_campaign_is_not_found(client):
    assert client.get("/api/campaigns/nothing/triage").status_code == 404


def test_bad_setups_name_every_bad_field(client):
    response = client.post("/api/campaigns", json=launch_spec(name="../x", algorithms=["NXQ"], evaluations=0, scenarios=[]))
    files = sorted(p["file"] for p in response.json()["problems"])
    assert response.status_code == 422 and files == ["algorithms", "evaluations", "name", "scenarios"]


def test_beyond_loopback_the_token_is_needed(tmp_path):
    with TestClient(create_app(tmp_path, token="s3cret")) as client:
        assert client.get("/").status_code == 200  # the page itself, which asks for the token
        assert client.get("/api/setup").status_code == 401
        assert client.post("/api/login", json={"token": "wrong"}).status_code == 401
        assert client.post("/api/login", json={"token": "s3cret"}).status_code == 200
        assert client.get("/api/setup").status_code == 200


# -- the page in a real browser -------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def server(tmp_path):
    port = free_port()
    process = subprocess.Popen([sys.executable, "-m", "harness.tools.cli", "ui", "--store-dir", str(tmp_path / "store"), "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            break
        except OSError:
            time.sleep(0.1)
    yield f"http://127.0.0.1:{port}"
    process.terminate()
    process.wait(timeout=30)


@pytest.fixture
def page():
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (make test installs it)")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        context = browser.new_context(accept_downloads=True, viewport={"width": 1200, "height": 1600})
        yield context.new_page()
        browser.close()


@pytest.mark.slow
def test_set_up_launch_watch_and_browse_a_campaign_in_the_browser(server, page, tmp_path):
    errors = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(server)
    page.fill("#name", "browser")
    page.check("input[value='scenarios/examples/fig4.json']")
    page.fill("#algorithms", "RANDOM")
    page.fill("#evaluations", "8")
    page.fill("#population", "4")
    page.select_option("#executor", "local")
    page.fill("#workers", "2")
    page.screenshot(path=str(ARTIFACTS / "1-setup.png"), full_page=True)
    page.click("#launch")
    page.wait_for_selector("#campaign-state.running, #campaign-state.finished", timeout=30_000)
    page.screenshot(path=str(ARTIFACTS / "2-running.png"), full_page=True)
    page.wait_for_function("document.getElementById('overall-progress').textContent === '8/8 evaluations'", timeout=180_000)
    page.wait_for_selector("#campaign-state.finished", timeout=30_000)
    assert page.locator("#chart circle.point").count() == 8
    assert page.locator("#progress-table td.done").inner_text() == "8/8"
    page.screenshot(path=str(ARTIFACTS / "3-finished.png"), full_page=True)
    page.wait_for_selector("a.open-evaluation")
    page.locator("a.open-evaluation").first.click()
    page.wait_for_function("document.getElementById('plot').complete && document.getElementById('plot').naturalWidth > 0", timeout=60_000)
    page.screenshot(path=str(ARTIFACTS / "4-evaluation.png"), full_page=True)
    # The violations triaged on the page: every violation in a mode, its worst example opens like an evaluation.
    violations = page.locator("#evaluations tr.violation").count()
    assert violations >= 1  # seed 0's eight samples of Fig. 4 hold a contact with the sphere
    page.click("#triage-button")
    page.wait_for_selector("#modes tr.mode")
    assert sum(int(cell) for cell in page.locator("#modes td.count").all_inner_texts()) == violations
    assert page.locator("#triage-summary").inner_text().startswith(f"{violations} distinct violations in ")
    page.locator("a.open-worst").first.click()
    page.wait_for_function("document.getElementById('evaluation-title').textContent.includes('violation')")
    page.wait_for_function("document.getElementById('plot').complete && document.getElementById('plot').naturalWidth > 0", timeout=60_000)
    page.screenshot(path=str(ARTIFACTS / "5-failure-modes.png"), full_page=True)
    with page.expect_download() as download:
        page.click("#mcap-link")
    saved = tmp_path / "downloaded.mcap"
    download.value.save_as(saved)
    from mcap.reader import make_reader

    with open(saved, "rb") as stream:
        assert stream.read(8) == b"\x89MCAP0\r\n"
        stream.seek(0)
        assert make_reader(stream).get_summary().statistics.message_count > 1000
    assert errors == []


@pytest.mark.slow
def test_a_malformed_upload_in_the_browser_shows_the_located_error_and_launches_nothing(server, page, tmp_path):
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(BROKEN))
    page.goto(server)
    page.set_input_files("#upload", str(broken))
    page.wait_for_selector("#upload-problems li")
    assert page.locator("#upload-problems").inner_text().startswith(WIND_ERROR)
    page.screenshot(path=str(ARTIFACTS / "6-malformed-upload.png"), full_page=True)
    page.fill("#name", "nothing")
    page.click("#launch")
    page.wait_for_selector("#launch-problems li")
    assert "choose at least one logical scenario" in page.locator("#launch-problems").inner_text()
    assert page.locator("#campaign-list li").count() == 0


@pytest.mark.slow
def sigint_pending(pid: int) -> bool:
    """Whether pid has a SIGINT waiting; True too once pid is gone, as there is nothing left to gate."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return True
    pending = int(next(line.split()[1] for line in status.splitlines() if line.startswith("ShdPnd:")), 16)
    return bool(pending & (1 << (signal.SIGINT - 1)))


def test_cancel_is_ctrl_c_and_resume_finishes_the_campaign_without_repeating_anything(client, tmp_path):
    import sqlite3

    assert client.post("/api/campaigns", json=launch_spec(evaluations=6, population=3)).status_code == 200
    campaigns = client.app.state.campaigns
    group = campaigns._processes["c1"].pid
    deadline = time.monotonic() + 120
    while campaigns.progress("c1")["done"] < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    # A gate instead of a race with the machine's speed: the campaign is frozen from here until its
    # cancel is pending, so it cannot finish first (five more flights in one 50 ms poll cannot be).
    os.killpg(group, signal.SIGSTOP)
    frozen_at = campaigns.progress("c1")["done"]
    assert 1 <= frozen_at < 6
    cancel = threading.Thread(target=lambda: replies.append(client.post("/api/campaigns/c1/cancel").json()))
    replies: list = []
    cancel.start()
    while not sigint_pending(group) and cancel.is_alive():
        time.sleep(0.01)
    try:
        os.killpg(group, signal.SIGCONT)
    except ProcessLookupError:
        pass
    cancel.join(timeout=90)
    assert replies == [{"state": "stopped"}]
    # Stopped by its own Ctrl-C handling (exit 130), not killed after the cancel's grace period,
    # also where the page was started with SIGINT ignored (the background of a script).
    assert campaigns._processes["c1"].returncode == 130
    stopped_at = campaigns.progress("c1")["done"]
    assert frozen_at <= stopped_at < 6
    assert client.post("/api/campaigns/c1/resume").json() == {"state": "running"}
    while campaigns.state("c1") == "running" and time.monotonic() < deadline + 120:
        time.sleep(0.5)
    assert campaigns.state("c1") == "finished"
    with sqlite3.connect(tmp_path / "store" / "c1.db") as db:
        ordinals = [row[0] for row in db.execute("SELECT ordinal FROM evaluations ORDER BY ordinal")]
    assert ordinals == list(range(6))
