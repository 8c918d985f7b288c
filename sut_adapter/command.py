"""Any MAVLink SUT started by a command line template.

    stella run S --sut command --sut-command "my_autopilot --sim tcp:127.0.0.1:{sim_port} --gcs udp:127.0.0.1:{api_port} --id {instance}" [--sut-hold frozen]

Placeholders: {sim_port} (the simulator's TCP port to connect to), {api_port} (the UDP port to
send the API link to), {instance} (the port block's index) and {workdir} (a fresh directory,
also the working directory). The template is split like a shell would split it, then each
word is filled in, so a placeholder never splits into two words. Parameters are set over
MAVLink by the harness. The hold mode defaults to "paced", which every SUT can live with.
"""

from __future__ import annotations

import shlex
import string
from pathlib import Path
from typing import Mapping

from sut_adapter.base import HOLD_MODES, Capabilities, SutError, SutHandle, start_process
from sut_adapter.processes import ManagedProcess

PLACEHOLDERS = ("sim_port", "api_port", "instance", "workdir")


def parse_template(template: str) -> list[str]:
    """The template's words; raises SutError naming what is wrong and how to fix it."""
    try:
        words = shlex.split(template)
    except ValueError as error:
        raise SutError("command", f"--sut-command cannot be split into words: {error}") from None
    if not words:
        raise SutError("command", "--sut-command is empty; give the SUT's command line with {sim_port} and {api_port}")
    used = set()
    for word in words:
        try:
            fields = [name for _text, name, _spec, _conversion in string.Formatter().parse(word) if name is not None]
        except ValueError as error:
            raise SutError("command", f"--sut-command word {word!r}: {error} (write {{{{ and }}}} for literal braces)") from None
        unknown = [name for name in fields if name not in PLACEHOLDERS]
        if unknown:
            raise SutError("command", f"--sut-command has unknown placeholder(s) {', '.join('{' + n + '}' for n in unknown)}; "
                                      f"available: {', '.join('{' + n + '}' for n in PLACEHOLDERS)}")
        used.update(fields)
    missing = [name for name in ("sim_port", "api_port") if name not in used]
    if missing:
        raise SutError("command", f"--sut-command must use {', '.join('{' + n + '}' for n in missing)}: evaluations run side by side on their own ports")
    return words


class CommandSut:
    name = "command"

    def __init__(self, config: Mapping[str, str]):
        unknown = sorted(set(config) - {"command", "hold"})
        if unknown:
            raise SutError(self.name, f"unknown configuration {unknown}; it takes command (--sut-command) and hold (--sut-hold)")
        self.words = parse_template(config.get("command", ""))
        hold_mode = config.get("hold", "paced")
        if hold_mode not in HOLD_MODES:
            raise SutError(self.name, f"--sut-hold {hold_mode!r} is not one of {', '.join(HOLD_MODES)}")
        self.capabilities = Capabilities(hold_mode=hold_mode, range_messages=("OBSTACLE_DISTANCE", "DISTANCE_SENSOR"),
                                         rig_messages=("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"))

    def argv(self, *, sim_port: int, api_port: int, instance: int, workdir: Path) -> list[str]:
        values = {"sim_port": sim_port, "api_port": api_port, "instance": instance, "workdir": str(workdir)}
        return [word.format(**values) for word in self.words]

    def check_params(self, params: Mapping[str, float]) -> None:
        """Its parameters are known only to the running SUT, which reports a bad one when set."""

    def start(self, *, sim_port: int, api_port: int, instance: int, workdir: Path, params: Mapping[str, float],
              spin_s: float = 0.0) -> SutHandle:
        process = ManagedProcess("sut", self.argv(sim_port=sim_port, api_port=api_port, instance=instance, workdir=workdir), log_dir=workdir, cwd=workdir)
        return start_process(self.name, process, artifacts=process.console_logs, mavlink_params=dict(params))
