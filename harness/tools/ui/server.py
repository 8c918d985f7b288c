"""`stella ui`: a web page to set up, launch, watch and browse campaigns (FastAPI + uvicorn).

Everything the page reaches is either under the store directory (stores, logs, plots, reports,
uploads) or a file under scenarios/; files are only ever found from a campaign name, an
evaluation id or a choice the page offered, never from a path the browser sends. The page starts
whatever `stella campaign` can (a command SUT, a px4 binary given by its path), so whoever reaches
it can run commands as the user who started it. It refuses requests from other sites' pages;
without a token it answers at a loopback address only; bound to anything but loopback, every
request needs the token (`--token`, or one made up and printed at start), which the page asks
for once and keeps in a cookie. On a machine shared with others, give a --token on loopback too.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import os
import secrets
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from fastapi import APIRouter, Depends, FastAPI, File, HTTPException, Request, UploadFile
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse

from harness.errors import InputError
from harness.execution import registry as executors
from harness.scenario.logical import DRIVES
from harness.scenario.rig import preset_names
from harness.tools.ui.campaigns import Campaigns, SetupError
from harness.tools.ui.uploads import MAX_UPLOAD_BYTES

STATIC = Path(__file__).resolve().parent / "static"
COOKIE = "stella_token"


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def problems_json(error: InputError) -> list[dict[str, str]]:
    fields = error.fields if isinstance(error, SetupError) else ("",) * len(error.problems)
    return [p.__dict__ | {"text": str(p), "field": field} for field, p in zip(fields, error.problems)]


def setup_choices(campaigns: Campaigns) -> dict[str, Any]:
    """What the set-up form offers: files, and the choices of `stella campaign`'s options."""
    import sut_adapter
    from sut_adapter.base import HOLD_MODES
    from sut_adapter.bundled import seeded_faults

    return {"scenarios": campaigns.uploads.choices("scenario"), "plans": campaigns.uploads.choices("plan"),
            "params_files": campaigns.uploads.choices("params"), "profiles": ["default"],
            "executors": sorted(executors.names(), key=lambda name: name != "local"),  # the form's first is its default
            "suts": sut_adapter.names(), "drives": list(DRIVES), "holds": list(HOLD_MODES), "rigs": preset_names(),
            "faults": [{"name": f.name, "breaks": f.breaks} for f in seeded_faults().values()],
            "px4_bin_default": os.environ.get("STELLA_PX4_BIN"), "ardupilot_bin_default": os.environ.get("STELLA_ARDUPILOT_BIN"),
            "max_upload_bytes": MAX_UPLOAD_BYTES}


def create_app(store_dir: Path, token: str | None = None) -> FastAPI:
    campaigns = Campaigns(store_dir)

    @asynccontextmanager
    async def lifespan(_app: FastAPI):
        yield
        await asyncio.to_thread(campaigns.close)  # as Ctrl-C would: stores keep what finished

    app = FastAPI(title="stella", docs_url=None, redoc_url=None, openapi_url=None, lifespan=lifespan)
    app.state.campaigns = campaigns
    app.state.token = token
    # Starlette runs the middleware added last first: the token check, then the site check.
    app.middleware("http")(same_site_only)
    app.middleware("http")(require_token)
    for router in (page, setup, campaign_routes, evaluation_routes):
        app.include_router(router)
    return app


# -- who may ask ---------------------------------------------------------------------------------


async def same_site_only(request: Request, call_next):
    """The page starts commands (a command SUT, a px4 binary): another site's page open in the
    same browser must not drive it, neither by a cross-site request nor by a host name of its own
    that resolves to this address (DNS rebinding)."""
    host = request.headers.get("host", "")
    origin = request.headers.get("origin")
    if request.method not in ("GET", "HEAD") and origin is not None and urlsplit(origin).netloc != host:
        return JSONResponse({"detail": f"refused: a request from a page of {origin}"}, status_code=403)
    if request.app.state.token is None and not is_loopback(urlsplit(f"//{host}").hostname or ""):
        return JSONResponse({"detail": f"refused: this server answers at a loopback address only, not at {host}; "
                                       "beyond loopback, start it with --host and a --token"}, status_code=403)
    return await call_next(request)


async def require_token(request: Request, call_next):
    token = request.app.state.token
    open_paths = ("/", "/static/app.js", "/static/style.css", "/api/login")
    if token is None or request.url.path in open_paths:
        return await call_next(request)
    given = request.cookies.get(COOKIE) or request.headers.get("x-stella-token") or ""
    if not hmac.compare_digest(given, token):
        return JSONResponse({"detail": "this server needs its token: enter it on the page"}, status_code=401)
    return await call_next(request)


