"""One ego's coordination in the graph (``coordination/link.py``), without ROS: the set of
statuses it resolves on, directives taken / refused, the peers it waits for."""
from __future__ import annotations

import pytest

from lmpc_msgs_py.coordination import ConflictView, Directive, EgoStatus, SpeedBand
from lmpc_msgs_py.vocabulary import load_decision_space

from lmpc_llm_planner.coordination.link import EgoLink

CID = "narrow:AB|BA"


def st(eid: str, via: str, entry: float, t: float) -> EgoStatus:
    view = ConflictView(conflict_id=CID, kind="narrow", via=via, dist_to_entry_m=entry,
                        dist_to_exit_m=entry + 60.0, dist_to_hold_m=max(entry - 25.0, 0.0))
    return EgoStatus(stamp_s=t, seq=1, ego_id=eid, dist_to_target_m=200.0, v_mps=5.0,
                     intent="approach", conflict=view)


def directive(eid: str, t: float = 1.0) -> Directive:
    return Directive(stamp_s=t, seq=1, directive_id=f"d-{eid}", ego_id=eid, conflict_id=CID,
                     priority=1, command="yield", speed_band=SpeedBand(max_mps=0.0),
                     deadline_s=t + 3.0, source="rules")


@pytest.fixture
def link() -> EgoLink:
    return EgoLink("ego_1", ["ego_1", "ego_2"], "distributed", load_decision_space())


def test_resolves_on_the_newest_stamp_every_active_ego_reported(link: EgoLink) -> None:
    link._own = {1000: st("ego_1", "AB_0", 50.0, 1.0), 1100: st("ego_1", "AB_0", 49.0, 1.1)}
    link.on_status(st("ego_2", "BA_0", 60.0, 1.0))
    got = link.complete_set(1.1)
    assert [(s.ego_id, s.stamp_s) for s in got] == [("ego_1", 1.0), ("ego_2", 1.0)]
    link.on_status(st("ego_2", "BA_0", 59.0, 1.1))
    assert {s.stamp_s for s in link.complete_set(1.1)} == {1.1}
    # a peer silent for longer than PEER_ACTIVE_S has left (through, or gone)
    link._own[2000] = st("ego_1", "AB_0", 30.0, 2.0)
    assert [s.ego_id for s in link.complete_set(2.0)] == ["ego_1"]


def test_waits_for_peers_of_its_step_not_for_one_that_left(link: EgoLink) -> None:
    assert link.waiting_for(0.0) == ("ego_2",)  # not heard yet, at the start
    assert link.waiting_for(5.0) == ()  # never heard of: not waited for later
    link.on_status(st("ego_2", "BA_0", 60.0, 4.9))
    assert link.waiting_for(5.0) == ("ego_2",)
    link.on_status(st("ego_2", "BA_0", 59.0, 5.0))
    assert link.waiting_for(5.0) == ()
    assert link.waiting_for(6.0) == ()  # silent for 1 s: left


def test_an_ego_whose_episode_ended_says_done_and_is_not_waited_for() -> None:
    ego_1 = EgoLink("ego_1", ["ego_1", "ego_2"], "distributed", load_decision_space())
    ego_2 = EgoLink("ego_2", ["ego_1", "ego_2"], "distributed", load_decision_space())
    assert ego_1.leave(1.0) is None  # never reported: nothing to say
    ego_1._own[1000] = st("ego_1", "AB_0", 10.0, 1.0)
    ego_2._own = {1000: st("ego_2", "BA_0", 60.0, 1.0), 1100: st("ego_2", "BA_0", 59.0, 1.1)}
    ego_2.on_status(ego_1._own[1000])
    assert ego_2.waiting_for(1.1) == ("ego_1",)
    done = ego_1.leave(1.1)  # reached at 1.1: no status of 1.1 from its planner
    assert done is not None and done.intent == "done" and done.conflict is None
    ego_2.on_status(done)
    assert ego_2.waiting_for(1.1) == () and ego_2.waiting_for(1.2) == ()
    # ego_2 resolves on its own newest status (not one step back) beside ego_1's "done"
    assert [(s.ego_id, s.stamp_s, s.intent) for s in ego_2.complete_set(1.2)] == [
        ("ego_2", 1.1, "approach"), ("ego_1", 1.1, "done")]


def test_directives_for_unknown_egos_are_refused_and_counted() -> None:
    link = EgoLink("ego_1", ["ego_1", "ego_2"], "central", load_decision_space())
    assert link.on_directive(directive("ego_7")) is not None
    link.refuse("field 'priority': -1 is below 0")
    assert link.counters["directives_refused"] == 2
    assert link.ego.command is None  # nothing followed
    assert link.on_directive(directive("ego_2")) is None  # another ego's: heard, not followed
    assert link.ego.command is None and link.last_directive_s == 1.0
    assert link.on_directive(directive("ego_1")) is None
    assert link.ego.command is not None and link.ego.command.command == "yield"
    assert link.counters["directives_followed"] == 1


def test_bad_configuration_is_refused() -> None:
    space = load_decision_space()
    with pytest.raises(ValueError, match="not one of the graph's egos"):
        EgoLink("ego_3", ["ego_1", "ego_2"], "central", space)
    with pytest.raises(ValueError, match="unknown coordination mode"):
        EgoLink("ego_1", ["ego_1"], "chaos", space)
