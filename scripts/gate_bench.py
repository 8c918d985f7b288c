"""The gate's wall time, cold (an empty cache: both sides built, every base flight flown) and
warm (the same gate again: builds and base flights from the cache), over several pairs of runs.

    .venv/bin/python scripts/gate_bench.py --runs 3 --out /tmp/gate-bench -- --sut bundled --source . --base HEAD \
        --patch FAULT.patch --suite scenarios/examples/wall_concrete.json --scenario scenarios/examples/wall.json --budget-flights 20

Prints each run's wall time, exit code, candidates and flights, then the medians and the median
of the warm/cold ratio measured in each pair (a ratio within one pair shares the machine's load).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def gate(argv: list[str], cache: Path, out: Path) -> dict:
    started = time.monotonic()
    done = subprocess.run([str(ROOT / ".venv" / "bin" / "stella"), "gate", *argv, "--cache", str(cache), "--out", str(out)],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    wall = time.monotonic() - started
    result = json.loads((out / "gate.json").read_text())
    flown = sum(search["flown"] for search in result["searches"])
    return {"wall_s": wall, "exit": done.returncode, "regressions": len(result["regressions"]), "search_flown": flown,
            "base": result["base"]["described"], "head": result["head"]["described"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("gate", nargs=argparse.REMAINDER, help="after --: the gate's options (not --cache or --out)")
    args = parser.parse_args()
    argv = [a for a in args.gate if a != "--"]
    cold, warm, ratios = [], [], []
    for run in range(1, args.runs + 1):
        cache = args.out / f"cache{run}"
        shutil.rmtree(cache, ignore_errors=True)
        first = gate(argv, cache, args.out / f"run{run}-cold")
        again = gate(argv, cache, args.out / f"run{run}-warm")
        cold.append(first["wall_s"])
        warm.append(again["wall_s"])
        ratios.append(again["wall_s"] / first["wall_s"])
        for name, entry in (("cold", first), ("warm", again)):
            print(f"run {run} {name}: {entry['wall_s']:.1f} s, exit {entry['exit']}, {entry['regressions']} regressions, "
                  f"{entry['search_flown']} search candidates flown; base {entry['base']}; head {entry['head']}")
    print(f"median cold {statistics.median(cold):.1f} s, warm {statistics.median(warm):.1f} s, "
          f"warm/cold {statistics.median(ratios):.2f} (each pair's ratio: {', '.join(f'{r:.2f}' for r in ratios)})")


if __name__ == "__main__":
    main()
