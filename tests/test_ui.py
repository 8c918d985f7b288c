"""`stella ui`: the API's guards (path traversal, upload size, malformed uploads, the token, other
sites' pages), the SUT's choices checked as the CLI checks them, campaigns that outlive the
request's thread but not the server, with FastAPI's test client; and the page driven end to end
in Debian's chromium with Playwright (against PX4 too where STELLA_PX4_BIN is set)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from conftest import ROOT, alive, children, wait_until_flying
from harness.campaigns.store import Store
from harness.flight import logs
from harness.tools.cli import main
from harness.tools.ui.campaigns import Campaigns
from harness.tools.ui.server import create_app
from harness.tools.ui.uploads import MAX_UPLOAD_BYTES

CHROMIUM = "/usr/bin/chromium"
ARTIFACTS = Path(os.environ.get("STELLA_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "ui"
BROKEN = json.loads((ROOT / "scenarios" / "examples" / "fig4.json").read_text())
BROKEN["environment"]["weather"]["wind force"] = "gale"
WIND_ERROR = 'broken.json: /environment/weather/wind force: "gale" is not allowed; allowed values: '


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(tmp_path / "store"), base_url="http://127.0.0.1:8765") as test_client:
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
    assert response.json()["problems"][0]["text"].startswith("syntax.json: invalid JSON at line 1")


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
                                  "/api/campaigns/nope/evaluations/1/log.mcap", "/api/campaigns/nope/evaluations/..%2F1/plot.png",
                                  "/api/campaigns/nope/evaluations/1/explain"])
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
    assert client.get(f"/api/campaigns/c1/evaluations/{evaluation_id}/explain").status_code == 404


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


def test_other_sites_pages_cannot_drive_the_page(client):
    """The page starts commands (a command SUT): a page of another site open in the same browser
    must not launch one, by a cross-site request or by its own name resolving to loopback."""
    assert client.post("/api/campaigns", json=launch_spec(), headers={"Origin": "http://evil.example"}).status_code == 403
    assert client.get("/api/setup", headers={"Host": "evil.example:8765"}).status_code == 403
    assert client.post("/api/campaigns", json=launch_spec(), headers={"Origin": "http://127.0.0.1:8765"}).status_code == 200
    assert client.post("/api/campaigns/c1/cancel").status_code == 200


# -- the SUT's choices, checked as the command line checks them -------------------------------------


def test_the_setup_offers_what_the_command_line_offers(client):
    setup = client.get("/api/setup").json()
    assert {"bundled", "px4", "command"} <= set(setup["suts"])
    assert setup["drives"] == ["mission", "pilot"] and setup["holds"] == ["frozen", "paced"]
    assert {"lidar_360", "four_rangefinders", "depth_camera"} <= set(setup["rigs"])
    assert "cp_ignores_delay" in [fault["name"] for fault in setup["faults"]]
    assert setup["plans"] == ["scenarios/examples/two_altitudes.plan"] and setup["params_files"] == []


def cli_refusal(tmp_path, capsys, options: list[str]) -> str:
    """What `stella campaign` says when it refuses these options on Fig. 4."""
    capsys.readouterr()
    assert main(["campaign", str(ROOT / "scenarios/examples/fig4.json"), "--algorithm", "RANDOM", "--evaluations", "2",
                 "--store", str(tmp_path / "cli.db"), *options]) == 2
    return capsys.readouterr().err.strip()


@pytest.mark.parametrize("changes, options, field", [
    ({"sut": "betaflight"}, ["--sut", "betaflight"], "sut"),
    ({"sut": "ardupilot", "ardupilot_bin": "/nonexistent/arducopter"}, ["--sut", "ardupilot", "--ardupilot-bin", "/nonexistent/arducopter"], "sut"),
    ({"sut": "px4", "px4_bin": "/nonexistent/px4"}, ["--sut", "px4", "--px4-bin", "/nonexistent/px4"], "sut"),
    ({"sut": "command", "sut_command": "my_autopilot --id {instance}"}, ["--sut", "command", "--sut-command", "my_autopilot --id {instance}"], "sut"),
    ({"sut": "px4", "sut_fault": "cp_ignores_delay"}, ["--sut", "px4", "--sut-fault", "cp_ignores_delay"], "sut_fault"),
    ({"sut_params": ["CP_DIST=near"]}, ["--sut-param", "CP_DIST=near"], "sut_params"),
    ({"sut_params": ["CP_DISTANCE=2"]}, ["--sut-param", "CP_DISTANCE=2"], "sut_params"),
    ({"sut_params": ["CP_DIST=99"]}, ["--sut-param", "CP_DIST=99"], "sut_params"),
    ({"rig": "sonar_ring"}, ["--rig", "sonar_ring"], "rig"),
])
def test_a_sut_the_command_line_refuses_is_refused_on_its_field_with_the_same_message(client, tmp_path, capsys, changes, options, field):
    response = client.post("/api/campaigns", json=launch_spec(**changes))
    assert response.status_code == 422
    [problem] = response.json()["problems"]
    assert (problem["field"], problem["text"]) == (field, cli_refusal(tmp_path, capsys, options))
    assert client.get("/api/campaigns").json() == []


@pytest.mark.parametrize("changes, field, text", [
    ({"drive": "teleport"}, "drive", "--drive: invalid choice: 'teleport' (choose from 'mission', 'pilot')"),
    ({"executor": "cloud"}, "executor", "--executor: invalid choice: 'cloud' (choose from 'sequential', 'local', 'dask', 'docker')"),
    ({"sut": "command", "sut_command": "a {sim_port} {api_port}", "sut_hold": "sleepy"}, "sut_hold",
     "--sut-hold: invalid choice: 'sleepy' (choose from 'paced', 'frozen')"),
    ({"mission_plan": "scenarios/../pyproject.toml"}, "mission_plan",
     "--mission-plan: scenarios/../pyproject.toml is not a QGroundControl plan of scenarios/ or an upload: upload it first"),
    ({"sut_params_file": "scenarios/examples/fig4.json"}, "sut_params_file",
     "--sut-params-file: scenarios/examples/fig4.json is not a parameter file of scenarios/ or an upload: upload it first"),
    ({"sut_params": "CP_DIST=2"}, "sut_params", "--sut-param: give a list of NAME=VALUE texts"),
    ({"sut": "px4", "px4_bin": 7}, "px4_bin", "--px4-bin: give text, not 7"),
])
def test_bad_choices_are_refused_on_their_field(client, changes, field, text):
    response = client.post("/api/campaigns", json=launch_spec(**changes))
    assert response.status_code == 422
    assert [(p["field"], p["text"]) for p in response.json()["problems"]] == [(field, text)]


def upload(client, route: str, name: str, data: bytes):
    return client.post(route, files={"file": (name, data, "application/octet-stream")})


def test_plan_and_parameter_file_uploads_are_checked_before_they_are_kept_and_offered(client):
    plan = (ROOT / "scenarios/examples/two_altitudes.plan").read_bytes()
    assert upload(client, "/api/plans", "../my plan.plan", plan).json() == {"plan": "uploads/my_plan.plan"}
    broken = upload(client, "/api/plans", "broken.plan", json.dumps({**json.loads(plan), "fileType": "Mission"}).encode())
    assert broken.status_code == 422
    assert [p["text"] for p in broken.json()["problems"]] == ['broken.plan: /fileType: not a QGroundControl plan: expected "fileType": "Plan"']
    assert upload(client, "/api/params-files", "qgc.params", b"# exported\n1\t1\tCP_DIST\t2.5\t9\n").json() == {"params": "uploads/qgc.params"}
    broken = upload(client, "/api/params-files", "bad.csv", b"CP_DIST,near\n")
    assert broken.status_code == 422
    assert [p["text"] for p in broken.json()["problems"]] == ["bad.csv: line 1: not a finite number of the right type (could not convert string to float: 'near')"]
    assert upload(client, "/api/params-files", "big.params", b"#" * (MAX_UPLOAD_BYTES + 1)).status_code == 413
    setup = client.get("/api/setup").json()
    assert setup["plans"] == ["scenarios/examples/two_altitudes.plan", "uploads/my_plan.plan"] and setup["params_files"] == ["uploads/qgc.params"]


def test_a_parameter_file_the_sut_refuses_is_refused_on_its_field_as_the_command_line_refuses_it(client, tmp_path, capsys):
    text = b"CP_DIST,2.0\nCP_DISTANCE,2.0\n"  # a sound file: whether its names exist is the SUT's to say
    assert upload(client, "/api/params-files", "typo.csv", text).json() == {"params": "uploads/typo.csv"}
    response = client.post("/api/campaigns", json=launch_spec(sut_params_file="uploads/typo.csv", sut_params=["CP_DELAY=0.1"]))
    (tmp_path / "typo.csv").write_bytes(text)
    expected = cli_refusal(tmp_path, capsys, ["--sut-params-file", str(tmp_path / "typo.csv"), "--sut-param", "CP_DELAY=0.1"])
    assert expected.startswith("--sut-params-file: bundled: unknown parameter 'CP_DISTANCE'")
    assert [(p["field"], p["text"]) for p in response.json()["problems"]] == [("sut_params_file", expected)]


QGC_PARAMS = b"# QGroundControl's export\n1\t1\tCP_DIST\t1.5\t9\n1\t1\tMPC_XY_CRUISE\t4\t9\n"


# -- campaigns outlive the request's thread, not the server -----------------------------------------


@pytest.mark.slow
def test_a_campaign_outlives_the_server_thread_that_launched_it(tmp_path):
    """Linux sends PR_SET_PDEATHSIG's signal when the thread that forked the child ends: a campaign
    launched on a request thread that the server's pool then retires must run on to its end."""
    campaigns = Campaigns(tmp_path / "store")
    try:
        request = threading.Thread(target=campaigns.launch, args=(launch_spec(),))
        request.start()
        request.join()
        assert campaigns._processes["c1"].wait(timeout=300) == 0
        assert campaigns.state("c1") == "finished"
    finally:
        campaigns.close()


