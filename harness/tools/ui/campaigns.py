"""The campaigns `stella ui` launches and watches, each one a `stella campaign` process.

A campaign launched from the page is the same command a user would type, run as a process of
its own with its store in the store directory (`NAME.db`, logs in `NAME-logs/`, its console in
`NAME.log`, the command in `NAME.json` so that Resume runs it again). Cancel sends it SIGINT, as
Ctrl-C in a terminal would; the store keeps every finished evaluation. Progress is read from
the store, which a running campaign commits to after every evaluation.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from harness.campaigns.store import Store
from harness.errors import InputError, Problem
from harness.paths import scenarios_dir
from harness.scenario.documents import load_json
from harness.scenario.logical import load_logical, logical_problems
from harness.scenario.profile import load_profile
from harness.search.optimizers import parse_algorithm
from sut_adapter.processes import dies_with_this_process

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
UPLOADS = "uploads"
MAX_UPLOAD_BYTES = 256 * 1024


def inside(base: Path, relative: str) -> Path | None:
    """base/relative if it stays inside base (no `..`, no absolute path, no symlink out), else None."""
    if not relative or relative.startswith("/") or "\\" in relative:
        return None
    candidate = (base / relative).resolve()
    return candidate if candidate.is_relative_to(base.resolve()) else None


class Campaigns:
    def __init__(self, store_dir: Path):
        self.store_dir = store_dir.resolve()
        self.store_dir.mkdir(parents=True, exist_ok=True)
        (self.store_dir / UPLOADS).mkdir(exist_ok=True)
        self._processes: dict[str, subprocess.Popen] = {}
        self._lock = threading.Lock()

    # -- scenarios ----------------------------------------------------------------------------

    def scenario_choices(self) -> list[str]:
        """Logical scenarios the page offers: `scenarios/...` files and `uploads/...` files."""
        bundled = sorted(f"scenarios/{p.relative_to(scenarios_dir()).as_posix()}" for p in scenarios_dir().rglob("*.json")
                         if "schema" not in p.parts and "profiles" not in p.parts)
        uploaded = sorted(f"{UPLOADS}/{p.name}" for p in (self.store_dir / UPLOADS).glob("*.json"))
        return bundled + uploaded

    def resolve_scenario(self, choice: str) -> Path | None:
        prefix, _, rest = choice.partition("/")
        if prefix == "scenarios":
            return inside(scenarios_dir(), rest)
        if prefix == UPLOADS:
            return inside(self.store_dir / UPLOADS, rest)
        return None

    def upload(self, filename: str, data: bytes, profile: str = "default") -> tuple[str | None, list[Problem]]:
        """Validate an uploaded logical scenario and keep it if it is valid: (its choice, problems)."""
        stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(filename).stem).strip("_")[:60] or "scenario"
        target = self.store_dir / UPLOADS / f"{stem}.json"
        pending = target.with_suffix(".pending")
        pending.write_bytes(data)
        try:
            try:
                document = load_json(pending)
            except InputError as error:
                return None, [Problem(filename, p.pointer, p.message) for p in error.problems]
            problems = logical_problems(document, load_profile(profile), filename)
            if problems:
                return None, problems
            pending.replace(target)
            return f"{UPLOADS}/{target.name}", []
        finally:
            pending.unlink(missing_ok=True)

    # -- launching ----------------------------------------------------------------------------

    def command(self, name: str) -> list[str]:
        spec = json.loads((self.store_dir / f"{name}.json").read_text())
        argv = [sys.executable, "-m", "harness.tools.cli", "campaign", *spec["scenario_paths"]]
        for algorithm in spec["algorithms"]:
            argv += ["--algorithm", algorithm]
        argv += ["--evaluations", str(spec["evaluations"]), "--runs", str(spec["runs"]), "--seed", str(spec["seed"]),
                 "--population", str(spec["population"]), "--profile", spec["profile"], "--executor", spec["executor"],
                 "--store", str(self.store_dir / f"{name}.db")]
        if spec.get("workers"):
            argv += ["--workers", str(spec["workers"])]
        return argv

    def launch(self, spec: dict[str, Any]) -> str:
        """Check a campaign set up on the page and start it; InputError names every bad field."""
        problems = []
        name = str(spec.get("name", ""))
        if not NAME.match(name):
            problems.append(Problem("name", "", "use 1-64 letters, digits, _ or -, starting with a letter or digit"))
        elif (self.store_dir / f"{name}.json").exists():
            problems.append(Problem("name", "", f"a campaign called {name} exists; resume it or choose another name"))
        paths = []
        for choice in spec.get("scenarios") or []:
            path = self.resolve_scenario(str(choice))
            if path is None or not path.is_file():
                problems.append(Problem("scenarios", "", f"{choice} is not a scenario of scenarios/ or an upload"))
                continue
            try:
                load_logical(path, load_profile(spec.get("profile", "default")))
            except InputError as error:
                problems.extend(Problem("scenarios", p.pointer, f"{choice}: {p.message}") for p in error.problems)
            paths.append(str(path))
        if not spec.get("scenarios"):
            problems.append(Problem("scenarios", "", "choose at least one logical scenario"))
        algorithms = [a.strip().upper() for a in spec.get("algorithms") or [] if a.strip()]
        if not algorithms:
            problems.append(Problem("algorithms", "", "give at least one algorithm: NSGAII, SMPSO, BO, RANDOM or a string of N, P, B, R"))
        for algorithm in algorithms:
            try:
                parse_algorithm(algorithm)
            except ValueError as error:
                problems.append(Problem("algorithms", "", str(error)))
        numbers = {}
        for field, low in (("evaluations", 1), ("population", 1), ("runs", 1), ("seed", 0), ("workers", 1)):
            value = spec.get(field)
            if field == "workers" and value in (None, ""):
                continue
            try:
                numbers[field] = int(value)
                if numbers[field] < low:
                    raise ValueError
            except (TypeError, ValueError):
                problems.append(Problem(field, "", f"must be a whole number of at least {low}, got {value!r}"))
        if spec.get("executor", "local") not in ("local", "sequential", "dask", "docker"):
            problems.append(Problem("executor", "", "choose local, sequential, dask or docker"))
        if problems:
            raise InputError(problems)
        document = {"scenarios": spec["scenarios"], "scenario_paths": paths, "algorithms": algorithms, "profile": spec.get("profile", "default"),
                    "executor": spec.get("executor", "local"), **numbers}
        (self.store_dir / f"{name}.json").write_text(json.dumps(document, indent=2))
        self._start(name)
        return name

    def _start(self, name: str) -> None:
        with self._lock:
            running = self._processes.get(name)
            if running is not None and running.poll() is None:
                return
            with open(self.store_dir / f"{name}.log", "ab") as console:
                self._processes[name] = subprocess.Popen(self.command(name), stdout=console, stderr=console, stdin=subprocess.DEVNULL,
                                                         start_new_session=True, preexec_fn=dies_with_this_process())

    def resume(self, name: str) -> None:
        self._start(name)

    def cancel(self, name: str) -> None:
        """Ctrl-C for the campaign: SIGINT to its process group (the campaign and its workers)."""
        with self._lock:
            process = self._processes.get(name)
        if process is not None and process.poll() is None:
            os.killpg(process.pid, signal.SIGINT)
            try:
                process.wait(timeout=60.0)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()

    def close(self) -> None:
        for name in list(self._processes):
            self.cancel(name)

    # -- watching and browsing ----------------------------------------------------------------

    def console_tail(self, name: str, lines: int = 15) -> str:
        """The end of the campaign process's output: why it stopped, when it did."""
        path = self.store_dir / f"{name}.log"
        if not path.exists():
            return ""
        # tqdm redraws its bar with carriage returns: keep the last state of each line.
        text = path.read_text(errors="replace").replace("\r\n", "\n")
        return "\n".join(line.rsplit("\r", 1)[-1] for line in text.splitlines()[-lines:])

    def names(self) -> list[str]:
        return sorted(p.stem for p in self.store_dir.glob("*.json") if NAME.match(p.stem))

    def exists(self, name: str) -> bool:
        return bool(NAME.match(name)) and (self.store_dir / f"{name}.json").is_file()

    def store(self, name: str) -> Store | None:
        path = self.store_dir / f"{name}.db"
        return Store(path) if path.exists() else None

    def state(self, name: str) -> str:
        process = self._processes.get(name)
        if process is not None and process.poll() is None:
            return "running"
        progress = self.progress(name)
        return "finished" if progress["runs"] and all(r["finished"] for r in progress["runs"]) and progress["done"] == progress["total"] else "stopped"

    def progress(self, name: str) -> dict[str, Any]:
        """Per run: evaluations done of its budget, best fitness so far, violations, evaluations
        per hour and ETA; and each run's best-so-far curve."""
        spec = json.loads((self.store_dir / f"{name}.json").read_text())
        per_run_total = spec["evaluations"]
        total = per_run_total * spec["runs"] * len(spec["algorithms"]) * len(spec["scenarios"])
        runs, curves = [], {}
        store = self.store(name)
        if store is not None:
            with store:
                for row in store.run_rows():
                    times = [t for (t,) in store.db.execute("SELECT created FROM evaluations WHERE run_id = ? ORDER BY created", (row["id"],))]
                    rate = 3600.0 * (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else None
                    remaining = per_run_total - row["evaluations"]
                    runs.append({"id": row["id"], "scenario": row["scenario"], "algorithm": row["algorithm"], "run": row["run_index"],
                                 "done": row["evaluations"], "total": per_run_total, "best_fitness": row["best_fitness"],
                                 "violations": row["violations"] or 0, "evaluations_per_hour": rate, "finished": row["finished"] is not None,
                                 "eta_s": 3600.0 * remaining / rate if rate and row["finished"] is None else None})
                    curves[str(row["id"])] = store.best_so_far(row["id"])
        return {"name": name, "done": sum(r["done"] for r in runs), "total": total, "runs": runs, "curves": curves, "time": time.time()}
