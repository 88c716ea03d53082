"""The limits the messages impose, checked while a scene file is validated.

A network or a traffic file can hold things the message schemas refuse: an id longer
than ``MAX_ID_CHARS`` (netconvert's joined junctions), a lane wider than 20 m, a vehicle
type longer than 30 m. Found only when the bridge builds the map or observes an agent,
they ended the bridge with a raw pydantic traceback. Checked here first, each problem
is one :class:`SceneError` line naming the file, the element and the limit.

Ids are checked over the whole network (an agent may stand on any lane within sensing
range, whatever the map keeps); lane geometry and speeds are checked on the lanes the
map holds, by building it (``mapping.build_map`` turns a schema refusal into a
``SceneError`` naming the lane).
"""
from __future__ import annotations

from typing import Any

from lmpc_msgs_py.messages import MAX_ID_CHARS, MAX_VEHICLE_DIM_M

from lmpc_bridge.demand import Demand
from lmpc_bridge.scenarios.base import SceneError

FLOW_SUFFIX_CHARS = 8
"""A flow's vehicles are named ``<flow id>.<index>``: room for the index."""


def short_id(text: str, keep: int = 60, *, with_length: bool = True) -> str:
    """An id for an error line: a long one shows its start (and its length)."""
    if len(text) <= keep:
        return repr(text)
    return f"{text[:keep]!r}..." + (f" ({len(text)} characters)" if with_length else "")


def _too_long(what: str, ident: str, where: str, extra: int = 0) -> SceneError:
    return SceneError(
        f"{where}: {what} {short_id(ident, with_length=False)} has an id of {len(ident)} "
        f"characters"
        f"{f' (+{extra} for its vehicles)' if extra else ''}; the messages carry ids of at "
        f"most {MAX_ID_CHARS} (lmpc_msgs_py.messages.MAX_ID_CHARS): rename it")


def check_net_ids(net: Any, *, where: str) -> int:
    """SceneError for the first junction, edge, lane or traffic light of ``net`` whose id
    is longer than the messages allow (junctions first: a joined junction's id is what
    its internal lanes are named after); returns the longest id length found."""
    edges = net.getEdges(withInternal=True)
    nodes = {n.getID() for e in edges for n in (e.getFromNode(), e.getToNode())
             if n is not None}
    for nid in sorted(nodes, key=len, reverse=True)[:1]:
        if len(nid) > MAX_ID_CHARS:
            raise _too_long("junction", nid, where)
    longest = max((len(n) for n in nodes), default=0)
    for edge in sorted(edges, key=lambda e: e.getFunction() != ""):
        eid = edge.getID()
        longest = max(longest, len(eid))
        if len(eid) > MAX_ID_CHARS:
            raise _too_long("edge", eid, where)
        for lane in edge.getLanes():
            lid = lane.getID()
            longest = max(longest, len(lid))
            if len(lid) > MAX_ID_CHARS:
                raise _too_long("lane", lid, where)
            for conn in lane.getOutgoing():
                tls = conn.getTLSID() or ""
                if len(tls) > MAX_ID_CHARS:
                    raise _too_long("traffic light", tls, where)
    return longest


def check_demand(demand: Demand, *, where: str) -> None:
    """SceneError for the first vehicle / flow id or vehicle type the messages refuse."""
    for element, ident in demand.ids:
        extra = FLOW_SUFFIX_CHARS if element.endswith("Flow") or element == "flow" else 0
        if len(ident) + extra > MAX_ID_CHARS:
            raise _too_long(element, ident, where, extra)
    for vtype, length_m, width_m in demand.vtypes:
        for name, value in (("length", length_m), ("width", width_m)):
            if value is not None and not 0.0 < value <= MAX_VEHICLE_DIM_M:
                raise SceneError(
                    f"{where}: vType {short_id(vtype)} has {name} {value:g} m; an agent "
                    f"message carries 0 < {name} <= {MAX_VEHICLE_DIM_M:g} m "
                    "(lmpc_msgs_py.messages.MAX_VEHICLE_DIM_M)")
