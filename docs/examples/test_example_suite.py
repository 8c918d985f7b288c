"""Hand-written scenario tests with the stella pytest plugin (installed with stella-uav).

Run from the repository root: `pytest docs/examples/`. Each flight's MCAP log lands in
stella-logs/ and its path in the JUnit XML (`--junitxml`) as the property `stella_log`.
"""

import pytest


@pytest.mark.scenario("scenarios/examples/fig4.json", seed=1)
def test_fig4_is_flown_with_the_safety_distance_kept(flight):
    assert flight.status == "ok", flight.why
    assert flight.min_clearance_m > 1.0


def test_moving_the_building_onto_the_route_costs_clearance(fly):
    # Fig. 4's route runs 60 m north from the origin; the building is obstacle_2, 10-20 m wide.
    aside = fly("scenarios/examples/fig4.json", seed=1, obstacle_2__north_m=30.0, obstacle_2__east_m=-30.0)
    on_route = fly("scenarios/examples/fig4.json", seed=1, obstacle_2__north_m=30.0, obstacle_2__east_m=-13.0)
    assert on_route.min_clearance_m < aside.min_clearance_m
    assert on_route.status in ("ok", "violation"), on_route.why
