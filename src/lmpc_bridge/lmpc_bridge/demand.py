"""What a scene's traffic files declare, and whether that traffic ever reaches the episode.

A recorded demand file departs at the hour it was recorded (e.g. from t = 25200 s,
7:00); a scene that starts SUMO at 0 then runs on an empty network and "reaches"
with every penalty 0. :func:`declared_demand` reads the route / trip / flow files
(SUMO XML) once; :func:`window_warnings` says, before the episode, when no vehicle
departs in the simulated window (``begin_s`` .. ``begin_s + warmup_s + max_time_s``);
:func:`entry_warnings` says, after it, when fewer vehicles entered than the files
declared for the time simulated (SUMO's own counters ``stats.vehicles.*``).

Counting (approximation, documented in docs/lmpc_bridge_external.md): ``vehicle`` and
``trip`` by their ``depart``; a ``flow`` by its ``begin`` / ``end`` and ``number`` /
``period`` / ``vehsPerHour`` (evenly spaced departures); flows with ``probability`` or
``period="exp(..)"`` are random: they count as "some traffic" for the window check
(expected number), never in the "fewer entered" comparison. Persons and containers
are not vehicles and are not counted. Times may be seconds or ``[[d:]h:]m:s``.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Optional, Sequence

FLOW_DEFAULT_END_S = 86400.0
"""SUMO's default end of a flow without ``end`` (24 h)."""
INSERTION_SLACK_S = 2.0
"""Vehicles due in the last seconds simulated are left out of the "fewer entered" count."""


def parse_time_s(text: Optional[str]) -> Optional[float]:
    """SUMO time: ``"25200"``, ``"25200.5"``, ``"7:00:00"``, ``"1:07:00:00"``; None if not a
    time (``triggered``, ``now``...)."""
    if text is None:
        return None
    text = text.strip()
    try:
        return float(text)
    except ValueError:
        pass
    parts = text.split(":")
    if not 2 <= len(parts) <= 4:
        return None
    try:
        values = [float(p) for p in parts]
    except ValueError:
        return None
    scale = (1.0, 60.0, 3600.0, 86400.0)
    return sum(v * scale[i] for i, v in enumerate(reversed(values)))


@dataclass(frozen=True)
class Flow:
    """A flow's departures: ``begin_s + k * period_s`` below ``end_s`` (at most ``number``);
    ``rate_per_s`` instead for a random flow (expected departures per second)."""

    id: str
    begin_s: float
    end_s: float
    period_s: Optional[float] = None
    number: Optional[int] = None
    rate_per_s: Optional[float] = None

    def count_between(self, lo_s: float, hi_s: float) -> float:
        """Departures in [lo_s, hi_s] (expected number for a random flow)."""
        a, b = max(lo_s, self.begin_s), min(hi_s, self.end_s)
        if b < a:
            return 0.0
        if self.rate_per_s is not None:
            return self.rate_per_s * (b - a)
        if not self.period_s or self.period_s <= 0.0:
            return 0.0
        k_hi = math.floor((b - self.begin_s) / self.period_s + 1e-9)
        if self.begin_s + k_hi * self.period_s >= self.end_s - 1e-9 and self.end_s > a:
            k_hi -= 1  # the interval is half-open: nothing departs at end_s
        if self.number is not None:
            k_hi = min(k_hi, self.number - 1)
        k_lo = max(math.ceil((a - self.begin_s) / self.period_s - 1e-9), 0)
        return float(max(k_hi - k_lo + 1, 0))


