"""The CI workflows of docs/ci/: valid against GitHub's and GitLab's schemas, and the PX4 workflow's
steps run as a script, as a runner would run them, against the bundled autopilot: a pull request
whose head leaves the sensor delay out of collision prevention's stopping distance."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from harness.campaigns.gate_config import load_config

from conftest import ROOT, junit_cases, without_sensor_delay

CI = ROOT / "docs" / "ci"
BIN = Path(sys.executable).parent


@pytest.mark.parametrize("workflow, schema", [("github-px4.yml", "vendor.github-workflows"), ("github-ardupilot.yml", "vendor.github-workflows"),
                                              ("gitlab-ci.yml", "vendor.gitlab-ci")])
def test_each_workflow_is_valid_for_its_ci(workflow, schema):
    checked = subprocess.run([str(BIN / "check-jsonschema"), "--builtin-schema", schema, str(CI / workflow)], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stdout + checked.stderr


def test_the_example_configuration_is_one_the_gate_reads():
    settings = load_config(CI / "stella.toml")
    assert settings["sut"] == "px4" and settings["drive"] == "pilot" and settings["sut_params"] == {"CP_DIST": 1.5}


# -- a runner, as far as these workflows need one ----------------------------------------------


@dataclass
class Ran:
    name: str
    returncode: int | None  # None: skipped


class Runner:
    """Runs a job's steps as GitHub's runner does: `run` steps in bash -eo pipefail with the
    workflow's env, `${{ }}` expressions filled in, $GITHUB_ENV and $GITHUB_PATH honoured between
    steps, a step after a failed one only where its `if` says always(). `uses` steps are the
    runner's actions (checkout, cache, upload, comment): recorded, with the path they would take."""

    def __init__(self, workspace: Path, expressions: dict[str, str], env: dict[str, str]):
        self.workspace, self.expressions, self.env = workspace, expressions, env
        self.files = {name: workspace.parent / f"{name.lower()}.txt" for name in ("GITHUB_ENV", "GITHUB_PATH", "GITHUB_STEP_SUMMARY")}
        for path in self.files.values():
            path.write_text("")

    def fill(self, text: str) -> str:
        def value(match: re.Match) -> str:
            expression = match.group(1).strip()
            if expression.startswith("env."):
                return self.env[expression[4:]]
            if expression not in self.expressions:
                raise AssertionError(f"the workflow uses ${{{{ {expression} }}}}, which this runner does not know: teach it")
            return self.expressions[expression]
        return re.sub(r"\$\{\{(.*?)\}\}", value, text)

    def holds(self, condition: str | None, failed: bool) -> bool:
        """A step's `if`: always(), env.NAME == 'x', hashFiles('p') != '', joined by &&."""
        if condition is None:
            return not failed
        results = []
        for part in (p.strip() for p in condition.split("&&")):
            if part == "always()":
                results.append(True)
                continue
            left, operator, right = re.fullmatch(r"(.+?)\s*(==|!=)\s*(.+)", part).groups()
            values = [self._term(term.strip()) for term in (left, right)]
            results.append((values[0] == values[1]) == (operator == "=="))
        return all(results) and ("always()" in condition or not failed)

    def _term(self, term: str) -> str:
        if term.startswith("'"):
            return term.strip("'")
        if term.startswith("env."):
            return self.env.get(term[4:], "")
        hashed = re.fullmatch(r"hashFiles\('(.+)'\)", term)
        if hashed:
            return "digest" if (self.workspace / hashed.group(1)).exists() else ""
        raise AssertionError(f"the workflow's condition uses {term!r}, which this runner does not know: teach it")

    def run_job(self, job: dict, skip: set[str]) -> list[Ran]:
        self.env = {key: self.fill(str(value)) for key, value in self.env.items()}
        ran, failed = [], False
        for step in job["steps"]:
            if step["name"] in skip or not self.holds(step.get("if"), failed):
                ran.append(Ran(step["name"], None))
                continue
            if "uses" in step:
                ran.append(Ran(step["name"], 0))
                continue
            script = self.fill(step["run"])
            paths = [line for line in self.files["GITHUB_PATH"].read_text().splitlines() if line]
            environment = {**os.environ, **self.env, **{name: str(path) for name, path in self.files.items()},
                           "PATH": os.pathsep.join([*reversed(paths), str(BIN), os.environ["PATH"]]), "RUNNER_TEMP": str(self.workspace.parent)}
            done = subprocess.run(["bash", "--noprofile", "--norc", "-eo", "pipefail", "-c", script], cwd=self.workspace, env=environment,
                                  stdout=sys.stderr, stderr=sys.stderr)
            ran.append(Ran(step["name"], done.returncode))
            failed |= done.returncode != 0
            for line in self.files["GITHUB_ENV"].read_text().splitlines():
                name, _, value = line.partition("=")
                self.env[name] = value
        return ran