def family(pid: int) -> list[int]:
    """pid and every process it started, and they started."""
    found, pending = [], [pid]
    while pending:
        found.append(pending.pop())
        pending += children(found[-1])
    return found


@pytest.mark.slow
def test_a_killed_server_takes_its_campaigns_down(tmp_path):
    import httpx

    with ui_server(tmp_path / "store") as (url, server_process):
        assert httpx.post(f"{url}/api/campaigns", json=launch_spec(evaluations=500)).status_code == 200
        [campaign] = children(server_process.pid)
        wait_until_flying(campaign)
        processes = family(campaign)
        server_process.kill()
        deadline = time.monotonic() + 30
        while any(alive(pid) for pid in processes) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [pid for pid in processes if alive(pid)]


# -- the page in a real browser -------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@contextmanager
def ui_server(store_dir: Path):
    """`stella ui` in a process of its own: (its address, the process)."""
    port = free_port()
    process = subprocess.Popen([sys.executable, "-m", "harness.tools.cli", "ui", "--store-dir", str(store_dir), "--port", str(port)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            break
        except OSError:
            time.sleep(0.1)
    try:
        yield f"http://127.0.0.1:{port}", process
    finally:
        process.terminate()
        process.wait(timeout=90)


@pytest.fixture
def server(tmp_path):
    with ui_server(tmp_path / "store") as (url, _process):
        yield url


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
    page.fill("#seed", "7")
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
    assert violations >= 1  # seed 7's eight samples of Fig. 4 hold a violation
    page.click("#triage-button")
    page.wait_for_selector("#modes tr.mode")
    assert sum(int(cell) for cell in page.locator("#modes td.count").all_inner_texts()) == violations
    assert page.locator("#triage-summary").inner_text().startswith(f"{violations} distinct violations in ")
    page.locator("a.open-worst").first.click()
    page.wait_for_function("document.getElementById('evaluation-title').textContent.includes('violation')")
    page.wait_for_function("document.getElementById('plot').complete && document.getElementById('plot').naturalWidth > 0", timeout=60_000)
    # Its explanation, read from its log: the mechanism that is also the mode's first column.
    page.wait_for_function("document.getElementById('explanation').textContent.includes('mechanism: ')", timeout=60_000)
    assert f"mechanism: {page.locator('#modes tr.mode td').nth(1).inner_text()}" in page.locator("#explanation").inner_text()
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


def sigint_pending(pid: int) -> bool:
    """Whether pid has a SIGINT waiting; True too once pid is gone, as there is nothing left to gate."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return True
    pending = int(next(line.split()[1] for line in status.splitlines() if line.startswith("ShdPnd:")), 16)
    return bool(pending & (1 << (signal.SIGINT - 1)))


@pytest.mark.slow
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
    # Seen once in CI: "finished" (the cause unknown; not reproduced in 9 runs here, 5 of them under load).
    assert replies == [{"state": "stopped"}], (frozen_at, campaigns.progress("c1")["done"], campaigns._processes["c1"].returncode, campaigns.console_tail("c1"))
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


def set_up_small_campaign(page, name: str, scenario: str) -> None:
    page.fill("#name", name)
    page.check(f"input[value='{scenario}']")
    page.fill("#algorithms", "RANDOM")
    page.fill("#evaluations", "2")
    page.fill("#population", "2")


def upload_params_file(page, path: Path) -> None:
    page.set_input_files("#params-upload", str(path))
    page.wait_for_function(f"document.getElementById('sut-params-file').value === 'uploads/{path.name}'")


@pytest.mark.slow
def test_the_sut_choices_in_the_browser_refuse_a_bad_parameter_and_launch_with_a_fault_a_parameter_file_and_the_pilot_drive(server, page, tmp_path):
    errors = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    params = tmp_path / "cp.params"
    params.write_bytes(QGC_PARAMS)
    page.goto(server)
    set_up_small_campaign(page, "faulty", "scenarios/examples/fig4.json")
    page.fill("#seed", "8")  # both of its candidates feasible: each is flown
    page.select_option("#executor", "sequential")
    page.select_option("#sut", "px4")  # each SUT shows its own options only
    assert page.is_visible("#px4-bin") and not page.is_visible("#sut-fault") and not page.is_visible("#sut-command")
    page.select_option("#sut", "ardupilot")
    assert page.is_visible("#ardupilot-bin") and not page.is_visible("#px4-bin")
    page.select_option("#sut", "bundled")
    assert page.is_visible("#sut-fault") and not page.is_visible("#px4-bin")
    page.select_option("#sut-fault", "cp_ignores_delay")
    page.select_option("#drive", "pilot")
    upload_params_file(page, params)
    page.fill("#sut-params", "CP_DELAY=0.2\nCP_DISTANCE=2")
    page.click("#launch")
    page.wait_for_selector("#launch-problems li")
    assert page.locator("#launch-problems").inner_text() == ("--sut-param: bundled: unknown parameter 'CP_DISTANCE' "
                                                             "(`python -m autopilot.params` lists its parameters)")
    assert page.locator("#sut-params.invalid").count() == 1 and page.locator("#campaign-list li").count() == 0
    page.screenshot(path=str(ARTIFACTS / "7-sut-refused.png"), full_page=True)
    page.fill("#sut-params", "CP_DELAY=0.2")
    page.click("#launch")
    page.wait_for_selector("#campaign-state.finished", timeout=300_000)
    assert page.locator("#sut-params.invalid").count() == 0
    command = page.locator("#command").text_content()
    assert "--sut-fault=cp_ignores_delay --drive=pilot --sut-params-file=" in command and command.endswith(" --sut-param=CP_DELAY=0.2")
    page.screenshot(path=str(ARTIFACTS / "8-sut-campaign.png"), full_page=True)
    flown = {"name": "bundled", "params": {"CP_DIST": 1.5, "MPC_XY_CRUISE": 4.0, "CP_DELAY": 0.2}, "fault": "cp_ignores_delay"}
    with Store(tmp_path / "store" / "faulty.db") as store:
        assert store.campaign_sut() == flown
        assert json.loads(store.db.execute("SELECT config FROM campaigns").fetchone()[0])["drive"] == "pilot"
        flights = store.db.execute("SELECT log_path, concrete FROM evaluations").fetchall()
    assert len(flights) == 2
    for log_path, concrete in flights:  # what each flight's log says it flew
        assert logs.json_metadata(Path(log_path), "sut") == flown
        assert json.loads(concrete)["logical_scenario"]["mission"]["drive"] == "pilot"
    assert errors == []


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("STELLA_PX4_BIN"), reason="STELLA_PX4_BIN is not set: no PX4 SITL build to fly against")
def test_the_page_launches_a_px4_pilot_drive_campaign_with_a_parameter_file(server, page, tmp_path):
    params = tmp_path / "px4.params"
    params.write_bytes(b"# QGroundControl's export\n1\t1\tCP_DIST\t1.5\t9\n1\t1\tMPC_XY_CRUISE\t3\t9\n")
    page.goto(server)
    set_up_small_campaign(page, "px4", "scenarios/table3/scenario_05.json")
    page.select_option("#executor", "local")
    page.fill("#workers", "2")
    page.select_option("#sut", "px4")
    page.fill("#px4-bin", os.environ["STELLA_PX4_BIN"])
    page.select_option("#drive", "pilot")
    upload_params_file(page, params)
    page.screenshot(path=str(ARTIFACTS / "9-px4-setup.png"), full_page=True)
    page.click("#launch")
    page.wait_for_selector("#campaign-state.finished", timeout=600_000)
    page.screenshot(path=str(ARTIFACTS / "10-px4-finished.png"), full_page=True)
    flown = {"name": "px4", "params": {"CP_DIST": 1.5, "MPC_XY_CRUISE": 3.0}}
    with Store(tmp_path / "store" / "px4.db") as store:
        assert store.campaign_sut() == flown
        assert json.loads(store.db.execute("SELECT config FROM campaigns").fetchone()[0])["drive"] == "pilot"
        flights = store.db.execute("SELECT status, why, log_path FROM evaluations").fetchall()
    assert len(flights) == 2
    for status, why, log_path in flights:
        assert status in ("ok", "violation", "mission_failed"), why
        assert logs.json_metadata(Path(log_path), "sut") == flown
