"""Scratch folders in the temporary directory that a killed process does not leave there for good.

An evaluation's folder, a warm stack's home or a worker's task folder is removed by its owner's
own cleanup, which a kill -9 (a campaign stopped hard, a worker lost) never runs: a day of tests
left some 500 behind here. Each folder is named after its owner (`stella-KIND-PID@HOST-XXXXXXXX`),
and the first folder a process makes sweeps away those whose owner on this host is gone. The host
is in the name because processes of other pid namespaces (containers) may share the directory.
"""

from __future__ import annotations

import functools
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path

_OWNED = re.compile(r"^stella-.+-(?P<pid>\d+)@(?P<host>[^@/]+)-[^-]+$")


def prefix(kind: str) -> str:
    """The name prefix of a scratch folder of `kind` for tempfile's mkdtemp or TemporaryDirectory;
    the first call in a process sweeps the folders of owners that are gone."""
    _sweep_once(os.getpid())
    return f"stella-{kind}-{os.getpid()}@{socket.gethostname()}-"


def folder(kind: str) -> Path:
    return Path(tempfile.mkdtemp(prefix=prefix(kind)))


def owner(name: str) -> tuple[int, str] | None:
    """The pid and host of the process that made a scratch folder of this name; None for a name
    that is no scratch folder's (the port lease's lock folder, another program's)."""
    match = _OWNED.match(name)
    return (int(match["pid"]), match["host"]) if match is not None else None


@functools.lru_cache(maxsize=None)
def _sweep_once(pid: int) -> None:
    """Once per process (a forked worker is a process of its own, hence the pid as the key)."""
    sweep(Path(tempfile.gettempdir()), socket.gethostname())


def sweep(directory: Path, host: str) -> list[Path]:
    """Remove the scratch folders in `directory` made on `host` by processes that are gone, and of
    ours only (another user's are not ours to judge); the folders removed."""
    removed = []
    uid = os.getuid()
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        made_by = owner(entry.name)
        if made_by is None or made_by[1] != host or _alive(made_by[0]):
            continue
        try:
            if not entry.is_dir(follow_symlinks=False) or entry.stat(follow_symlinks=False).st_uid != uid:
                continue
        except OSError:
            continue  # its owner's cleanup took it meanwhile
        shutil.rmtree(entry.path, ignore_errors=True)
        removed.append(Path(entry.path))
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True
