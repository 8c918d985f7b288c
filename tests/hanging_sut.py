"""A SUT that hangs: the bundled autopilot, frozen (SIGSTOP) as soon as it has connected to the
simulator, so alive but answering nothing, however fast the flight would otherwise be.

python tests/hanging_sut.py SIM_PORT API_PORT
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time


def connected(sim_port: int) -> bool:
    """Whether a local TCP connection to the simulator's port is established (/proc/net/tcp:
    remote address 127.0.0.1:port, state 01)."""
    remote = f"0100007F:{sim_port:04X}"
    with open("/proc/net/tcp") as table:
        return any(fields[2] == remote and fields[3] == "01" for fields in (line.split() for line in table.readlines()[1:]))


def main() -> int:
    sim_port, api_port = int(sys.argv[1]), int(sys.argv[2])
    autopilot = subprocess.Popen([sys.executable, "-m", "autopilot", "--sim", f"tcp:127.0.0.1:{sim_port}", "--api", f"udp:127.0.0.1:{api_port}"])
    while autopilot.poll() is None and not connected(sim_port):
        time.sleep(0.002)
    autopilot.send_signal(signal.SIGSTOP)
    return autopilot.wait()


if __name__ == "__main__":
    sys.exit(main())
