"""A screen's correction learned across stores (`stella campaign ... --screen-learn-from STORE`).

The correction learns how the cheap model errs about one subject: from the candidates flown both
ways in this campaign and, with this option, in earlier screened campaigns of the same subject
(the same build, parameters, seeded fault and reference), drive, profile and cheap model, for the
same scenarios (by content). What else differs between the campaigns (algorithm, budget, seed,
share of each batch) changes which candidates were flown, not what a flight of one gives, so it
does not matter.

The pairs are copied into this campaign's store when it begins, as the other store holds them
then (it is only read): a resumed campaign learns from the same pairs, whatever became of the other store since,
and so decides each new batch as it would have without the interruption. For the same reason a
campaign that has begun learns from no new store.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

from harness.campaigns.store import Store
from harness.errors import InputError, Problem

# What makes a flight of a candidate the same flight in two campaigns (CampaignConfig._identity).
SAME_FLIGHTS = ("profile", "drive", "sut", "sut_params", "sut_build", "sut_fault", "reference", "subject", "objective", "properties")


def _differences(theirs: Mapping[str, Any], ours: Mapping[str, Any]) -> list[str]:
    fields = [name for name in SAME_FLIGHTS if theirs.get(name) != ours.get(name)]
    if theirs.get("screen", {}).get("sut") != ours.get("screen", {}).get("sut"):
        fields.append("screen/sut")
    return fields


def _learnable(path: Path, ours: Mapping[str, Any], scenario_keys: set[str]) -> list[dict[str, Any]]:
    """The other store's candidates flown both ways of these scenarios, or why it has none to give."""
    def refused(why: str) -> InputError:
        return InputError([Problem("--screen-learn-from", "", f"{path}: {why}")])

    if not path.is_file():
        raise refused("no such campaign store: give the --store file of an earlier screened campaign")
    with Store.read_only(path) as other:
        theirs = other.campaign_config()
        if "screen" not in theirs:
            raise refused("its campaign was not screened (--screen none): it has no cheap flights to learn from")
        differences = _differences(theirs, ours)
        if differences:
            shown = ", ".join(f"{name} {theirs.get(name)!r} where this campaign has {ours.get(name)!r}" for name in differences if "/" not in name)
            raise refused(f"its campaign flew other flights ({shown or 'another cheap model'}): a correction learns how the cheap model errs "
                          "about one subject, build, drive and profile; give a store of the same")
        pairs = [pair for pair in other.flown_both_ways() if pair["scenario_key"] in scenario_keys]
    if not pairs:
        raise refused("has no candidate flown both ways of this campaign's scenarios (as their documents are now)")
    return pairs


def pairs_to_learn(store: Store, ours: Mapping[str, Any], scenario_keys: set[str], paths: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
    """The candidates flown both ways of these scenarios in the stores at `paths` that `store`
    has not copied yet, by store, each store checked (read only) before any is returned; nothing
    is written, so a refused store leaves `store` as it was. Store.learn_screen_pairs keeps them."""
    learned = store.screen_sources()
    sources = {str(Path(path).resolve()): Path(path) for path in paths}
    own = str(store.path.resolve())
    if own in sources:
        raise InputError([Problem("--screen-learn-from", "", f"{sources[own]} is this campaign's own store: its runs learn from its earlier ones already")])
    new = {source: path for source, path in sources.items() if source not in learned}
    if new and store.runs():
        began = ", ".join(learned) if learned else "no other store"
        raise InputError([Problem("--screen-learn-from", "", f"{next(iter(new.values()))}: this campaign began learning from {began}, and learns "
                                                             "from no store it did not begin with (its decisions would depend on when it was "
                                                             "resumed): leave out --screen-learn-from to resume it, or start a new --store")])
    return {source: _learnable(path, ours, scenario_keys) for source, path in new.items()}
