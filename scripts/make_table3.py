"""Writes scenarios/table3/*.json from the paper's Table III (scripts/table3_logical_scenarios.tsv).

Run once: `python scripts/make_table3.py`. The weather parameters the table does not list take
the profile's defaults (see scenarios/profiles/default.json, weather_defaults).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
KIND = {"ST": "static", "DY": "dynamic"}
SIZE = {"S": "small", "M": "medium", "L": "large"}
FORM = {"CU": "cuboid", "SP": "sphere", "CY": "cylinder"}


def scenario(row: dict[str, str]) -> dict:
    obstacles = [
        {"kind": KIND[row[f"kind{i}"]], "size": SIZE[row[f"size{i}"]], "form": FORM[row[f"form{i}"]]}
        for i in range(1, 5)
        if row[f"kind{i}"] != "-"
    ]
    assert len(obstacles) == int(row["n_obstacles"]), row
    return {
        "name": f"Table III scenario {int(row['id'])}",
        "system": {"UAVs": [{"maneuvers": ["take off", "move to waypoint", "land"]}]},
        "environment": {
            "flight area": {"landform": row["landform"], "surface nature": row["surface_nature"]},
            "obstacles": obstacles,
            "weather": {"wind force": row["wind"], "reduced visibility": row["reduced_visibility"]},
        },
    }


def main() -> None:
    out = ROOT / "scenarios" / "table3"
    out.mkdir(parents=True, exist_ok=True)
    with open(ROOT / "scripts" / "table3_logical_scenarios.tsv", newline="") as handle:
        for row in csv.DictReader(handle, delimiter="\t"):
            path = out / f"scenario_{int(row['id']):02d}.json"
            path.write_text(json.dumps(scenario(row), indent=2) + "\n")


if __name__ == "__main__":
    main()