def campaigns_of(request: Request) -> Campaigns:
    return request.app.state.campaigns


def known(name: str, campaigns: Campaigns = Depends(campaigns_of)) -> str:
    """A campaign's name from the path, if there is such a campaign."""
    if not campaigns.exists(name):
        raise HTTPException(404, f"no campaign {name!r}")
    return name


# -- the page --------------------------------------------------------------------------------------

page = APIRouter()


@page.get("/", response_class=HTMLResponse)
def index() -> str:
    return (STATIC / "index.html").read_text()


@page.get("/static/{name}")
def static(name: str) -> FileResponse:
    if name not in ("app.js", "style.css"):
        raise HTTPException(404)
    return FileResponse(STATIC / name, media_type="text/javascript" if name.endswith(".js") else "text/css")


@page.post("/api/login")
async def login(request: Request) -> Response:
    token = request.app.state.token
    given = (await request.json()).get("token", "")
    if token is not None and not hmac.compare_digest(str(given), token):
        raise HTTPException(401, "wrong token")
    response = JSONResponse({"ok": True})
    response.set_cookie(COOKIE, str(given), httponly=True, samesite="strict")
    return response


# -- setting a campaign up -------------------------------------------------------------------------

setup = APIRouter()


@setup.get("/api/setup")
def choices(campaigns: Campaigns = Depends(campaigns_of)) -> dict[str, Any]:
    return setup_choices(campaigns)


async def _upload(kind: str, file: UploadFile, campaigns: Campaigns) -> JSONResponse:
    data = await file.read(MAX_UPLOAD_BYTES + 1)
    if len(data) > MAX_UPLOAD_BYTES:
        raise HTTPException(413, f"{file.filename} is larger than {MAX_UPLOAD_BYTES // 1024} KiB")
    choice, problems = await asyncio.to_thread(campaigns.uploads.add, kind, file.filename or kind, data)
    if problems:
        return JSONResponse({"problems": problems_json(InputError(problems))}, status_code=422)
    return JSONResponse({kind: choice})


@setup.post("/api/scenarios")
async def upload_scenario(file: UploadFile = File(...), campaigns: Campaigns = Depends(campaigns_of)) -> JSONResponse:
    return await _upload("scenario", file, campaigns)


@setup.post("/api/plans")
async def upload_plan(file: UploadFile = File(...), campaigns: Campaigns = Depends(campaigns_of)) -> JSONResponse:
    return await _upload("plan", file, campaigns)


@setup.post("/api/params-files")
async def upload_params(file: UploadFile = File(...), campaigns: Campaigns = Depends(campaigns_of)) -> JSONResponse:
    return await _upload("params", file, campaigns)


@setup.post("/api/campaigns")
async def launch(request: Request, campaigns: Campaigns = Depends(campaigns_of)) -> JSONResponse:
    try:
        name = await asyncio.to_thread(campaigns.launch, await request.json())
    except InputError as error:
        return JSONResponse({"problems": problems_json(error)}, status_code=422)
    return JSONResponse({"name": name})


# -- campaigns: their state, progress and results ----------------------------------------------

campaign_routes = APIRouter()


@campaign_routes.get("/api/campaigns")
def listing(campaigns: Campaigns = Depends(campaigns_of)) -> list[dict[str, Any]]:
    return [{"name": n, "state": campaigns.state(n), **{k: v for k, v in campaigns.progress(n).items() if k in ("done", "total")}} for n in campaigns.names()]


