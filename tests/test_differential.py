"""Differential evaluation's judgement (harness/flight/differential.py), stored pairs judged again
(harness/campaigns/rejudge.py) and the refusals of the --reference-* options: no flight."""

from __future__ import annotations

import fcntl
import json
from dataclasses import replace

import numpy as np
import pytest
from mcap.writer import Writer

from conftest import stored_result
from harness.campaigns.coverage import missed, withdrawn
from harness.campaigns.pairs import ReferenceCache
from harness.campaigns.regression import verdict
from harness.campaigns.store import Store
from harness.firmware import mutation
from harness.flight.differential import CLEARANCE_RESOLUTION_M, Difference, Outcome, Reveal, compare, objective_value, record
from harness.flight.results import EvaluationResult
from harness.flight.fitness import PENALTY, Status
from harness.tools.cli import main


def flight(status: Status, clearance: float | None, time_s: float = 40.0, safety_m: float = 1.0) -> Outcome:
    fitness = PENALTY if clearance is None else clearance - safety_m + (PENALTY if status == Status.MISSION_FAILED else 0.0)
    return Outcome(status, fitness, clearance, time_s)


def test_the_subject_violating_where_the_reference_keeps_its_distance_is_unsafe():
    verdict = compare([flight(Status.VIOLATION, 0.4)], [flight(Status.OK, 1.3)])
    assert verdict.reveals == Reveal.UNSAFE and "0.40 m" in verdict.why and "1.30 m" in verdict.why


def test_unsafe_needs_every_subject_flight_to_violate_and_no_reference_flight():
    assert compare([flight(Status.VIOLATION, 0.4), flight(Status.OK, 1.2)], [flight(Status.OK, 1.3)]).reveals != Reveal.UNSAFE
    assert compare([flight(Status.VIOLATION, 0.4)], [flight(Status.OK, 1.3), flight(Status.VIOLATION, 0.9)]).reveals != Reveal.UNSAFE


def test_blocked_where_the_reference_flies_through_is_a_behaviour_difference():
    # GIVEN the subject stopped 24 m before a wall that the reference passes at 1.3 m
    verdict = compare([flight(Status.MISSION_FAILED, 24.0)], [flight(Status.OK, 1.3)])
    assert verdict.reveals == Reveal.BEHAVIOUR and "mission_failed" in verdict.why


def test_clearances_differ_only_beyond_the_references_measured_spread():
    reference = [flight(Status.OK, 1.30), flight(Status.OK, 1.70)]  # 40 cm apart, as PX4's pilot flights can be
    assert compare([flight(Status.OK, 1.95)], reference).reveals is None  # 25 cm beyond, inside the spread
    assert compare([flight(Status.OK, 2.20)], reference).reveals == Reveal.BEHAVIOUR
    # With one flight a side, the resolution decides.
    assert compare([flight(Status.OK, 1.30 + CLEARANCE_RESOLUTION_M / 2)], [flight(Status.OK, 1.30)]).reveals is None
    assert compare([flight(Status.OK, 1.30 + 3 * CLEARANCE_RESOLUTION_M)], [flight(Status.OK, 1.30)]).reveals == Reveal.BEHAVIOUR


def test_flight_time_differs_as_a_behaviour_too():
    assert compare([flight(Status.OK, 1.3, 60.0)], [flight(Status.OK, 1.3, 40.0)]).reveals == Reveal.BEHAVIOUR
    assert compare([flight(Status.OK, 1.3, 40.4)], [flight(Status.OK, 1.3, 40.0)]).reveals is None


def landed(time_s: float, first_touchdown_s: float) -> Outcome:
    return Outcome(Status.OK, 0.3, 1.3, time_s, first_touchdown_s=first_touchdown_s)


def test_flights_are_timed_by_their_first_touchdown_so_the_hops_of_a_landing_reveal_nothing():
    # GIVEN PX4's landing as flown on m0020's 23rd wall candidate: both came down at 59.6-59.8 s,
    # the original hopped once and ended at 61-64 s, the mutant hopped up to four times
    reference = [landed(63.8, 59.67), landed(61.1, 59.70), landed(63.8, 59.68)]
    hopping = [landed(72.9, 59.64), landed(69.3, 59.81), landed(71.1, 59.75)]
    assert compare(hopping, reference).reveals is None
    # a subject that comes down later beyond the spread still reveals, timed by its touchdown
    late = compare([landed(75.0, 66.0)], reference)
    assert late.reveals == Reveal.BEHAVIOUR and late.difference == Difference.LONGER and late.why.startswith("touchdown 66.0 s")
    # outcomes recorded before the touchdown was kept (a cached reference) are timed as before, whole flights
    assert compare(hopping, [flight(Status.OK, 1.3, 63.8)]).why.startswith("flight time 72.9 s")


