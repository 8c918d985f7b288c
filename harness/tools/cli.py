"""The `stella` command line. Results go to stdout (one JSON object with --json); logs to stderr.

Exit codes: 0 success, 1 a violation where the user asked to fail on one, 2 bad input or
usage, 3 infrastructure failure.

Each module of harness/tools/commands/ declares its commands, each command's (or action's)
options beside its handler, as a pytest plugin declares its options beside its hooks; this
module only assembles them and turns errors into exit codes.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import signal
import sqlite3
import sys
import traceback
from typing import Sequence

from harness.errors import InputError, StellaError
# Importing a command module declares its commands, in the order `stella --help` lists them.
from harness.tools.commands import scenarios, flights, properties, explain, campaigns, shrink, sut, gate, mutants, faults, machinery  # noqa: F401
from harness.tools.commands.common import COMMANDS, add_command

log = logging.getLogger("stella")


def parser(kind: type[argparse.ArgumentParser] = argparse.ArgumentParser) -> argparse.ArgumentParser:
    root = kind(prog="stella", description="Scenario-based safety testing of UAV autopilots over MAVLink.")
    root.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    subparsers = root.add_subparsers(dest="command", required=True)
    for declared in COMMANDS.values():
        add_command(subparsers, declared)
    return root


def main(argv: Sequence[str] | None = None) -> int:
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # Started in the background of a script (which ignores SIGINT for its & jobs), or by such a
        # process: Ctrl-C is still how a campaign stops with nothing lost, and how the campaign
        # page's Cancel stops one.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr, format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.handler(args)
    except InputError as error:
        print(str(error), file=sys.stderr)
        return error.exit_code
    except StellaError as error:
        print(f"error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`stella faults list | head`): stop quietly, as other tools do;
        # stdout is pointed at /dev/null so that closing it at exit raises nothing more.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except sqlite3.OperationalError as error:
        if "full" not in str(error):
            return _internal_error()
        # SQLite rolled the transaction back: the store holds every evaluation finished before.
        print(f"{getattr(args, 'store', 'the campaign store')}: {error}: make room and run the same command again to resume", file=sys.stderr)
        return 2
    except OSError as error:
        if error.filename is None and error.errno != errno.ENOSPC:
            return _internal_error()
        # An output that cannot be written (no such folder, no permission, a full disk): the
        # user's to mend, so one line naming the path rather than a traceback.
        resume = "; the store keeps every finished evaluation: run the same command again to resume" if args.command == "campaign" else ""
        fewer = "; --sut-logs failures keeps the SUT's own logs of failing flights only" if getattr(args, "sut_logs", None) == "all" else ""
        print(f"{error.filename or 'writing the campaign store or logs'}: {error.strerror}: give a path in a writable folder with room{resume}{fewer}", file=sys.stderr)
        return 2
    except Exception:
        return _internal_error()


def _internal_error() -> int:
    """A defect of stella's own: the traceback, and exit 3 rather than Python's 1, which a script
    or CI job would read as "a violation" or "a regression" (`stella gate`)."""
    traceback.print_exc()
    print("error: the above is a defect of stella, not of the SUT or the input; please report it with the traceback", file=sys.stderr)
    return 3


if __name__ == "__main__":
    sys.exit(main())