@campaign_routes.post("/api/campaigns/{name}/cancel")
async def cancel(name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> dict[str, str]:
    await asyncio.to_thread(campaigns.cancel, name)
    return {"state": campaigns.state(name)}


@campaign_routes.post("/api/campaigns/{name}/resume")
def resume(name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> dict[str, str]:
    campaigns.resume(name)
    return {"state": campaigns.state(name)}


@campaign_routes.get("/api/campaigns/{name}/events")
async def events(name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> StreamingResponse:
    async def stream():
        last = None
        while True:
            progress = await asyncio.to_thread(campaigns.progress, name)
            state = campaigns.state(name)
            message = json.dumps({**progress, "state": state})
            if message != last:
                yield f"data: {message}\n\n"
                last = message
            if state != "running":
                return
            await asyncio.sleep(0.5)

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})


def _baseline(campaigns: Campaigns, name: str) -> str:
    """The campaign's first algorithm, which the others are compared with."""
    return next(iter(json.loads((campaigns.store_dir / f"{name}.json").read_text())["algorithms"]))


@campaign_routes.get("/api/campaigns/{name}")
def details(name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> dict[str, Any]:
    from harness.campaigns.statistics import compare

    store = campaigns.store(name)
    console = campaigns.console_tail(name)
    command = campaigns.command_text(name)
    if store is None:
        return {"name": name, "comparison": None, "evaluations": [], "console": console, "command": command}
    with store:
        comparison = compare(store, _baseline(campaigns, name))
        lowest = store.lowest(200)
    return {"name": name, "comparison": comparison, "console": console, "command": command,
            "evaluations": [{"id": e.id, "scenario": e.scenario, "algorithm": e.algorithm, "run": e.run_index,
                             "status": str(e.status), "fitness": e.fitness, "min_clearance_m": e.min_clearance_m, "concrete": e.concrete,
                             "has_log": e.log_path is not None} for e in lowest]}


@campaign_routes.get("/api/campaigns/{name}/triage")
def triage(name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> dict[str, Any]:
    """The campaign's violations in failure modes; each example as the evaluations table has it,
    so the page opens it like any evaluation. Read from every violation's log: on demand."""
    from harness.campaigns.triage import triage as group

    store = campaigns.store(name)
    if store is None:
        raise HTTPException(404, "no store yet")
    with store:
        report = group(store.path).as_dict()
        examples = [mode[which] for mode in report["modes"] for which in ("worst", "typical")]
        stored = {example["id"]: store.evaluation(example["id"]) for example in examples}
    for example in examples:
        example.update(status=str(stored[example["id"]].status), concrete=stored[example["id"]].concrete)
    return report


@campaign_routes.get("/api/campaigns/{name}/report.html")
def report(name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> FileResponse:
    from harness.campaigns.report import write_report

    store = campaigns.store(name)
    if store is None:
        raise HTTPException(404, "no store yet")
    target = campaigns.store_dir / f"{name}-report.html"
    with store:
        write_report(store, target, 5, _baseline(campaigns, name))
    return FileResponse(target, media_type="text/html")


# -- one evaluation's log and plot ---------------------------------------------------------------

evaluation_routes = APIRouter()


def log_of(evaluation: int, name: str = Depends(known), campaigns: Campaigns = Depends(campaigns_of)) -> Path:
    """An evaluation's log, found from the store (never from a path the browser sends)."""
    store = campaigns.store(name)
    if store is None:
        raise HTTPException(404, "no store yet")
    with store:
        stored = store.evaluation(evaluation)
    if stored is None or stored.log_path is None:
        raise HTTPException(404, f"evaluation {evaluation} has no log")
    path = Path(stored.log_path).resolve()
    if not path.is_relative_to(campaigns.store_dir) or not path.is_file():
        raise HTTPException(404, f"evaluation {evaluation}'s log is not in the store directory")
    return path


@evaluation_routes.get("/api/campaigns/{name}/evaluations/{evaluation}/log.mcap")
def download(name: str, path: Path = Depends(log_of)) -> FileResponse:
    return FileResponse(path, media_type="application/octet-stream", filename=f"{name}-{path.name}")


@evaluation_routes.get("/api/campaigns/{name}/evaluations/{evaluation}/plot.png")
def plot(name: str, evaluation: int, log_path: Path = Depends(log_of), campaigns: Campaigns = Depends(campaigns_of)) -> FileResponse:
    from harness.flight.inspect_log import plot as draw

    target = campaigns.store_dir / f"{name}-plots" / f"evaluation{evaluation}.png"
    if not target.exists():
        target.parent.mkdir(exist_ok=True)
        draw(log_path, target)
    return FileResponse(target, media_type="image/png")


@evaluation_routes.get("/api/campaigns/{name}/evaluations/{evaluation}/explain")
def explanation(name: str, log_path: Path = Depends(log_of)) -> dict[str, Any]:
    """`stella explain` of the evaluation's log: its closest approach's timeline and mechanism."""
    from harness.campaigns.explain import explain, explain_text

    try:
        report = explain(log_path)
    except InputError as error:
        raise HTTPException(422, str(error)) from None
    return {**report, "text": explain_text(report)}


def serve(store_dir: Path, host: str, port: int, token: str | None) -> None:
    import uvicorn

    if not is_loopback(host) and token is None:
        token = secrets.token_urlsafe(18)
        print(f"stella ui on {host}:{port} needs a token; it is: {token}", flush=True)
    print(f"stella ui: http://{host}:{port}/ (store directory {store_dir.resolve()})", flush=True)
    uvicorn.run(create_app(store_dir, token), host=host, port=port, log_level="warning")