def test_a_revealing_case_holds_a_build_to_the_references_touchdown_not_its_hops():
    by_touchdown = {**REFERENCE, "difference": "longer", "first_touchdown_s": [59.6, 59.8]}
    del by_touchdown["sim_time_s"]
    hopping = EvaluationResult(**{**result_of(Status.OK, 15.72, 72.9).as_dict(), "first_touchdown_s": 59.7})
    assert verdict("as_reference", hopping, 1.0, by_touchdown) is None
    late = EvaluationResult(**{**result_of(Status.OK, 15.72, 72.9).as_dict(), "first_touchdown_s": 66.0})
    assert "touched down at 66.0 s where the reference build touched down at 59.6-59.8 s" in verdict("as_reference", late, 1.0, by_touchdown)
    assert "never touched down" in verdict("as_reference", result_of(Status.OK, 15.72, 72.9), 1.0, by_touchdown)


def test_a_behaviour_difference_says_by_what_from_the_subjects_side():
    reference = [flight(Status.OK, 2.0, 60.0), flight(Status.OK, 2.1, 61.0)]
    assert compare([flight(Status.MISSION_FAILED, 9.0)], reference).difference == Difference.STATUS
    assert compare([flight(Status.OK, 1.5, 60.0)], reference).difference == Difference.CLOSER
    assert compare([flight(Status.OK, 3.0, 60.0)], reference).difference == Difference.FARTHER
    assert compare([flight(Status.OK, 2.0, 50.0)], reference).difference == Difference.SHORTER
    assert compare([flight(Status.OK, 2.0, 70.0)], reference).difference == Difference.LONGER
    assert compare([flight(Status.VIOLATION, 0.4)], reference).difference is None  # unsafe: the safety distance says it


def result_of(status: Status, clearance: float, time_s: float) -> EvaluationResult:
    return EvaluationResult(status=status, fitness=clearance - 1.0, why=None, min_clearance_m=clearance, min_clearance_at_s=1.0,
                            min_clearance_obstacle="obstacle_1", sim_time_s=time_s, wall_time_s=1.0, real_time_factor=None, seed=0,
                            log_path=None, scenario="wall", sut="px4")


# What the fix of PX4's db13b9cb50 did on its own regression cases: its parent was blocked where
# the fix flew on, and the fix flew 3.4 s longer than on the two flights the case was made from.
REFERENCE = {"level": "behaviour", "min_clearance_m": 15.70, "max_clearance_m": 15.74, "tolerance_m": 0.05, "statuses": ["ok"],
             "sim_time_s": [79.1, 79.7], "time_tolerance_s": 1.0}


def test_a_revealing_case_holds_the_build_to_what_revealed_it_and_to_the_references_safety():
    # GIVEN a case revealed by the subject's status: the good build passes it although its flight
    # time lies beyond the two reference flights' spread; the bad build, blocked, fails it
    by_status = {**REFERENCE, "difference": "status"}
    assert verdict("as_reference", result_of(Status.OK, 15.78, 83.1), 1.0, by_status) is None
    assert "not flown to its end" in verdict("as_reference", result_of(Status.MISSION_FAILED, 13.2, 46.0), 1.0, by_status)
    # a case revealed by a longer flight fails a longer flight only
    by_time = {**REFERENCE, "difference": "longer"}
    assert "flew 83.1 s" in verdict("as_reference", result_of(Status.OK, 15.72, 83.1), 1.0, by_time)
    assert verdict("as_reference", result_of(Status.OK, 15.72, 70.0), 1.0, by_time) is None
    # coming closer than the reference fails whatever revealed the case
    assert "came closer" in verdict("as_reference", result_of(Status.OK, 12.0, 79.5), 1.0, by_time)
    # a case written before `difference` holds the flight to every aspect, as it did
    assert "flew 83.1 s" in verdict("as_reference", result_of(Status.OK, 15.78, 83.1), 1.0, REFERENCE)


