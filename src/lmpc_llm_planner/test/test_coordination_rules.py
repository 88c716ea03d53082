"""The coordination rule set and the coordinator core (issue 18), without a simulation."""
from __future__ import annotations

import json

import pytest

from lmpc_msgs_py.codec import DecodeError, encode
from lmpc_msgs_py.coordination import ConflictView, EgoStatus

from lmpc_llm_planner.coordination import (
    Coordination,
    CoordinatorCore,
    RulesCoordinator,
    SilentCoordinator,
)
from lmpc_llm_planner.coordination.rules import resolve

CID = "narrow:AB|BA"


def st(eid: str, via: str, entry: float, v: float = 5.0, *, hold: float | None = None,
       oncoming: tuple[str, ...] = (), t: float = 1.0) -> EgoStatus:
    hold = max(entry - 25.0, 0.0) if hold is None else hold
    view = ConflictView(conflict_id=CID, kind="narrow", via=via, dist_to_entry_m=entry,
                        dist_to_exit_m=entry + 60.0, dist_to_hold_m=hold,
                        inside=entry <= 0.0, oncoming=oncoming)
    return EgoStatus(stamp_s=t, seq=1, ego_id=eid, dist_to_target_m=200.0, v_mps=v,
                     intent="pass" if entry <= 0.0 else "approach", conflict=view)


def commands(statuses: list[EgoStatus], memory: dict | None = None) -> dict[str, str]:
    return {k: v.command for k, v in resolve(statuses, {} if memory is None else memory).items()}


def test_the_closer_ego_proceeds_the_other_yields() -> None:
    assert commands([st("ego_1", "AB_0", 60.0), st("ego_2", "BA_0", 40.0)]) == \
        {"ego_1": "yield", "ego_2": "proceed"}


def test_tie_goes_to_the_lower_id() -> None:
    assert commands([st("ego_2", "BA_0", 50.0), st("ego_1", "AB_0", 50.0)]) == \
        {"ego_1": "proceed", "ego_2": "yield"}


def test_an_ego_inside_or_too_fast_to_stop_goes_first() -> None:
    assert commands([st("ego_1", "AB_0", 0.0, 3.0), st("ego_2", "BA_0", 30.0, 2.0)]) == \
        {"ego_1": "proceed", "ego_2": "yield"}
    # 12 m/s needs 24 m to stop at 3 m/s^2: past its hold point 10 m ahead -> committed
    assert commands([st("ego_1", "AB_0", 70.0, 12.0, hold=10.0),
                     st("ego_2", "BA_0", 30.0, 2.0)])["ego_1"] == "proceed"


def test_same_direction_egos_go_together_before_the_other_direction() -> None:
    got = commands([st("ego_1", "AB_0", 30.0), st("ego_3", "AB_0", 45.0),
                    st("ego_2", "BA_0", 50.0)])
    assert got == {"ego_1": "proceed", "ego_3": "proceed", "ego_2": "yield"}


def test_a_foreign_vehicle_coming_the_other_way_makes_the_first_ego_wait() -> None:
    got = commands([st("ego_1", "AB_0", 30.0, oncoming=("bg0",)), st("ego_2", "BA_0", 80.0)])
    assert got["ego_1"] == "yield"


def test_memory_keeps_the_direction_while_its_ego_is_committed() -> None:
    memory: dict = {}
    commands([st("ego_1", "AB_0", 20.0, 8.0), st("ego_2", "BA_0", 40.0)], memory)
    assert memory[CID] == "AB_0"
    # ego_2 now closer to the entry than ego_1, but ego_1 is inside: it keeps the section
    assert commands([st("ego_1", "AB_0", 0.0, 8.0), st("ego_2", "BA_0", 26.0, 0.0)],
                    memory) == {"ego_1": "proceed", "ego_2": "yield"}
    # ego_1 left: the conflict is free, memory forgets it
    assert commands([st("ego_2", "BA_0", 26.0, 0.0)], memory) == {"ego_2": "proceed"}


def test_coordinator_directives_and_refusals() -> None:
    core = CoordinatorCore(RulesCoordinator(), period_s=1.0, ttl_s=3.0)
    out = core.on_statuses([st("ego_1", "AB_0", 60.0), st("ego_2", "BA_0", 40.0)], 1.0)
    assert {d.ego_id: d.command for d in out} == {"ego_1": "yield", "ego_2": "proceed"}
    assert all(d.deadline_s == pytest.approx(4.0) for d in out)
    assert core.on_statuses([st("ego_1", "AB_0", 60.0)], 1.5) == []  # not due yet
    text = encode(out[0])
    with pytest.raises(ValueError, match="unknown ego 'ego_1'"):
        core.receive(text, {"ego_2"})
    data = json.loads(text)
    data["command"] = "overtake"
    with pytest.raises(DecodeError, match="field 'command'"):
        core.receive(json.dumps(data), {"ego_1", "ego_2"})


def test_a_silent_coordinator_issues_nothing() -> None:
    core = CoordinatorCore(SilentCoordinator())
    assert core.on_statuses([st("ego_1", "AB_0", 60.0), st("ego_2", "BA_0", 40.0)], 1.0) == []


def test_coordination_refuses_bad_modes() -> None:
    from lmpc_msgs_py.vocabulary import load_decision_space

    with pytest.raises(ValueError, match="unknown coordination mode"):
        Coordination("chaos", ["ego_1"], load_decision_space())
    with pytest.raises(ValueError, match="needs a coordinator"):
        Coordination("central", ["ego_1"], load_decision_space())


def test_a_car_following_the_other_ego_through_holds_the_section() -> None:
    # ego_2 has left the section; bg0 behind it is inside (ego_1 cannot see that far)
    through = EgoStatus(stamp_s=1.0, seq=1, ego_id="ego_2", dist_to_target_m=40.0, v_mps=9.0,
                        intent="through", conflict=ConflictView(
                            conflict_id=CID, kind="narrow", via="BA_0", dist_to_entry_m=0.0,
                            dist_to_exit_m=0.0, inbound=("bg0",)))
    assert commands([st("ego_1", "AB_0", 26.0, 0.0), through]) == {"ego_1": "yield"}
    assert commands([st("ego_1", "AB_0", 26.0, 0.0), through.model_copy(
        update={"conflict": through.conflict.model_copy(update={"inbound": ()})})]) == \
        {"ego_1": "proceed"}