@dataclass(frozen=True)
class Demand:
    """The vehicles the traffic files declare."""

    departures_s: tuple[float, ...] = ()
    """Sorted ``depart`` times of single vehicles and trips."""
    flows: tuple[Flow, ...] = ()
    ids: tuple[tuple[str, str], ...] = ()
    """(element, id) of every vehicle, trip, flow, person, container (for id limits)."""
    vtypes: tuple[tuple[str, Optional[float], Optional[float]], ...] = ()
    """(id, length_m, width_m) of every vType that gives them."""
    unknown_departs: int = 0
    """Vehicles whose depart is not a time (``triggered``...)."""

    def count_between(self, lo_s: float, hi_s: float, *, random_flows: bool = True) -> float:
        singles = sum(1 for t in self.departures_s if lo_s <= t <= hi_s)
        flows = sum(f.count_between(lo_s, hi_s) for f in self.flows
                    if random_flows or f.rate_per_s is None)
        return singles + flows

    @property
    def empty(self) -> bool:
        return not self.departures_s and not self.flows

    def span_s(self) -> Optional[tuple[float, float]]:
        """(first, last) departure time over vehicles, trips and flows (None if none)."""
        starts = list(self.departures_s[:1]) + [f.begin_s for f in self.flows]
        ends = list(self.departures_s[-1:]) + [f.end_s for f in self.flows]
        if not starts:
            return None
        return min(starts), max(ends)


_VEHICLES = ("vehicle", "trip")
_FLOWS = ("flow",)
_OTHERS = ("person", "personFlow", "container", "containerFlow")


def _flow(el: Any) -> Flow:
    fid = el.get("id", "")
    begin = parse_time_s(el.get("begin")) or 0.0
    end = parse_time_s(el.get("end"))
    number = el.get("number")
    n = int(float(number)) if number is not None else None
    period_text = (el.get("period") or "").strip()
    if el.get("probability") is not None:
        return Flow(fid, begin, end if end is not None else FLOW_DEFAULT_END_S,
                    rate_per_s=float(el.get("probability")), number=n)
    if period_text.startswith("exp(") and period_text.endswith(")"):
        return Flow(fid, begin, end if end is not None else FLOW_DEFAULT_END_S,
                    rate_per_s=float(period_text[4:-1]), number=n)
    if period_text:
        period = parse_time_s(period_text)
    elif el.get("vehsPerHour") is not None:
        vph = float(el.get("vehsPerHour"))
        period = 3600.0 / vph if vph > 0 else None
    elif n is not None and end is not None and n > 0:
        period = (end - begin) / n
    else:
        period = None
    if end is None:
        end = begin + period * n if (period and n is not None) else FLOW_DEFAULT_END_S
    return Flow(fid, begin, end, period_s=period, number=n)


def _read_one(path: Path) -> Demand:
    departures: list[float] = []
    flows: list[Flow] = []
    ids: list[tuple[str, str]] = []
    vtypes: list[tuple[str, Optional[float], Optional[float]]] = []
    unknown = 0
    for _, el in ET.iterparse(path, events=("end",)):
        tag = el.tag
        if tag in _VEHICLES:
            ids.append((tag, el.get("id", "")))
            t = parse_time_s(el.get("depart"))
            if t is None:
                unknown += 1
            else:
                departures.append(t)
        elif tag in _FLOWS:
            ids.append((tag, el.get("id", "")))
            flows.append(_flow(el))
        elif tag in _OTHERS:
            ids.append((tag, el.get("id", "")))
        elif tag == "vType":
            length, width = el.get("length"), el.get("width")
            vtypes.append((el.get("id", ""), float(length) if length else None,
                           float(width) if width else None))
        if tag in _VEHICLES + _FLOWS + _OTHERS:
            el.clear()  # big recorded demand files: keep memory flat
    return Demand(tuple(sorted(departures)), tuple(flows), tuple(ids), tuple(vtypes), unknown)


def refused_at_start(route_file: Path, *, present: Sequence[str],
                     pending: Sequence[str]) -> tuple[str, ...]:
    """The vehicles of a family scene's ``route_file`` departing at 0 that are neither in
    the simulation nor waiting to be inserted after its first step: SUMO refused them with
    an error (e.g. a leader it finds unable to stop before a never-green link) and the
    scene runs without them. Unreadable files: ()."""
    try:
        root = ET.parse(route_file).getroot()
    except (OSError, ET.ParseError):
        return ()
    seen = set(present) | set(pending)
    return tuple(v.get("id", "") for v in root.iter("vehicle")
                 if parse_time_s(v.get("depart")) == 0.0 and v.get("id") not in seen)


def refused_warnings(ids: Sequence[str]) -> tuple[str, ...]:
    """The traffic warning for each vehicle ``refused_at_start`` found."""
    return tuple(f"SUMO refused {vid}, a vehicle the scene starts with (it never entered)"
                 for vid in ids)


