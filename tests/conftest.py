from __future__ import annotations

import socket
from pathlib import Path

import pytest

from harness.scenario.profile import Profile, load_profile

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parent.parent
TABLE3 = sorted((ROOT / "scenarios" / "table3").glob("*.json"))


def port_bound(port: int, kind: int = socket.SOCK_STREAM) -> bool:
    """Whether a live socket holds the port; connections lingering in TIME_WAIT do not count,
    as the bridge's own SO_REUSEADDR listener binds over them."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
            return False
        except OSError:
            return True


@pytest.fixture(scope="session")
def profile() -> Profile:
    return load_profile("default")
