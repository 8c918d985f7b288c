"""A long campaign watched for leaks: resources sampled as it goes, killed with SIGKILL once and
resumed, then its store checked for evaluations lost or flown twice.

    .venv/bin/python scripts/soak.py --out runs/soak --evaluations 20000 --workers 2 --kill-after-s 1200 \
        [--scenario scenarios/examples/fig4.json] [--stop-after-s S] [-- EXTRA CAMPAIGN OPTIONS, e.g. --sut px4 --drive pilot --sut-logs violations]

A PX4 soak keeps each flight's ULog unless told otherwise (`--sut-logs`): about 40 MB with its
MCAP for a pilot flight of fig4, so 2,000 flights want 80 GB; `--sut-logs violations` keeps the
violating flights' only.

Every --sample-s it writes a row to OUT/samples.csv: evaluations stored, and of the campaign's
process tree (the campaign, its workers, their simulators and SUTs) the processes, their summed
and largest resident memory and open files; machine-wide, stella's temporary folders, the files
in /dev/shm and the sockets bound. At the end it prints those figures for the first and the
last thousand evaluations, and whether every candidate of the run is stored exactly once.
"""

from __future__ import annotations

import argparse
import csv
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIELDS = ["wall_s", "evaluations", "processes", "rss_mb_total", "rss_mb_largest", "largest", "open_files", "temp_folders", "shm_files", "sockets"]


def tree(root: int) -> list[int]:
    """The process and its descendants, from /proc."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                parent = int(Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(parent, []).append(int(entry))
    found, frontier = [], [root]
    while frontier:
        pid = frontier.pop()
        found.append(pid)
        frontier.extend(children.get(pid, []))
    return found


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def sample(root: int, store: Path, started: float) -> dict:
    memory, files, names = {}, 0, {}
    for pid in tree(root):
        try:
            memory[pid] = rss_mb(pid)
            files += len(os.listdir(f"/proc/{pid}/fd"))
            names[pid] = Path(f"/proc/{pid}/comm").read_text().strip()
        except OSError:  # gone meanwhile
            continue
    largest = max(memory, key=memory.get) if memory else None
    sockets = sum(max(0, len(Path(f"/proc/net/{kind}").read_text().splitlines()) - 1) for kind in ("tcp", "tcp6", "udp", "udp6", "unix"))
    return {"wall_s": round(time.monotonic() - started, 1), "evaluations": stored(store), "processes": len(memory),
            "rss_mb_total": round(sum(memory.values()), 1), "rss_mb_largest": round(memory[largest], 1) if largest else 0.0,
            "largest": names.get(largest, ""), "open_files": files,
            "temp_folders": sum(1 for entry in Path(tempfile.gettempdir()).iterdir() if entry.name.startswith("stella-")),
            "shm_files": len(os.listdir("/dev/shm")), "sockets": sockets}


def stored(store: Path) -> int:
    if not store.exists():
        return 0
    with sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=30) as db:
        try:
            return db.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0]
        except sqlite3.OperationalError:  # not made yet
            return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--scenario", default=str(ROOT / "scenarios" / "examples" / "fig4.json"))
    parser.add_argument("--evaluations", type=int, default=20_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--kill-after-s", type=float, default=1200.0, help="SIGKILL the campaign's process group this long after its start, then resume it")
    parser.add_argument("--stop-after-s", type=float, help="end the soak (Ctrl-C to the campaign) after this long, done or not")
    parser.add_argument("--sample-s", type=float, default=30.0)
    parser.add_argument("extra", nargs="*", help="more campaign options, after --")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    store = args.out / "soak.db"
    command = [str(ROOT / ".venv" / "bin" / "stella"), "campaign", args.scenario, "--algorithm", "RANDOM", "--evaluations", str(args.evaluations),
               "--workers", str(args.workers), "--store", str(store), "--json", *args.extra]
    started = time.monotonic()
    killed = False
    with open(args.out / "samples.csv", "w", newline="") as out, open(args.out / "campaign.log", "ab") as log:
        writer = csv.DictWriter(out, FIELDS)
        writer.writeheader()
        while True:
            campaign = subprocess.Popen(command, stdout=log, stderr=log, start_new_session=True)
            next_sample = time.monotonic()
            while campaign.poll() is None:
                now = time.monotonic()
                if now >= next_sample:
                    writer.writerow(sample(campaign.pid, store, started))
                    out.flush()
                    next_sample = now + args.sample_s
                if not killed and now - started >= args.kill_after_s:
                    os.killpg(campaign.pid, signal.SIGKILL)
                    campaign.wait()
                    killed = True
                    print(f"killed with SIGKILL after {now - started:.0f} s at {stored(store)} evaluations; resuming", flush=True)
                    break
                if args.stop_after_s is not None and now - started >= args.stop_after_s:
                    campaign.send_signal(signal.SIGINT)
                    campaign.wait()
                    break
                time.sleep(1.0)
            else:
                break
            if args.stop_after_s is not None and time.monotonic() - started >= args.stop_after_s:
                break
    report(args.out / "samples.csv", store)
    return 0


def report(samples_file: Path, store: Path) -> None:
    with open(samples_file) as samples:
        rows = [row for row in csv.DictReader(samples)]
    with sqlite3.connect(f"file:{store}?mode=ro", uri=True) as db:
        runs = db.execute("SELECT run_id, COUNT(*), COUNT(DISTINCT ordinal), MIN(ordinal), MAX(ordinal), COUNT(DISTINCT vector_key) FROM evaluations GROUP BY run_id").fetchall()
    for run_id, count, ordinals, lowest, highest, vectors in runs:
        whole = count == ordinals == highest - lowest + 1 and lowest == 0
        print(f"run {run_id}: {count} evaluations stored, ordinals {lowest}-{highest}, {vectors} distinct candidates: "
              + ("none lost, none twice" if whole else "GAPS OR DOUBLES"))
    thousands = [row for row in rows if int(row["evaluations"]) >= 1000]
    for label, chosen in (("first thousand on", thousands[:3]), ("last", thousands[-3:])):
        for row in chosen:
            print(label, {key: row[key] for key in FIELDS})


if __name__ == "__main__":
    sys.exit(main())