@lru_cache(maxsize=32)
def _read_cached(path: str, size: int, mtime_ns: int) -> Demand:
    return _read_one(Path(path))


def declared_demand(files: Sequence[Path]) -> Demand:
    """The vehicles ``files`` declare (route, trip, flow or additional files).

    Raises ``ValueError`` naming the file when one is not well-formed XML or holds a
    number that is not one."""
    parts = []
    for f in files:
        st = Path(f).stat()
        try:
            parts.append(_read_cached(str(f), st.st_size, st.st_mtime_ns))
        except (ET.ParseError, ValueError) as exc:
            raise ValueError(f"{f}: {exc}") from None
    return Demand(
        departures_s=tuple(sorted(t for p in parts for t in p.departures_s)),
        flows=tuple(fl for p in parts for fl in p.flows),
        ids=tuple(i for p in parts for i in p.ids),
        vtypes=tuple(v for p in parts for v in p.vtypes),
        unknown_departs=sum(p.unknown_departs for p in parts),
    )


@dataclass(frozen=True)
class Window:
    """The simulated span of one episode in SUMO time."""

    begin_s: float
    warmup_s: float
    max_time_s: float

    @property
    def end_s(self) -> float:
        return self.begin_s + self.warmup_s + self.max_time_s


def window_warnings(demand: Demand, window: Window) -> list[str]:
    """Before the episode: a line when no background vehicle departs in ``window``."""
    if demand.count_between(window.begin_s, window.end_s) > 0 or demand.unknown_departs:
        return []
    lo, hi = window.begin_s, window.end_s
    where = (f"between t = {lo:g} s and {hi:g} s (SUMO time: begin_s {lo:g} + warmup_s "
             f"{window.warmup_s:g} + max_time_s {window.max_time_s:g})")
    span = demand.span_s()
    if span is None:
        return [f"no background traffic: the scene's files declare no vehicle, so no vehicle "
                f"departs {where}; the episode runs on an empty network"]
    first, last = span
    hint = (f"set begin_s: {first:g} (SUMO --begin) so the episode runs when the traffic does"
            if first > hi or last < lo else "choose begin_s / warmup_s inside it")
    return [f"no background vehicle departs {where}: the files' departures span "
            f"{first:g}-{last:g} s; {hint}. The episode would run on an empty network"]


@dataclass
class EntryCount:
    """SUMO's counters at the end of an episode (``simulation.getParameter('', 'stats...')``)."""

    inserted: int
    waiting: int
    sumo_time_s: float
    ego_inserted: int = 1
    notes: list[str] = field(default_factory=list)


def read_entry_count(traci: Any, *, ego_inserted: int = 1) -> Optional[EntryCount]:
    """Inserted / waiting vehicles so far (None where SUMO does not offer the counters)."""
    try:
        inserted = int(traci.simulation.getParameter("", "stats.vehicles.inserted"))
        waiting = int(traci.simulation.getParameter("", "stats.vehicles.waiting"))
        now = float(traci.simulation.getTime())
    except Exception:  # noqa: BLE001 - an older SUMO, or SUMO already closed
        return None
    return EntryCount(inserted=inserted, waiting=waiting, sumo_time_s=now,
                      ego_inserted=ego_inserted)


def entry_warnings(demand: Demand, window: Window, count: EntryCount) -> list[str]:
    """After the episode: a line when fewer vehicles entered than the files declared to
    depart by the time simulated (random flows left out of the comparison)."""
    # a vehicle due in the last steps may wait a step or two for a gap: not counted
    until_s = count.sumo_time_s - INSERTION_SLACK_S
    declared = int(demand.count_between(window.begin_s, until_s, random_flows=False))
    entered = max(count.inserted - count.ego_inserted, 0)
    if declared <= 0 or entered >= declared:
        return []
    return [f"fewer vehicles entered than the files declare: {entered} of the {declared} "
            f"declared to depart between t = {window.begin_s:g} s and {until_s:g} s "
            f"(SUMO time) entered the network, {count.waiting} still waiting for insertion "
            "(blocked departure lanes, or routes SUMO refused)"]
