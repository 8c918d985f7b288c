"""The campaigns `stella ui` launches and watches, each one a `stella campaign` process.

A campaign launched from the page is the same command a user would type, run as a process of
its own with its store in the store directory (`NAME.db`, logs in `NAME-logs/`, its console in
`NAME.log`, the command in `NAME.json` so that Resume runs it again). Its SUT, drive, plan,
seeded fault and parameters are the command's options, and the command line is checked by the
CLI's own code before it starts (harness.tools.commands.campaigns.checked_campaign), so the page refuses what
the command would refuse, with the same message. Cancel sends it SIGINT, as Ctrl-C in a
terminal would; the store keeps every finished evaluation. Progress is read from the store,
which a running campaign commits to after every evaluation.

Campaigns die with the server (PR_SET_PDEATHSIG) but not with the request's thread that asked
for them: they are started from a launcher thread that lives as long as the server.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from harness.campaigns.store import Store
from harness.errors import InputError, Problem
from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.search.optimizers import parse_algorithm
from harness.tools.commands.campaigns import checked_campaign
from harness.tools.commands.common import positive_int, seed_int
from harness.tools.ui.uploads import KINDS, Uploads
from sut_adapter.processes import Launcher

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
NUMBERS = {"evaluations": positive_int, "population": positive_int, "runs": positive_int, "seed": seed_int, "workers": positive_int}
# The page's fields for `stella campaign`'s options: text as typed, and files chosen by kind.
TEXT_OPTIONS = {"sut": "--sut", "px4_bin": "--px4-bin", "ardupilot_bin": "--ardupilot-bin", "sut_command": "--sut-command", "sut_hold": "--sut-hold", "sut_fault": "--sut-fault",
                "autopilot_dir": "--autopilot-dir", "drive": "--drive", "rig": "--rig"}
FILE_OPTIONS = {"mission_plan": ("plan", "--mission-plan"), "sut_params_file": ("params", "--sut-params-file")}
FIELDS = {"--algorithm": "algorithms", "--sut-param": "sut_params", "--profile": "profile", "--executor": "executor", "--workers": "workers",
          **{f"--{field}": field for field in NUMBERS}, **{option: field for field, option in TEXT_OPTIONS.items()},
          **{option: field for field, (_kind, option) in FILE_OPTIONS.items()}}


class SetupError(InputError):
    """A campaign set up on the page that cannot start: each problem with the field it is about."""

    def __init__(self, problems: list[tuple[str, Problem]]):
        self.fields = tuple(field for field, _problem in problems)
        super().__init__([problem for _field, problem in problems])


def _numbers(spec: dict[str, Any]) -> tuple[dict[str, int], list[tuple[str, Problem]]]:
    """The number fields, each checked as its command-line option is."""
    numbers, problems = {}, []
    for field, convert in NUMBERS.items():
        value = spec.get(field)
        if field == "workers" and value in (None, ""):
            continue
        try:
            numbers[field] = convert(str(value))
        except (argparse.ArgumentTypeError, ValueError) as error:
            why = str(error) if isinstance(error, argparse.ArgumentTypeError) else f"{value!r} is not a whole number"
            problems.append((field, Problem(field, "", why)))
    return numbers, problems


class Campaigns:
    def __init__(self, store_dir: Path):
        self.store_dir = store_dir.resolve()
        self.store_dir.mkdir(parents=True, exist_ok=True)
        self.uploads = Uploads(self.store_dir)
        self._processes: dict[str, subprocess.Popen] = {}
        self._lock = threading.Lock()
        self._launcher = Launcher("campaign-launcher")

    # -- launching ----------------------------------------------------------------------------

    def arguments(self, name: str, spec: dict[str, Any] | None = None) -> list[str]:
        """`stella campaign`'s arguments for the campaign called name (as stored, or as spec)."""
        spec = spec or json.loads((self.store_dir / f"{name}.json").read_text())
        argv = list(spec["scenario_paths"])
        for algorithm in spec["algorithms"]:
            argv += ["--algorithm", algorithm]
        argv += ["--evaluations", str(spec["evaluations"]), "--runs", str(spec["runs"]), "--seed", str(spec["seed"]),
                 "--population", str(spec["population"]), "--profile", spec["profile"], "--executor", spec["executor"],
                 "--store", str(self.store_dir / f"{name}.db")]
        if spec.get("workers"):
            argv += ["--workers", str(spec["workers"])]
        return argv + spec.get("options", [])

    def command(self, name: str) -> list[str]:
        return [sys.executable, "-m", "harness.tools.cli", "campaign", *self.arguments(name)]

    def command_text(self, name: str) -> str:
        """The command as a user would type it in the checkout."""
        return shlex.join(["stella", "campaign", *self.arguments(name)])

    def launch(self, spec: dict[str, Any]) -> str:
        """Check a campaign set up on the page and start it; SetupError names every bad field."""
        if not isinstance(spec, dict):
            raise SetupError([("", Problem("campaign", "", "send the set-up as a JSON object"))])
        problems: list[tuple[str, Problem]] = []
        name = str(spec.get("name", ""))
        if not NAME.match(name):
            problems.append(("name", Problem("name", "", "use 1-64 letters, digits, _ or -, starting with a letter or digit")))
        elif (self.store_dir / f"{name}.json").exists():
            problems.append(("name", Problem("name", "", f"a campaign called {name} exists; resume it or choose another name")))
        profile = str(spec.get("profile", "default"))
        paths: dict[str, tuple[str, str]] = {}  # file -> (field, choice), to put problems of the command's files on the page's fields
        problems += self._scenario_problems(spec.get("scenarios"), profile, paths)
        scenario_paths = list(paths)
        algorithms = [a.strip().upper() for a in spec.get("algorithms") or [] if isinstance(a, str) and a.strip()]
        if not algorithms:
            problems.append(("algorithms", Problem("algorithms", "", "give at least one algorithm: NSGAII, SMPSO, BO, RANDOM or a string of N, P, B, R")))
        for algorithm in algorithms:
            try:
                parse_algorithm(algorithm)
            except ValueError as error:
                problems.append(("algorithms", Problem("algorithms", "", str(error))))
        numbers, number_problems = _numbers(spec)
        options, option_problems = self._options(spec, paths)
        problems += number_problems + option_problems
        document = {"scenarios": spec.get("scenarios"), "scenario_paths": scenario_paths, "algorithms": algorithms, "profile": profile,
                    "executor": spec.get("executor", "local"), **numbers, "options": options}
        if not problems:  # the command is whole: the CLI's own checks
            problems = self._command_problems(name, document, paths)
        if problems:
            raise SetupError(problems)
        (self.store_dir / f"{name}.json").write_text(json.dumps(document, indent=2))
        self._start(name)
        return name

    def _scenario_problems(self, choices: Any, profile: str, paths: dict[str, tuple[str, str]]) -> list[tuple[str, Problem]]:
        if not choices or not isinstance(choices, list):
            return [("scenarios", Problem("scenarios", "", "choose at least one logical scenario"))]
        problems = []
        for choice in choices:
            path = self.uploads.resolve("scenario", choice)
            if path is None:
                problems.append(("scenarios", Problem("scenarios", "", f"{choice} is not a scenario of scenarios/ or an upload")))
                continue
            try:
                load_logical(path, load_profile(profile))
            except InputError as error:
                problems.extend(("scenarios", Problem("scenarios", p.pointer, f"{choice}: {p.message}")) for p in error.problems)
            paths[str(path)] = ("scenarios", choice)
        return problems

    def _options(self, spec: dict[str, Any], paths: dict[str, tuple[str, str]]) -> tuple[list[str], list[tuple[str, Problem]]]:
        """The SUT, drive and plan fields as the command's options (--option=VALUE, so that a value
        that starts with - is not taken for an option), and what is wrong with their shapes."""
        options, problems = [], []
        for field, option in TEXT_OPTIONS.items():
            value = spec.get(field)
            if value in (None, ""):
                continue
            if isinstance(value, str):
                options.append(f"{option}={value}")
            else:
                problems.append((field, Problem(option, "", f"give text, not {value!r}")))
        for field, (kind, option) in FILE_OPTIONS.items():
            choice = spec.get(field)
            if choice in (None, ""):
                continue
            path = self.uploads.resolve(kind, choice)
            if path is None:
                problems.append((field, Problem(option, "", f"{choice} is not {KINDS[kind].what} of scenarios/ or an upload: upload it first")))
                continue
            options.append(f"{option}={path}")
            paths[str(path)] = (field, choice)
        params = spec.get("sut_params") or []
        if not isinstance(params, list) or not all(isinstance(item, str) for item in params):
            problems.append(("sut_params", Problem("--sut-param", "", "give a list of NAME=VALUE texts")))
        else:
            options += [f"--sut-param={item.strip()}" for item in params if item.strip()]
        return options, problems

    def _command_problems(self, name: str, document: dict[str, Any], paths: dict[str, tuple[str, str]]) -> list[tuple[str, Problem]]:
        """What the CLI refuses of the command the page would run, on the page's fields."""
        try:
            checked_campaign(self.arguments(name, document))
        except InputError as error:
            problems = []
            for problem in error.problems:
                field, file = paths.get(problem.file, (FIELDS.get(problem.file, ""), problem.file))
                problems.append((field, Problem(file, problem.pointer, problem.message)))
            return problems
        return []

    def _start(self, name: str) -> None:
        with self._lock:
            running = self._processes.get(name)
            if running is not None and running.poll() is None:
                return
            with open(self.store_dir / f"{name}.log", "ab") as console:
                self._processes[name] = self._launcher.popen(self.command(name), stdout=console, stderr=console, stdin=subprocess.DEVNULL,
                                                             start_new_session=True)

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
        self._launcher.close()

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
                for run in store.runs():
                    span_s = (run.last_created - run.first_created) if run.evaluations > 1 else 0.0
                    rate = 3600.0 * (run.evaluations - 1) / span_s if span_s > 0 else None
                    remaining = per_run_total - run.evaluations
                    runs.append({"id": run.id, "scenario": run.scenario, "algorithm": run.algorithm, "run": run.run_index,
                                 "done": run.evaluations, "total": per_run_total, "best_fitness": run.best_fitness,
                                 "violations": run.violations, "evaluations_per_hour": rate, "finished": run.finished is not None,
                                 "eta_s": 3600.0 * remaining / rate if rate and run.finished is None else None})
                    curves[str(run.id)] = store.best_so_far(run.id)
        return {"name": name, "done": sum(r["done"] for r in runs), "total": total, "runs": runs, "curves": curves, "time": time.time()}
