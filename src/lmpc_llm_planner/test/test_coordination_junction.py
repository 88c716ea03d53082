"""The rule set on the junction and merge conflicts of ``usi-multi`` / ``merge`` (issue 18):
one movement holds the junction zone at a time, ranked as in a narrow section."""
from __future__ import annotations

from lmpc_msgs_py.coordination import ConflictView, EgoStatus

from lmpc_llm_planner.coordination import CoordinatorCore, RulesCoordinator
from lmpc_llm_planner.coordination.rules import resolve

JID = "junction:C"
MID = "merge:J"


def st(eid: str, via: str, entry: float, v: float = 5.0, *, cid: str = JID,
       exit_m: float | None = None, oncoming: tuple[str, ...] = ()) -> EgoStatus:
    kind = cid.split(":")[0]
    exit_m = entry + 20.0 if exit_m is None else exit_m
    view = ConflictView(conflict_id=cid, kind=kind, via=via, dist_to_entry_m=entry,
                        dist_to_exit_m=exit_m, dist_to_hold_m=max(entry - 1.0, 0.0),
                        inside=entry <= 0.0 < exit_m, oncoming=oncoming)
    intent = "through" if exit_m <= 0.0 else ("pass" if entry <= 0.0 else "approach")
    return EgoStatus(stamp_s=1.0, seq=1, ego_id=eid, dist_to_target_m=90.0, v_mps=v,
                     intent=intent, conflict=view)


def verdicts(statuses, memory=None):
    return resolve(statuses, {} if memory is None else memory)


def test_four_movements_one_at_a_time_closest_first() -> None:
    got = verdicts([st("ego_1", ":C_4_0", 40.0), st("ego_2", ":C_8_0", 30.0),
                    st("ego_3", ":C_0_0", 55.0), st("ego_4", ":C_10_0", 30.0)])
    assert {k: v.command for k, v in got.items()} == {
        "ego_1": "yield", "ego_2": "proceed", "ego_3": "yield", "ego_4": "yield"}
    # ranks: distance to the stop line, ties by id
    assert [got[e].priority for e in ("ego_2", "ego_4", "ego_1", "ego_3")] == [0, 1, 2, 3]


def test_the_next_movement_goes_when_the_first_has_left_the_junction() -> None:
    memory: dict = {}
    verdicts([st("ego_1", ":C_4_0", 20.0), st("ego_2", ":C_8_0", 10.0, 8.0)], memory)
    assert memory[JID] == ":C_8_0"
    # ego_2 inside (committed): it keeps the zone though ego_1 is now closer to its line
    mid = verdicts([st("ego_1", ":C_4_0", 2.0, 0.0), st("ego_2", ":C_8_0", 0.0, 8.0,
                                                        exit_m=6.0)], memory)
    assert mid["ego_1"].command == "yield" and mid["ego_2"].command == "proceed"
    # ego_2's rear left the junction: ego_1 goes
    after = verdicts([st("ego_1", ":C_4_0", 2.0, 0.0),
                      st("ego_2", ":C_8_0", 0.0, 8.0, exit_m=0.0)], memory)
    assert {k: v.command for k, v in after.items()} == {"ego_1": "proceed"}


def test_an_ego_too_fast_to_stop_before_the_line_goes_first() -> None:
    # 9 m/s needs 13.5 m at 3 m/s^2; its hold point is 11 m ahead: committed
    got = verdicts([st("ego_1", ":C_4_0", 12.0, 9.0), st("ego_2", ":C_8_0", 5.0, 2.0)])
    assert got["ego_1"].command == "proceed" and got["ego_2"].command == "yield"


def test_a_foreign_car_on_a_foe_connection_makes_the_first_ego_wait() -> None:
    got = verdicts([st("ego_1", ":C_4_0", 20.0, oncoming=("bg0",)),
                    st("ego_2", ":C_8_0", 60.0)])
    assert got["ego_1"].command == "yield"


def test_merge_rank_and_central_directives() -> None:
    statuses = [st("ego_1", ":J_1_0", 35.0, cid=MID), st("ego_2", ":J_0_0", 28.0, cid=MID)]
    core = CoordinatorCore(RulesCoordinator())
    out = {d.ego_id: d for d in core.on_statuses(statuses, 1.0)}
    assert out["ego_2"].command == "proceed" and out["ego_1"].command == "yield"
    assert out["ego_1"].conflict_id == MID and out["ego_1"].speed_band.max_mps == 0.0
    assert core.refused == 0


def test_junction_and_narrow_conflicts_are_resolved_apart() -> None:
    # two egos at different conflicts never make each other yield
    got = verdicts([st("ego_1", ":C_4_0", 20.0), st("ego_2", ":J_0_0", 10.0, cid=MID)])
    assert {v.command for v in got.values()} == {"proceed"}
