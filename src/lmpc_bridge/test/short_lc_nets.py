"""Test networks with a lane change required on a short (5-10 m) edge before a junction.

The situation of issue 21 (an OSM import): the ego arrives on a one-lane road that feeds
only one lane of a two-lane stub a few metres long, and the turn its route takes leaves
from the other lane of the stub. Built with netconvert from hand-written nodes, edges
and connections (all roads two-way, a four-arm junction at the end of the stub)::

        far / near arm (N)
              |
    W ---- B -C ---- E       B-C: the stub, 2 lanes, 5-10 m long after junction shapes
              |
        near / far arm (S)

``need``: which lane of the stub the route's turn leaves from.
- ``"inner"``: the route takes the far-side turn (right-hand traffic: left, to N;
  left-hand: right, to S), which leaves from the inner lane (index 1); the ego enters
  the stub on the outer lane (index 0, netconvert's lane 0 is the outer lane in both
  traffic directions). The stub's outer lane goes straight or turns near-side.
- ``"outer"``: the route takes the near-side turn (right-hand: right, to S; left-hand:
  left, to N) from the outer lane; the ego enters on the inner lane, which goes straight
  or turns far-side.
So ``inner`` in right-hand traffic is a change to the left, ``outer`` one to the right;
in left-hand traffic (``netconvert --lefthand``) the sides swap.
"""
from __future__ import annotations

from pathlib import Path

from lmpc_bridge.scenarios.base import run_netconvert
from lmpc_bridge.scenarios.common import write_plain_net

STUB_END_X_M = 20.0
"""x of node C: with the junction shapes at B and C the stub's lanes are ~8 m long."""
SPEED_MPS = 13.89


def far_near(left_hand: bool) -> tuple[str, str]:
    """(far-side arm, near-side arm) of the junction: the arm whose turn crosses the
    oncoming traffic, and the other one."""
    return ("S", "N") if left_hand else ("N", "S")


def make_short_lc_net(out_dir: Path, *, need: str, left_hand: bool = False,
                      entry_turns: bool = True, stub_end_x_m: float = STUB_END_X_M) -> Path:
    """Build the network; returns the ``.net.xml`` path (see the module docstring).

    ``entry_turns=False``: the entry lane only goes straight on and the other lane goes
    straight on or turns (the route's turn): then the ego's candidates on the entry lane
    are "continue in lane" and "change to the left / right lane", both going straight
    on through the junction (issue 21's "change to the left lane")."""
    if need not in ("inner", "outer"):
        raise ValueError(f"need must be 'inner' or 'outer', not {need!r}")
    name = f"short_lc_{need}{'' if entry_turns else '_st'}{'_lh' if left_hand else ''}"
    c = stub_end_x_m
    nodes = [dict(id="W", x=-150.0, y=0.0), dict(id="B", x=0.0, y=0.0, type="priority"),
             dict(id="C", x=c, y=0.0, type="priority"), dict(id="E", x=c + 150.0, y=0.0),
             dict(id="N", x=c, y=150.0), dict(id="S", x=c, y=-150.0)]
    edges = [dict(id="WB", **{"from": "W", "to": "B"}, numLanes=1, speed=SPEED_MPS,
                  priority=2),
             dict(id="BW", **{"from": "B", "to": "W"}, numLanes=1, speed=SPEED_MPS,
                  priority=2),
             dict(id="BC", **{"from": "B", "to": "C"}, numLanes=2, speed=SPEED_MPS,
                  priority=2),
             dict(id="CB", **{"from": "C", "to": "B"}, numLanes=1, speed=SPEED_MPS,
                  priority=2)]
    for arm in ("E", "N", "S"):
        prio = 2 if arm == "E" else 1
        edges.append(dict(id=f"C{arm}", **{"from": "C", "to": arm}, numLanes=1,
                          speed=SPEED_MPS, priority=prio))
        edges.append(dict(id=f"{arm}C", **{"from": arm, "to": "C"}, numLanes=1,
                          speed=SPEED_MPS, priority=prio))
    nod, edg = write_plain_net(out_dir, name, nodes=nodes, edges=edges)
    far, near = far_near(left_hand)
    entry = 0 if need == "inner" else 1
    other = 1 - entry
    turn_from_other = far if need == "inner" else near
    turn_from_entry = near if need == "inner" else far
    conns = [("WB", 0, "BC", entry), ("BC", entry, "CE", 0),
             ("BC", other, f"C{turn_from_other}", 0)]
    conns.append(("BC", entry, f"C{turn_from_entry}", 0) if entry_turns
                 else ("BC", other, "CE", 0))
    con = out_dir / f"{name}.con.xml"
    con.write_text("<connections>\n" + "".join(
        f'  <connection from="{a}" to="{b}" fromLane="{i}" toLane="{j}"/>\n'
        for a, i, b, j in conns) + "</connections>\n")
    net = out_dir / f"{name}.net.xml"
    extra: tuple[str, ...] = ("--connection-files", str(con))
    if left_hand:
        extra += ("--lefthand", "true")
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net, extra_args=extra)
    return net


def route_of(need: str, left_hand: bool) -> list[str]:
    """The ego's edge route on that network (W -> the arm its turn goes to)."""
    far, near = far_near(left_hand)
    arm = far if need == "inner" else near
    return ["WB", "BC", f"C{arm}"]


def scene_yaml(net: Path, *, need: str, left_hand: bool, seed: int = 1,
               background: bool = True) -> str:
    """A scene file body for that network: start 60 m before the stub, target 40 m into
    the route's last edge; background traffic (randomTrips, seeded) when asked."""
    route = route_of(need, left_hand)
    bg = "background: {period_s: 3, end_s: 300, seed: 4}\nwarmup_s: 20\n" if background else ""
    return (f"net: {net}\nseed: {seed}\n{bg}max_time_s: 90\n"
            f"ego: {{start: {{edge: WB, pos_m: 80}}, speed_mps: 8, "
            f"route: [{', '.join(route)}]}}\n"
            f"target: {{pos_m: 40, radius_m: 4}}\n")
