"""The bundled autopilot (`python -m autopilot`) as a SUT.

With `autopilot_dir` (a folder holding an `autopilot` package: a mutant built by `stella mutants
build`, or the user's own edit) that package flies instead of the installed one. It runs in a
process of its own then, with the folder first on its PYTHONPATH, never inside the simulator's
process, whose `autopilot` is the installed one. A coverage build's folder (`stella sut build
bundled --coverage`) flies under coverage.py, its flights recording their coverage
(sut_adapter/coverage.py).
"""

from __future__ import annotations

import json
import os
import logging
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from sut_adapter.base import Capabilities, SutError, SutHandle, start_process
from sut_adapter.coverage import coverage_build, python_command, python_record
from sut_adapter.processes import ManagedProcess

log = logging.getLogger(__name__)


class BundledAutopilot:
    name = "bundled"
    capabilities = Capabilities(hold_mode="frozen", range_messages=("OBSTACLE_DISTANCE",), rig_messages=("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"), transports=("tcp", "unix", "shm", "memory"),
                                answers_every_step=True, echoes_step_time=True)

    def __init__(self, config: Mapping[str, str] | None = None):
        config = dict(config or {})
        self.fault = config.pop("fault", None)
        self.autopilot_dir = config.pop("autopilot_dir", None)
        if config:
            raise SutError(self.name, f"takes no configuration but a seeded fault and an autopilot folder, got {sorted(config)}")
        if self.fault is not None and self.fault not in seeded_faults():
            raise SutError(self.name, f"no seeded fault {self.fault!r}; `stella faults list` names them")
        if self.autopilot_dir is not None:
            folder = Path(self.autopilot_dir).expanduser().resolve()
            if not (folder / "autopilot" / "__main__.py").is_file():
                raise SutError(self.name, f"{folder} holds no autopilot package (autopilot/__main__.py): give the folder `stella mutants build` wrote for a mutant")
            self.autopilot_dir = str(folder)
            # Its package must be found on its own PYTHONPATH, which only a process of its own has.
            self.capabilities = replace(self.capabilities, transports=("tcp", "unix", "shm"))

    def check_params(self, params: Mapping[str, float]) -> None:
        """Refuse a name neither the bundled autopilot nor PX4 has; say, once, which PX4
        parameters are accepted without effect, so nobody believes they shaped the flights."""
        from autopilot.params import ParamError, Params, without_effect

        try:
            Params(dict(params))
        except ParamError as error:
            raise SutError(self.name, f"{error} (`python -m autopilot.params` lists its parameters)") from None
        ignored = without_effect(params)
        if ignored:
            log.warning("%s: accepted without effect (PX4 parameters it does not model): %s", self.name, ", ".join(ignored))

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float],
              spin_s: float = 0.0, sim_socket: str | None = None, sim_shared_memory: bool = False) -> SutHandle:
        sim = f"{'shm' if sim_shared_memory else 'unix'}:{sim_socket}" if sim_socket is not None else f"tcp:127.0.0.1:{sim_port}"
        measured = coverage_build(self.autopilot_dir)
        interpreter = [sys.executable] if measured is None else python_command(measured, Path(self.autopilot_dir), workdir)
        argv = [*interpreter, "-m", "autopilot", "--sim", sim, *self._arguments(api_port=api_port, workdir=workdir, params=params)]
        if spin_s > 0.0:
            argv += ["--spin-us", str(spin_s * 1e6)]
        env = None
        if self.autopilot_dir is not None:
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [self.autopilot_dir, os.environ.get("PYTHONPATH")]))}
        process = ManagedProcess("autopilot", argv, log_dir=workdir, cwd=workdir, env=env)
        if measured is None:
            return start_process(self.name, process)
        return start_process(self.name, process, coverage=lambda: python_record(Path(self.autopilot_dir), workdir))

    def _arguments(self, *, api_port: int, workdir: Path, params: Mapping[str, float]) -> list[str]:
        argv = ["--api", f"udp:127.0.0.1:{api_port}"]
        if params:
            params_file = workdir / "autopilot_params.json"
            params_file.write_text(json.dumps(dict(params)))
            argv += ["--params", str(params_file)]
        if self.fault is not None:
            argv += ["--fault", self.fault]
        return argv

    def inline_arguments(self, *, api_port: int, workdir: Path, params: Mapping[str, float]) -> list[str]:
        """`python -m autopilot`'s arguments but the simulator's, for running it inside the bridge's
        process (`python -m sut_adapter.inline`, --transport memory)."""
        return self._arguments(api_port=api_port, workdir=workdir, params=params)


def seeded_faults() -> dict[str, Any]:
    """The bundled autopilot's seeded faults by name (autopilot/faults.py), for `stella faults`."""
    from autopilot.faults import BY_NAME

    return dict(BY_NAME)


def step_bench(stream: bytes, mission: Mapping[str, Any]) -> dict[str, Any]:
    """The bundled autopilot's own cost per step, replaying a simulator-to-SUT stream in this
    process (autopilot/step_bench.py)."""
    from autopilot.step_bench import replay

    return replay(stream, mission)