def git(folder: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(folder), "-c", "user.name=ci", "-c", "user.email=ci@example.org", *args],
                          capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.slow
def test_the_px4_workflows_steps_fail_a_pull_request_whose_head_brakes_late(tmp_path):
    # GIVEN a clone of this project (its compiled modules built, as `make setup` leaves them) whose
    # head commit leaves the sensor delay out of collision prevention's stopping distance
    workspace = tmp_path / "workspace"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(workspace)], check=True)
    base = git(workspace, "rev-parse", "HEAD")
    collision = workspace / "autopilot" / "collision.py"
    collision.write_text(without_sensor_delay(collision.read_text()))
    git(workspace, "commit", "-qam", "CP: the estimator compensates the sensor delay already")
    head = git(workspace, "rev-parse", "HEAD")
    for compiled in (ROOT / "autopilot").glob("*.so"):
        shutil.copy(compiled, workspace / "autopilot")
    subprocess.run([sys.executable, "setup.py", "build_ext", "--inplace"], cwd=workspace, check=True, capture_output=True,
                   env={**os.environ, "STELLA_COMPILE_ONLY": "autopilot/collision.py"})
    # and the team's settings at its root
    (workspace / "stella.toml").write_text('[gate]\nsut = "bundled"\nsuite = ["scenarios/examples/wall_concrete.json"]\n'
                                           'scenarios = ["scenarios/examples/wall.json"]\nbudget_flights = 2\nshrink_candidates = 0\nworkers = 2\n')
    workflow = yaml.safe_load((CI / "github-px4.yml").read_text())
    runner = Runner(workspace, {"github.event.pull_request.base.sha": base, "github.event.pull_request.head.sha": head,
                                "github.workspace": str(workspace)},
                    {**workflow["env"], "STELLA_SUT": "bundled", "XDG_CACHE_HOME": str(tmp_path / "cache")})

    # WHEN its steps run, the harness's installation being this checkout's
    ran = {step.name: step.returncode for step in runner.run_job(workflow["jobs"]["gate"], skip={"Install the harness"})}

    # THEN PX4's tools are not installed for the bundled autopilot, the gate fails the job with exit 1
    assert ran["Install PX4's build tools"] is None
    assert ran["Gate"] == 1
    # and the steps after it still say why: the job summary leads with the verdict, the findings
    # are where the upload and the comment take them from
    assert ran["Job summary"] == 0 and ran["Upload the findings"] == 0 and ran["Comment on the pull request"] == 0
    summary = runner.files["GITHUB_STEP_SUMMARY"].read_text()
    assert summary.startswith("## stella gate: FAILED") and "wall_concrete (suite case): the head violates the safety distance" in summary
    assert junit_cases(workspace / "stella-gate" / "junit.xml")["stella.gate.suite::wall_concrete"] == "failure"
    assert f"commit {head[:10]}" in summary and f"commit {base[:10]}" in summary