def test_a_side_that_could_not_finish_reveals_nothing():
    verdict = compare([flight(Status.VIOLATION, 0.4)], [Outcome(Status.SUT_CRASHED, PENALTY, None, 0.0, "px4 exited")])
    assert verdict.reveals is None and not verdict.comparable and "reference could not finish" in verdict.why


def test_a_subject_whose_sut_dies_in_every_flight_where_the_reference_flies_is_unsafe():
    """A mutant's `now % 0` kills PX4 in the air (SIGFPE) where the original flies on: a kill,
    not a pair that could not be compared."""
    died = Outcome(Status.SUT_CRASHED, PENALTY, None, 11.0, "px4 died of SIGFPE (Floating point exception)")
    verdict = compare([died, died, died], [flight(Status.MISSION_FAILED, 2.6), flight(Status.OK, 2.7), flight(Status.OK, 2.6)])
    assert verdict.reveals == Reveal.UNSAFE and "SUT died in flight (px4 died of SIGFPE" in verdict.why and "mission_failed/ok" in verdict.why
    # once of three is the infrastructure's or the spread's, not the build's
    assert compare([died, flight(Status.OK, 2.6)], [flight(Status.OK, 2.7)]).reveals is None
    assert compare([died], [Outcome(Status.TIMEOUT, PENALTY, None, 0.0, "timed out")]).reveals is None


def test_the_difference_objective_is_lowest_where_the_subject_comes_closer():
    closer, same = objective_value("difference", flight(Status.OK, 1.1), flight(Status.OK, 2.0)), \
        objective_value("difference", flight(Status.OK, 2.0), flight(Status.OK, 2.0))
    assert closer == pytest.approx(-0.9) and same == 0.0
    # Blocked by collision prevention (the pilot drive's safe end at a wall) compares by clearance,
    # on either side: a subject that flies into the wall where the reference holds it back scores lowest.
    assert objective_value("difference", flight(Status.VIOLATION, 0.3), flight(Status.MISSION_FAILED, 1.6)) == pytest.approx(-1.3)
    assert objective_value("difference", flight(Status.MISSION_FAILED, 5.0), flight(Status.OK, 2.0)) == pytest.approx(3.0)
    # A reference that could not finish its flight leaves nothing to compare: the penalty; a
    # subject whose SUT died where the reference flew scores as if it had touched the obstacle.
    crashed = Outcome(Status.SUT_CRASHED, PENALTY, None, 0.0, "px4 died of SIGFPE (Floating point exception)")
    assert objective_value("difference", flight(Status.OK, 1.1), crashed) == PENALTY
    assert objective_value("difference", crashed, flight(Status.OK, 1.1)) == pytest.approx(-1.1)
    assert objective_value("difference", crashed, crashed) == PENALTY
    assert objective_value("subject", flight(Status.OK, 1.1), flight(Status.OK, 2.0)) == pytest.approx(0.1)


def test_a_record_keeps_both_sides_flights_and_the_verdict():
    document = record("subject", [flight(Status.VIOLATION, 0.4)], [flight(Status.OK, 1.3), flight(Status.OK, 1.4)])
    assert document["reveals"] == "unsafe" and len(document["subject"]) == 1 and len(document["reference"]) == 2
    assert Outcome.from_dict(document["reference"][1]).min_clearance_m == 1.4
    # a flight stored by a later version, with a field this one does not know, still reads
    assert Outcome.from_dict({**document["reference"][1], "landing_hops": 3}) == Outcome.from_dict(document["reference"][1])


