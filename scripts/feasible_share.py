"""The share of uniformly sampled points of each Table III scenario that keep every realism
constraint: what a random search flies of what it draws, and NSGA-II's first generation.

    .venv/bin/python scripts/feasible_share.py [--samples 20000] [--seed 0] [--cuboids]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.scenario.logical import load_logical
from harness.scenario.profile import load_profile
from harness.scenario.space import SearchSpace

TABLE3 = Path(__file__).resolve().parent.parent / "scenarios" / "table3"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cuboids", action="store_true", help="only the scenarios with a cuboid obstacle")
    args = parser.parse_args()
    profile = load_profile("default")
    for path in sorted(TABLE3.glob("scenario_*.json")):
        space = SearchSpace(load_logical(path, profile), profile)
        obstacles = space.logical.obstacles
        if args.cuboids and not any(o.form == "cuboid" for o in obstacles):
            continue
        share = space.feasible(space.sample(np.random.default_rng(args.seed), args.samples)).mean()
        print(f"{path.stem}  {share:.3f}  {' '.join(f'{o.kind} {o.form}' for o in obstacles)}")


if __name__ == "__main__":
    main()
