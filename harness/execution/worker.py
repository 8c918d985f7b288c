"""One try of one evaluation as a process of its own: `python -m harness.execution.worker`.

Reads a job (JSON, `Job.to_json`) from a file or stdin, flies it, writes the result (JSON) to a
file or stdout. The Dask and Docker executors run evaluations this way, so that each has its
own process group and can be killed whole when it overruns.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from harness.execution.executor import Job, run_job
from harness.flight import stack
from harness.paths import write_atomically


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.execution.worker", description=__doc__.splitlines()[0])
    parser.add_argument("--job", help="job JSON file (default: stdin)")
    parser.add_argument("--result", help="where to write the result JSON (default: stdout)")
    args = parser.parse_args(argv)
    document = json.loads(Path(args.job).read_text() if args.job else sys.stdin.read())
    try:
        result = run_job(Job.from_json(document))
    finally:
        stack.close_kept()  # one job per process: nothing to keep it for
    text = json.dumps(result.as_dict())
    if args.result:
        write_atomically(Path(args.result), text.encode())
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