def flight_log(path, touchdowns: list[float]) -> str:
    """A flight's log as far as re-judging reads it: its touchdown events."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        channel = writer.register_channel("/events", "json", writer.register_schema("event", "jsonschema", b"{}"))
        for t in touchdowns:
            writer.add_message(channel, log_time=int(t * 1e9), publish_time=int(t * 1e9), data=json.dumps({"t": t, "event": "touchdown"}).encode())
        writer.finish()
    return str(path)


def hop_store(path, logs_dir, confirm: int = 2) -> list[dict]:
    """A differential search stored by a version that timed pairs by the whole flight, confirmed
    with two more flights a side (by default): candidate 2 "revealed" only by the hops of the
    landings (both sides came down at 59.6-59.8 s), candidate 3 by its clearance; candidate 1
    revealed nothing and was flown once a side, although it came down 2.3 s after the reference.
    Its pairs."""
    def side(name, clearance, flights):
        return [Outcome(Status.OK, clearance - 1.0, clearance, time_s, log_path=flight_log(logs_dir / f"{name}{i}.mcap", touchdowns))
                for i, (time_s, touchdowns) in enumerate(flights)]

    reference = side("reference", 1.30, [(63.8, [59.67, 61.5]), (61.1, [59.70]), (63.8, [59.68, 61.6])])
    pairs = [record("difference", side("late", 1.30, [(63.6, [62.0])]), reference[:1]),
             record("difference", side("hopping", 1.30, [(72.9, [59.64, 61.9, 64.0, 66.8]), (69.3, [59.81, 62.2]), (71.1, [59.75, 63.0])]), reference),
             record("difference", side("closer", 0.90, [(63.7, [59.69]), (63.9, [59.70]), (63.5, [59.66])]), reference)]
    assert [p["reveals"] for p in pairs] == [None, "behaviour", "behaviour"] and pairs[1]["why"].startswith("flight time")
    path.parent.mkdir(parents=True, exist_ok=True)
    with Store(path) as store:
        config = {"scenarios": ["wall.json"], "reference": {"sut": "px4"}, **({"confirm": confirm} if confirm else {})}
        run_id, _ = store.run(store.campaign(config), "wall.json", "wall", "RANDOM", 0, 0)
        for ordinal, pair in enumerate(pairs):
            result = replace(stored_result(pair["fitness"], "ok", min_clearance_m=pair["subject"][0]["min_clearance_m"]), differential=pair)
            store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer="RANDOM", vector=np.array([float(ordinal)]), result=result, concrete=None)
    return pairs


def test_stored_reveals_by_a_landings_hops_are_withdrawn_when_judged_again_by_first_touchdown(tmp_path, capsys):
    # GIVEN a mutant's finished search stored by an older version (hop_store), another search of
    # it under way, and the reference flight they share cached without its touchdown
    folder = tmp_path / "mutation"
    finished, under_way = folder / "search" / "m0001" / "wall-RANDOM.db", folder / "search" / "m0001" / "scenario_13-NSGAII.db"
    pairs = hop_store(finished, tmp_path)
    hop_store(under_way, tmp_path)
    with Store.existing(finished) as store:
        stored_search = store.first_reveals()
    assert stored_search["evaluation"] == 2
    (folder / mutation.RUN).write_text(json.dumps({"screening": {}, "searching": {}, "mutants": {
        "m0001": {"state": "survived_suite", "suite_flights": 1, "search": {"RANDOM": {"wall": stored_search}}}}}))
    mutant_index(folder)
    cache = ReferenceCache(folder / mutation.CACHE)
    cache.put("wall", [Outcome.from_dict(pairs[0]["reference"][0])])
    cache.close()

    # (not while another process works on the folder: it would write back its own verdicts)
    with open(folder / mutation.LOCK, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        assert main(["mutants", "rejudge", str(folder)]) == 2
        assert "another `stella mutants run`, `rejudge` or `recheck` is working on this folder" in capsys.readouterr().err

    # WHEN the folder is judged again
    assert main(["mutants", "rejudge", str(folder)]) == 0

    # THEN the hop reveals are withdrawn and said so, in both searches; the clearance reveal is now
    # the finished search's first kill
    said = capsys.readouterr().out
    assert "m0001 evaluation 2 (wall RANDOM run 0): behaviour (flight time 72.9 s" in said and "-> no reveal" in said and "2 stored verdicts changed" in said
    search = json.loads((folder / mutation.RUN).read_text())["mutants"]["m0001"]["search"]["RANDOM"]["wall"]
    assert search == {**stored_search, "evaluation": 3}
    for path in (finished, under_way):
        with Store.existing(path) as store:
            late, hopping, _closer = (e.differential for e in store.pairs())
            # a reveal needs confirmation flights that candidate 1 never had: re-judging adds none
            assert late == pairs[0]
            assert hopping["reveals"] is None and [o["first_touchdown_s"] for o in hopping["subject"]] == [59.64, 59.81, 59.75]
    # and the cached reference flight, which pairs flown from now on are judged with, has its touchdown
    cache = ReferenceCache(folder / mutation.CACHE)
    assert [o.first_touchdown_s for _key, outcomes in cache.items() for o in outcomes] == [59.67]
    cache.close()
    # judged again, nothing changes
    assert main(["mutants", "rejudge", str(folder)]) == 0
    assert "0 stored verdicts changed" in capsys.readouterr().out


def mutant_index(folder, line: int = 120) -> None:
    """The folder's mutants.json: m0001 changes that line of the bundled autopilot's collision prevention."""
    from harness.firmware import mutants

    (folder / mutants.INDEX).write_text(json.dumps({"format": mutants.FORMAT, "mutants": [{"id": "m0001", "file": "autopilot/collision.py", "line": line}]}))


def test_a_stored_reveal_whose_subject_never_ran_the_mutated_line_is_withdrawn_when_judged_again(tmp_path, capsys):
    # GIVEN a coverage build's search of mutant m0001 (line 120 mutated): two candidates revealed
    # alike (0.90 m against 1.30 m, confirmed), one of them in a flight that never ran line 120
    folder = tmp_path / "mutation"
    store_path = folder / "search" / "m0001" / "wall-RANDOM.db"
    closer = hop_store(tmp_path / "flown.db", tmp_path)[2]
    store_path.parent.mkdir(parents=True)
    with Store(store_path) as store:
        run_id, _ = store.run(store.campaign({"scenarios": ["wall.json"], "reference": {"sut": "bundled"}, "confirm": 2}), "wall.json", "wall", "RANDOM", 0, 0)
        for ordinal, hit in enumerate(([119, 120], [119, 121])):
            coverage = {"tool": "coverage.py", "sources": "", "files": {"autopilot/collision.py": {
                "lines_hit": hit, "lines_missed": sorted({119, 120, 121} - set(hit)), "branches_hit": [], "branches_missed": []}}}
            result = replace(stored_result(closer["fitness"], "ok", min_clearance_m=0.90), differential=closer, coverage=coverage)
            store.add_evaluation(run_id, ordinal=ordinal, step=0, optimizer="RANDOM", vector=np.array([float(ordinal)]), result=result, concrete=None)
    (folder / mutation.RUN).write_text(json.dumps({"screening": {}, "searching": {}, "mutants": {"m0001": {"state": "survived_suite"}}}))
    mutant_index(folder)

    # (and a third, withdrawn when flown as a confirmation flight never ran the line, although the first, whose record is stored, did)
    with Store(store_path) as store:
        coverage = {"tool": "coverage.py", "sources": "", "files": {"autopilot/collision.py": {
            "lines_hit": [120], "lines_missed": [], "branches_hit": [], "branches_missed": []}}}
        result = replace(stored_result(closer["fitness"], "ok", min_clearance_m=0.90), differential=withdrawn(closer, ["autopilot/collision.py:L120"], [1]),
                         coverage=coverage)
        store.add_evaluation(run_id, ordinal=2, step=0, optimizer="RANDOM", vector=np.array([2.0]), result=result, concrete=None)

    assert main(["mutants", "rejudge", str(folder)]) == 0

    # THEN the reveal of the flight that ran line 120 stands, the other is withdrawn as the SUT's own spread, and the third stays withdrawn
    assert "1 stored verdict changed" in capsys.readouterr().out
    with Store.existing(store_path) as store:
        ran, never, confirmation_never = (e.differential for e in store.pairs())
    assert ran["reveals"] == "behaviour" and confirmation_never["reveals"] is None
    assert never["reveals"] is None and never["why"] == (f"the subject never ran autopilot/collision.py:L120, by its coverage: what differed "
                                                         f"({closer['why']}) is the SUT's own spread")


def test_a_mutant_whose_sut_dies_in_the_changed_line_keeps_its_kill_though_its_coverage_says_it_never_ran_it(tmp_path, capsys):
    # GIVEN a coverage build's search of mutant m0001 (line 120 a division by zero): its PX4 died
    # in every flight where the original flew; gcov counts a block's lines as the block is left, so
    # the record PX4 wrote on its way out says line 120 never ran, and the last version withdrew the
    # unsafe reveal for it (marked without the flights' indices)
    folder = tmp_path / "mutation"
    store_path = folder / "search" / "m0001" / "wall-RANDOM.db"
    store_path.parent.mkdir(parents=True)
    died = Outcome(Status.SUT_CRASHED, PENALTY, None, 12.0, "px4 died of SIGFPE (Floating point exception)")
    pair = record("difference", [died] * 3, [flight(Status.OK, 1.3)] * 3)
    assert pair["reveals"] == "unsafe"
    lines = ["autopilot/collision.py:L120"]
    coverage = {"tool": "gcov", "sources": "", "files": {"autopilot/collision.py": {
        "lines_hit": [119], "lines_missed": [120], "branches_hit": [], "branches_missed": []}}}
    with Store(store_path) as store:
        run_id, _ = store.run(store.campaign({"scenarios": ["wall.json"], "reference": {"sut": "px4"}, "confirm": 2}), "wall.json", "wall", "RANDOM", 0, 0)
        result = replace(stored_result(PENALTY, "sut_crashed"), differential={**withdrawn(pair, lines, [0]), "missed_changed_lines": True}, coverage=coverage)
        store.add_evaluation(run_id, ordinal=0, step=0, optimizer="RANDOM", vector=np.array([0.0]), result=result, concrete=None)
    (folder / mutation.RUN).write_text(json.dumps({"screening": {}, "searching": {}, "mutants": {"m0001": {"state": "survived_suite"}}}))
    mutant_index(folder)
    # (a flight whose SUT died is not judged by its coverage; one that flew on is)
    assert not missed(Status.SUT_CRASHED, coverage, lines) and missed(Status.OK, coverage, lines)

    # WHEN the search is judged again
    assert main(["mutants", "rejudge", str(folder)]) == 0

    # THEN the kill is back
    assert "1 stored verdict changed" in capsys.readouterr().out
    with Store.existing(store_path) as store:
        assert store.pairs()[0].differential["reveals"] == "unsafe"


def test_a_differential_campaigns_store_is_judged_again_too(tmp_path, capsys):
    # GIVEN a campaign that confirmed nothing (--confirm 0), one of whose flights lost its log
    hop_store(tmp_path / "diff.db", tmp_path, confirm=0)
    (tmp_path / "closer1.mcap").unlink()
    # a store that is no differential campaign among those given changes nothing
    with Store(tmp_path / "plain.db") as store:
        store.campaign({"scenarios": ["wall.json"]})
    assert main(["rejudge", str(tmp_path / "diff.db"), str(tmp_path / "plain.db")]) == 2
    assert "not a differential campaign" in capsys.readouterr().err
    with Store.existing(tmp_path / "diff.db") as store:
        assert [e.ordinal for e in store.revealing_cases()] == [2, 1]

    assert main(["rejudge", str(tmp_path / "diff.db")]) == 0

    said = capsys.readouterr().out
    # THEN the hop reveal is withdrawn, and the late touchdown is a reveal now: one flight a side
    # was all this campaign flew of any pair
    assert "evaluation 2 (wall RANDOM run 0): behaviour (flight time 72.9 s" in said and "2 stored verdicts changed" in said
    assert "evaluation 1 (wall RANDOM run 0): no reveal (no difference beyond the reference's spread) -> behaviour (touchdown 62.0 s" in said
    assert f"the logs of 1 flight are gone (e.g. {tmp_path / 'closer1.mcap'})" in said
    with Store.existing(tmp_path / "diff.db") as store:
        assert sorted(e.ordinal for e in store.revealing_cases()) == [0, 2]


@pytest.mark.parametrize("argv, message", [
    (["--objective", "difference"], "difference needs a reference SUT"),
    (["--reference-sut-param", "CP_DIST=1.0", "--sut-param", "CP_DIST=1.0"], "the reference is the subject itself"),
    (["--reference-sut", "px4", "--reference-px4-bin", "/nonexistent/px4"], "is not an executable px4 binary"),
    (["--reference-sut-param", "CP_DISTANCE=2"], "unknown parameter"),
    (["--reference-sut", "ardupilot", "--reference-ardupilot-bin", "/nonexistent/arducopter"], "no executable arducopter"),
])
def test_a_bad_reference_is_refused_with_the_option_named(argv, message, capsys, tmp_path):
    assert main(["campaign", "scenarios/examples/wall.json", "--algorithm", "RANDOM", "--evaluations", "2", "--store", str(tmp_path / "c.db"), *argv]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "c.db").exists()
