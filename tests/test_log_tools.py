"""Reading logs back: topic listing, CSV export, diff of two runs, and the Foxglove layout."""

from __future__ import annotations

import csv
import json

import pytest

from conftest import ROOT
from harness.flight import logs
from harness.flight.evaluation import evaluate
from harness.scenario.logical import load_logical
from harness.scenario.space import SearchSpace
from harness.tools.cli import main
from sim_bridge.recording import TOPICS

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def runs(tmp_path_factory, profile):
    """The same concrete scenario flown twice with sensor seed 1 and once with seed 2."""
    space = SearchSpace(load_logical(ROOT / "tests" / "data" / "scenarios" / "one_dynamic_sphere.json", profile), profile)
    x = space.vector_from({"obstacle_1.north_m": 40.0, "obstacle_1.east_m": 15.0})
    out = tmp_path_factory.mktemp("logs")
    return {name: evaluate(space, x, seed=seed, out_dir=out, name=name) for name, seed in (("first", 1), ("again", 1), ("other_seed", 2))}


def run_cli(capsys, *argv) -> tuple[int, dict]:
    code = main([*argv, "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_topics_lists_every_channel_with_its_schema_count_and_span(runs, capsys):
    code, report = run_cli(capsys, "inspect", runs["first"].log_path, "--topics")
    assert code == 0
    rows = {row["topic"]: row for row in report["topics"]}
    assert {topic: row["schema"] for topic, row in rows.items()} == TOPICS
    assert all(row["messages"] > 0 and row["first_s"] <= row["last_s"] for row in rows.values())
    assert rows["/clearance"]["last_s"] <= runs["first"].sim_time_s


def test_csv_export_has_one_row_per_step_and_the_minimum_the_run_reported(runs, capsys, tmp_path):
    code, report = run_cli(capsys, "inspect", runs["first"].log_path, "--export", "csv", "--topic", "/clearance", "--topic", "/uav/state", "--out", str(tmp_path))
    assert code == 0 and sorted(report["exported"]) == [str(tmp_path / "clearance.csv"), str(tmp_path / "uav_state.csv")]
    with open(tmp_path / "clearance.csv") as stream:
        rows = list(csv.DictReader(stream))
    steps = sum(len(batch["t"]) for _topic, _ns, batch in logs.messages(runs["first"].log_path, ["/clearance"]))
    assert len(rows) == steps
    nearest = min(rows, key=lambda row: float(row["d"]))
    assert float(nearest["d"]) == runs["first"].min_clearance_m
    assert (float(nearest["t"]), nearest["o"]) == (runs["first"].min_clearance_at_s, runs["first"].min_clearance_obstacle)
    with open(tmp_path / "uav_state.csv") as stream:
        header = next(csv.reader(stream))
    assert header[:5] == ["log_time_s", "t", "north_m", "east_m", "up_m"] and "v_ned_m_s.2" in header and "motors.3" in header


def test_exporting_an_unknown_topic_names_the_topics_there_are(runs, capsys):
    assert main(["inspect", runs["first"].log_path, "--export", "csv", "--topic", "/nope"]) == 2
    assert "/nope not in" in capsys.readouterr().err


def test_diff_of_two_identical_runs_finds_nothing(runs, capsys):
    code, report = run_cli(capsys, "diff", runs["first"].log_path, runs["again"].log_path)
    assert code == 0 and report["identical"]
    assert report["same_inputs"] == {"concrete_scenario": True, "world": True, "sut": True}
    assert report["max_clearance_difference_m"] == 0.0 and report["clearance_divergence"] is None and report["path_divergence"] is None


def test_diff_finds_where_two_sensor_seeds_part(runs, capsys):
    code, report = run_cli(capsys, "diff", runs["first"].log_path, runs["other_seed"].log_path)
    assert code == 1 and not report["identical"]
    assert report["same_inputs"]["concrete_scenario"] and not report["same_inputs"]["world"]  # the world carries the seed
    # the vehicle sits on the ground until the mission starts, so the runs part only once it moves
    assert 0.0 < report["path_divergence"]["t_s"] < runs["first"].sim_time_s
    assert report["clearance_divergence"]["t_s"] <= report["path_divergence"]["t_s"] + 0.1
    code, loose = run_cli(capsys, "diff", runs["first"].log_path, runs["other_seed"].log_path, "--tolerance", "100")
    assert loose["clearance_divergence"] is None and loose["path_divergence"] is None
    assert loose["identical"] == (runs["first"].fitness == runs["other_seed"].fitness) and code == (0 if loose["identical"] else 1)


@pytest.fixture
def truncated(runs, tmp_path):
    """The first run's log cut at 60 % of its bytes, as a flight killed mid-way or a full disk leaves it."""
    whole = runs["first"].log_path
    cut = tmp_path / "cut.mcap"
    data = open(whole, "rb").read()
    cut.write_bytes(data[: len(data) * 6 // 10])
    return cut


def csv_rows(path) -> list[dict]:
    with open(path) as stream:
        return list(csv.DictReader(stream))


def test_a_truncated_log_is_read_up_to_the_damage_and_scored_on_what_it_holds(runs, truncated, capsys, tmp_path):
    code, report = run_cli(capsys, "inspect", str(truncated), "--export", "csv", "--topic", "/clearance", "--topic", "/uav/state", "--out", str(tmp_path / "csv"))
    assert code == 0 and report["partial"]
    size = truncated.stat().st_size
    assert 0 < report["truncation"]["readable_bytes"] <= size == report["truncation"]["size_bytes"]
    assert 0 < report["truncation"]["last_time_s"] < runs["first"].sim_time_s
    recorded = [(t, d, o) for _topic, _ns, batch in logs.messages(runs["first"].log_path, ["/clearance"])
                for t, d, o in zip(batch["t"], batch["d"], batch["o"]) if t <= report["truncation"]["last_time_s"] and d is not None]
    nearest = min(recorded, key=lambda entry: entry[1])
    assert (report["min_clearance_at_s"], report["min_clearance_m"]) == (nearest[0], nearest[1])
    assert report["fitness"] == nearest[1] - report["safety_distance_m"] and report["fitness_reproduced"] is None
    # what was read is exactly the beginning of the whole log
    main(["inspect", runs["first"].log_path, "--export", "csv", "--topic", "/uav/state", "--out", str(tmp_path / "whole"), "--json"])
    capsys.readouterr()
    partial_states, whole_states = csv_rows(tmp_path / "csv" / "uav_state.csv"), csv_rows(tmp_path / "whole" / "uav_state.csv")
    assert 0 < len(partial_states) < len(whole_states) and partial_states == whole_states[: len(partial_states)]
    assert main(["inspect", str(truncated)]) == 0
    assert "log truncated: readable up to byte" in capsys.readouterr().out


def test_diff_compares_a_truncated_log_up_to_its_damage(runs, truncated, capsys):
    code, report = run_cli(capsys, "diff", str(truncated), runs["first"].log_path)
    assert code == 1 and not report["identical"] and set(report["truncated"]) == {"a"}
    assert report["common_steps"] > 0 and report["steps_only_in_a"] == 0 and report["steps_only_in_b"] > 0
    assert report["clearance_divergence"] is None and report["path_divergence"] is None


def test_the_foxglove_layout_refers_to_what_the_logs_hold(runs):
    layout = json.loads((ROOT / "docs" / "foxglove_layout.json").read_text())
    panels = layout["configById"]
    three_d = panels["3D!stella3d"]
    frames = {message["child_frame_id"] for _topic, _ns, message in logs.messages(runs["first"].log_path, ["/tf"])}
    assert three_d["followTf"] in frames
    assert set(three_d["topics"]) <= set(TOPICS)
    plotted = {path["value"].split(".")[0] for path in panels["Plot!stellaclearance"]["paths"]}
    assert plotted <= set(TOPICS)
    assert panels["map!stellamap"]["followTopic"] in TOPICS and panels["RawMessages!stellaevents"]["topicPath"] in TOPICS

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)


def test_names_on_disk_are_slugs_of_whatever_a_scenario_is_called():
    from harness.flight.logs import slug

    assert slug("Holdout 2: three static obstacles") == "Holdout_2_three_static_obstacles"
    assert slug("Test Scenario #1-seed0") == "Test_Scenario_1-seed0"  # the names logs had before
    assert slug("::") == "scenario"
