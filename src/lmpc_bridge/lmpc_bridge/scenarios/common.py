"""Helpers shared by the scenario generators: candidate selection, vTypes, routes, targets.

Candidate selection (the "a scene only counts if the ego meets somebody" rule,
DESIGN §6): a family draws *candidates* ``c = 0, 1, 2, ...``, each from its own
``numpy`` generator ``PCG64([family_key, c])``, and applies a deterministic
build-time check to each. Scene ``seed`` is the ``seed``-th candidate that passes,
so "seeds 0-24" always names the same 25 scenes, and a rejected candidate never
shifts the random numbers of another one.
"""
from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from lmpc_bridge.scenarios.base import SceneError, TargetSpec, xml_attrs

EGO_LENGTH_M = 4.5
EGO_WIDTH_M = 1.8
LANE_WIDTH_M = 3.2
MAX_CANDIDATES_PER_SCENE = 50
"""Give up (SceneError) when this many candidates in a row fail the interaction check."""

P = TypeVar("P")


@dataclass(frozen=True)
class Candidate(Generic[P]):
    """A candidate that passed the check: its index, parameters and the check's reason."""

    index: int
    params: P
    reason: str


@dataclass
class _Scan:
    """How far one family's candidates were checked in this process."""

    passed: list[int]
    """The indices of the candidates that passed, in order (scene ``seed`` is ``passed[seed]``)."""
    next_index: int = 0
    misses: int = 0


_SCANS: dict[tuple[str, Callable[..., Any], Callable[..., Any]], _Scan] = {}
"""Per (family, sampler, check): the scan so far. Scene ``seed`` needs every candidate
before it checked; kept, building seeds 10000, 10001, ... (training) checks each candidate
once instead of ~10 000 per scene (~5 s per si scene)."""


def _draw(key: int, index: int, sample: Callable[[np.random.Generator], P]) -> P:
    return sample(np.random.Generator(np.random.PCG64([key, index])))


def select_candidate(family: str, seed: int, *, sample: Callable[[np.random.Generator], P],
                     check: Callable[[P], str | None]) -> Candidate[P]:
    """The ``seed``-th candidate of ``family`` whose ``check`` returns a reason (not None)."""
    key = zlib.crc32(family.encode())
    scan = _SCANS.setdefault((family, sample, check), _Scan(passed=[]))
    while len(scan.passed) <= seed:
        c = scan.next_index
        if check(_draw(key, c, sample)) is not None:
            scan.passed.append(c)
            scan.misses = 0
        else:
            scan.misses += 1
            if scan.misses >= MAX_CANDIDATES_PER_SCENE:
                raise SceneError(f"{family}: {scan.misses} candidates in a row without "
                                 f"interaction (after candidate {c}); the generator's ranges "
                                 "are too loose")
        scan.next_index = c + 1
    index = scan.passed[seed]
    params = _draw(key, index, sample)
    reason = check(params)
    assert reason is not None, f"{family} candidate {index}: its check is not deterministic"
    return Candidate(index=index, params=params, reason=reason)


BG_DECEL_MPS2 = 4.5
"""The background drivers' (and bikes') ``decel``."""


def driver_vtype(type_id: str, *, aggressiveness: float, vclass: str = "passenger",
                 length_m: float = 4.5, width_m: float = 1.8, max_speed_mps: float | None = None,
                 color: str = "0.6,0.6,0.9", speed_factor: float | None = None) -> str:
    """A background driver: ``aggressiveness`` in [0, 1] sets gaps, noise, assertiveness.

    Bolder drivers accelerate harder, keep shorter time gaps, drive faster than
    the limit, change lanes more assertively and accept shorter gaps at junctions.
    """
    g = float(aggressiveness)
    return "  <vType " + xml_attrs(
        id=type_id, vClass=vclass, length=length_m, width=width_m,
        maxSpeed=max_speed_mps,
        accel=2.6 + 0.8 * g if vclass != "bicycle" else 1.2, decel=BG_DECEL_MPS2,
        emergencyDecel=9.0,
        sigma=0.5 - 0.3 * g, tau=1.0 - 0.4 * g, minGap=2.5 - 1.0 * g,
        speedFactor=(1.0 + 0.15 * g) if speed_factor is None else speed_factor, speedDev=0.05,
        impatience=0.5 * g, jmTimegapMinor=1.0 - 0.5 * g,
        lcAssertive=1.0 + 1.5 * g, lcSpeedGain=1.0 + g, lcCooperative=1.0 - 0.5 * g,
        color=color,
    ) + "/>"


