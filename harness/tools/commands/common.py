"""What every command module uses: the declaration of a command (or an action of one) with its
options beside its handler, the JSON-or-text output, and argparse types that say what is wrong."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, field
from typing import Any, Callable

from harness.errors import InputError, Problem

Handler = Callable[[argparse.Namespace], int]
Options = Callable[[argparse.ArgumentParser], None]


def no_options(parser: argparse.ArgumentParser) -> None:
    """A command whose only option is --json."""


@dataclass
class Command:
    name: str
    help: str
    options: Options = no_options
    run: Handler | None = None  # None: the command only dispatches to its actions
    description: str | None = None  # the --help text, where the listing's one line says too little
    actions: dict[str, Command] = field(default_factory=dict)


COMMANDS: dict[str, Command] = {}


def command(name: str, help_text: str, options: Options = no_options, *, description: str | None = None) -> Callable[[Handler], Handler]:
    """Declare `stella NAME` (or, for "faults list", an action of a command declared with
    `command_with_actions`) with its options; the decorated function handles it."""
    def register(run: Handler) -> Handler:
        declared = Command(name.split()[-1], help_text, options, run, description)
        if " " in name:
            parent, _action = name.split()
            COMMANDS[parent].actions[declared.name] = declared
        else:
            COMMANDS[name] = declared
        return run

    return register


def command_with_actions(name: str, help_text: str, *, description: str | None = None) -> None:
    """Declare `stella NAME ACTION`, each action with its own options (`command("NAME ACTION", ...)`)."""
    COMMANDS[name] = Command(name, help_text, description=description)


def add_command(subparsers: argparse._SubParsersAction, declared: Command) -> None:
    parser = subparsers.add_parser(declared.name, help=declared.help, description=declared.description or declared.help)
    if declared.actions:
        actions = parser.add_subparsers(dest="action", required=True)
        for action in declared.actions.values():
            add_command(actions, action)
        return
    add_options(parser, declared.options)
    parser.set_defaults(handler=declared.run)


def add_options(parser: argparse.ArgumentParser, options: Options) -> None:
    """--json, which every command takes, and the command's own options."""
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    options(parser)


def emit(args: argparse.Namespace, result: Any, text: str) -> None:
    if getattr(args, "json", False):
        print(json.dumps(result, indent=2))
    else:
        print(text)


class RefusingParser(argparse.ArgumentParser):
    """An argument parser that raises InputError where argparse would print usage and exit."""

    def error(self, message: str):
        option, separator, text = message.partition(": ")
        if separator and option.startswith("argument "):
            raise InputError([Problem(option.removeprefix("argument "), "", text)])
        raise InputError([Problem(self.prog, "", message)])


def _bounded(name: str, convert: Callable[[str], Any], accepts: Callable[[Any], bool], is_not: str) -> Callable[[str], Any]:
    """An argparse type: convert, then refuse values outside the range with `TEXT is not ...`."""
    def parse(text: str):
        value = convert(text)
        if not accepts(value):
            raise argparse.ArgumentTypeError(f"{text} is not {is_not}")
        return value
    parse.__name__ = name  # argparse names the type in "invalid NAME value"
    return parse


positive_int = _bounded("positive_int", int, lambda v: v >= 1, "a positive whole number")
non_negative_int = _bounded("non_negative_int", int, lambda v: v >= 0, "a whole number of zero or more")
seed_int = _bounded("seed_int", int, lambda v: 0 <= v < 2**32, "a seed: give a whole number from 0 to 4294967295")
port_int = _bounded("port_int", int, lambda v: 1 <= v <= 65535, "a TCP port: give 1 to 65535")
positive_float = _bounded("positive_float", float, lambda v: 0 < v < math.inf, "a positive number")
non_negative_float = _bounded("non_negative_float", float, lambda v: 0 <= v < math.inf, "a number of zero or more")
share = _bounded("share", float, lambda v: 0 <= v <= 1, "a share: give a number from 0 to 1")
