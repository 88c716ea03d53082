"""The fixed rule set that resolves a shared conflict from the egos' statuses (issue 18).

Used by every ego in ``distributed`` mode (each on the statuses it received, with its own
memory: the same statuses give every ego the same answer) and by the coordinator's
``rules`` backend in ``central`` mode. The same rules for the three kinds of conflict
(``coordination.conflicts``): a narrow section (a direction = its section lane), a
junction or a merge (one zone; a "direction" = an ego's movement through it, its first
internal lane). Per conflict, among the egos that have not left it
and are within ``ENGAGE_M`` of its entry:

1. **committed** egos go first: inside the conflict, or too fast to stop before their
   hold point at ``COMFORT_BRAKE_MPS2``;
2. then by distance to the entry, ties by id (``ego_1`` before ``ego_2``);
3. the direction (the conflict lane, ``ConflictView.via``) of the first one gets the
   conflict; it keeps it while one of its egos is still committed to it (memory);
4. an ego proceeds when it takes that direction and no ego of the other direction is
   ranked before it; every other ego yields (priority = its rank);
5. an ego that is not committed also yields while a vehicle that is not an ego comes
   the other way: seen by the ego itself (``ConflictView.oncoming``) or reported by an
   ego of the other direction as following it through (``ConflictView.inbound``, also
   after that ego left the conflict); nobody coordinates with such a vehicle.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lmpc_msgs_py.coordination import EgoStatus

ENGAGE_M = 120.0
COMFORT_BRAKE_MPS2 = 3.0


@dataclass(frozen=True)
class Verdict:
    ego_id: str
    conflict_id: str
    command: str
    """``proceed`` or ``yield``."""
    priority: int
    why: str


def committed(st: EgoStatus) -> bool:
    c = st.conflict
    if c is None:
        return False
    return c.inside or st.v_mps ** 2 / (2.0 * COMFORT_BRAKE_MPS2) >= c.dist_to_hold_m


def resolve(statuses: Sequence[EgoStatus], memory: dict[str, str]) -> dict[str, Verdict]:
    """Verdicts for the egos that take part in a conflict now (others: none). ``memory``
    (conflict id -> the direction holding it) is updated in place."""
    ego_ids = {st.ego_id for st in statuses}
    by_conflict: dict[str, list[EgoStatus]] = {}
    inbound: dict[tuple[str, str], set[str]] = {}  # (conflict, direction) -> non-egos
    for st in statuses:
        c = st.conflict
        if c is not None:
            inbound.setdefault((c.conflict_id, c.via), set()).update(
                a for a in c.inbound if a not in ego_ids)
        if c is None or st.intent in ("done", "through") or c.dist_to_exit_m <= 0.0 \
                or c.dist_to_entry_m > ENGAGE_M:
            continue
        by_conflict.setdefault(c.conflict_id, []).append(st)
    out: dict[str, Verdict] = {}
    for cid in list(memory):
        if cid not in by_conflict:
            del memory[cid]  # everybody through: the conflict is free again
    for cid, parts in sorted(by_conflict.items()):
        order = sorted(parts, key=lambda st: (not committed(st),
                                              st.conflict.dist_to_entry_m,  # type: ignore
                                              st.ego_id))
        held = memory.get(cid)
        if held is None or not any(committed(st) and st.conflict.via == held  # type: ignore
                                   for st in parts):
            held = order[0].conflict.via  # type: ignore[union-attr]
        memory[cid] = held
        opposite_seen = False
        for rank, st in enumerate(order):
            c = st.conflict
            assert c is not None
            foreign = sorted({a for a in c.oncoming if a not in ego_ids}.union(
                *(ids for (k, via), ids in inbound.items() if k == cid and via != c.via)))
            if c.via != held:
                opposite_seen = True
                out[st.ego_id] = Verdict(st.ego_id, cid, "yield", rank,
                                         f"the section is given to the direction of {held}")
            elif opposite_seen:
                out[st.ego_id] = Verdict(st.ego_id, cid, "yield", rank,
                                         "an ego of the other direction is ranked first")
            elif foreign and not committed(st):
                out[st.ego_id] = Verdict(st.ego_id, cid, "yield", rank,
                                         f"{', '.join(foreign)} comes the other way")
            else:
                out[st.ego_id] = Verdict(st.ego_id, cid, "proceed", rank,
                                         "committed" if committed(st) else "first in line")
    return out