def ego_vtype() -> str:
    return "  <vType " + xml_attrs(id="ego_type", vClass="passenger", length=EGO_LENGTH_M,
                                   width=EGO_WIDTH_M, color="1,0,0") + "/>"


def vehicle_line(vid: str, *, type_id: str, route: str, depart_s: float, lane: int | str,
                 pos_m: float, speed_mps: float, stops: Sequence[dict[str, Any]] = (),
                 speed_factor: float | None = None, insertion_checks: str | None = None) -> str:
    """A ``<vehicle>`` element (with optional ``<stop>`` children).

    ``speed_factor`` fixes this driver's desired speed as a multiple of the lane
    limit (SUMO otherwise draws it from the vType's speedFactor distribution):
    slow traffic stays slow instead of accelerating to the limit. ``insertion_checks``:
    SUMO's ``insertionChecks`` (default: all).
    """
    head = "  <vehicle " + xml_attrs(id=vid, type=type_id, route=route, depart=depart_s,
                                     departLane=lane, departPos=pos_m, departSpeed=speed_mps,
                                     speedFactor=speed_factor, insertionChecks=insertion_checks)
    if not stops:
        return head + "/>"
    inner = "".join(f"\n    <stop {xml_attrs(**s)}/>" for s in stops)
    return head + ">" + inner + "\n  </vehicle>"


def write_routes(path: Path, *, vtypes: Sequence[str], routes: dict[str, Sequence[str]],
                 vehicles: Sequence[tuple[float, str]], persons: Sequence[tuple[float, str]] = ()
                 ) -> None:
    """Write a routes file; vehicles and persons are (depart, xml) and sorted by depart time."""
    lines = ["<routes>", *vtypes, ego_vtype()]
    lines += [f'  <route {xml_attrs(id=rid, edges=" ".join(edges))}/>'
              for rid, edges in routes.items()]
    items = sorted([*vehicles, *persons], key=lambda item: item[0])
    lines += [xml for _, xml in items]
    lines.append("</routes>")
    path.write_text("\n".join(lines) + "\n")


def write_plain_net(scene_dir: Path, name: str, *, nodes: Sequence[dict[str, Any]],
                    edges: Sequence[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``<name>.nod.xml`` / ``<name>.edg.xml``; dict keys are SUMO attribute names.

    An edge may carry ``lanes``: a list of dicts of per-lane attributes (``index``...).
    """
    nod = scene_dir / f"{name}.nod.xml"
    edg = scene_dir / f"{name}.edg.xml"
    nod.write_text("<nodes>\n" + "\n".join(f"  <node {xml_attrs(**n)}/>" for n in nodes)
                   + "\n</nodes>\n")
    lines = []
    for e in edges:
        attrs = {k: v for k, v in e.items() if k != "lanes"}
        lanes = e.get("lanes") or ()
        if not lanes:
            lines.append(f"  <edge {xml_attrs(**attrs)}/>")
        else:
            inner = "".join(f"\n    <lane {xml_attrs(**lane)}/>" for lane in lanes)
            lines.append(f"  <edge {xml_attrs(**attrs)}>{inner}\n  </edge>")
    edg.write_text("<edges>\n" + "\n".join(lines) + "\n</edges>\n")
    return nod, edg


def read_net(net_file: Path) -> Any:
    """The network parsed by sumolib (internal lanes included)."""
    import sumolib

    return sumolib.net.readNet(str(net_file), withInternal=True)


def target_on_lanes(net: Any, lane_ids: Sequence[str], *, pos_m: float,
                    radius_m: float) -> TargetSpec:
    """Target area centred on the first of ``lane_ids`` at ``pos_m`` (clipped to the lane)."""
    import sumolib

    lane = net.getLane(lane_ids[0])
    pos = min(max(pos_m, 1.0), float(lane.getLength()) - 1.0)
    cx, cy = sumolib.geomhelper.positionAtShapeOffset(lane.getShape(), pos)
    return TargetSpec(edge_id=lane.getEdge().getID(), lane_ids=tuple(lane_ids), lane_pos_m=pos,
                      center=(round(float(cx), 3), round(float(cy), 3)), radius_m=radius_m)


def rotate(x: float, y: float, angle_rad: float) -> tuple[float, float]:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return (round(c * x - s * y, 3), round(s * x + c * y, 3))


def arrival_window(arrivals: Sequence[float], ego_arrival_s: float, *, before_s: float = 3.0,
                   after_s: float = 8.0) -> list[float]:
    """Arrivals within ``[-before_s, +after_s]`` of the ego's nominal arrival."""
    return [a for a in arrivals if -before_s <= a - ego_arrival_s <= after_s]
