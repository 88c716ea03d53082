"""Driving style, measured: per-episode figures of how the ego drove (gaps, deceleration,
jerk, the gaps it accepted) from the episode record, the instruction sets of
``benchmark.py --instruction-set`` and the style table (per family and style).

Definitions (all from :class:`lmpc_bridge.record.EpisodeRecord`, one record per step):

- ``mean_gap_m``: mean over the steps with another vehicle within sensing range of the
  smallest bumper-to-bumper gap (``NearbyVehicle.gap_m``) on that step; ``min_gap_m``:
  the smallest gap of the episode;
- ``peak_decel_mps2``: the strongest deceleration of the ego (``-min a_mps2``, 0 if it
  never braked); ``peak_jerk_mps3``: the largest ``|a_k - a_{k-1}| / dt``;
- ``lc_gap_m``: the gap accepted at a lane change (the lane index changes on the same
  edge, both normal lanes): on that step, the smallest gap to a vehicle in the lane the
  ego enters - its new leader or follower: heading within ``ALONG_RAD`` of the ego's, and
  its centre on the entered side of the ego's centre by at most ``TARGET_LANE_BAND_M``
  across its own heading (the ego's centre has just crossed the lane line, so the new
  lane's vehicles are about half a lane width that way, the old lane's half a lane the
  other). The episode's value is the smallest over its lane changes (nan: no lane change
  with a vehicle in the entered lane within sensing range: the lane was free). Until
  2026-12-07 it was the smallest gap to any vehicle, which at a lane change is mostly the
  leader in the lane the ego leaves (an obstacle it passes), not the gap it accepted;
- ``junction_gap_m``: at each junction entry (a normal lane followed by an internal
  ``:`` lane) the smallest gap to a vehicle whose heading differs from the ego's by more
  than ``CROSS_HEADING_RAD`` (crossing, merging, oncoming traffic; not the leader or the
  queue) and that moves (``v >= MOVING_MPS``); the smallest over the entries (nan: no
  such vehicle on any entry). It counts vehicles that have just left as well as those
  arriving, and is a distance; the next figure is the time gap the ego accepted:
- ``junction_pet_s``: the post-encroachment time at the ego's junction crossings (the
  smallest over them; nan: no conflict): for each other vehicle (not a pedestrian) whose
  recorded path comes within ``PET_CROSS_M`` of the ego's path on a junction's
  internal (``:``) lanes at a heading more than ``CROSS_HEADING_RAD`` off the ego's,
  the time between the ego and it passing that point (closest recorded centre points,
  0.1 s samples, while within sensing range). Approximation: centre points, not boxes,
  and a vehicle seen only on one side of the point does not count.
"""
from __future__ import annotations

import math
import statistics
from typing import Any, Optional

import numpy as np

from lmpc_bridge.evaluation.table import finite, markdown, mean_finite, wilson_interval
from lmpc_bridge.record import EpisodeRecord, StepRecord

CROSS_HEADING_RAD = math.radians(30.0)
MOVING_MPS = 0.5
ALONG_RAD = math.radians(45.0)
"""Another vehicle's heading this close to the ego's: same direction (``lc_gap_m``; the
ego's own heading turns up to ~20 deg off the road during a lane change)."""
TARGET_LANE_BAND_M = 3.0
"""``lc_gap_m``: how far to the entered side of the ego's centre a vehicle of the entered
lane may be (lanes are 3.2-3.5 m wide: its centre is ~1.6-1.75 m that way; a vehicle two
lanes over ~4.8 m)."""
PET_CROSS_M = 2.0
"""Two recorded centre points this close: the paths cross there (``junction_pet_s``;
at 14 m/s consecutive samples are 1.4 m apart)."""
STYLE_COLUMNS = ("mean_gap_m", "min_gap_m", "peak_decel_mps2", "peak_jerk_mps3", "lc_gap_m",
                 "lc_changes", "junction_gap_m", "junction_pet_s")
STYLES = ("conservative", "normal", "aggressive")

INSTRUCTION_SETS: dict[str, tuple[tuple[str, Optional[str]], ...]] = {
    # (style, the user's text; None: no instruction)
    "styles": (
        ("conservative", "drive conservatively"),
        ("conservative", "take it easy, no risks"),
        ("normal", None),
        ("aggressive", "I'm in a hurry"),
        ("aggressive", "drive aggressively"),
    ),
    "styles-short": (
        ("conservative", "drive conservatively"),
        ("normal", None),
        ("aggressive", "drive aggressively"),
    ),
    # situational text (lmpc_bridge.evaluation.situations): the label is the situation
    "situations": (
        ("none", None),
        ("closure", "the right lane is closed ahead"),
        ("make-room", "an ambulance is coming from behind, make room"),
        ("pedestrians", "pedestrians are crossing at the next junction"),
    ),
}
"""``benchmark.py --instruction-set NAME``: each scene once per (label, phrasing); the
label is a style, or for ``situations`` the situation."""
SITUATION_SETS = frozenset({"situations"})
"""The sets whose labels are situations (situations.csv / situation_table.md)."""


def edge_lane(lane_id: Optional[str]) -> Optional[tuple[str, str]]:
    """(edge, lane index) of a normal lane's id; None on a junction (``:...``) or none."""
    if not lane_id or lane_id.startswith(":") or "_" not in lane_id:
        return None
    edge, _, idx = lane_id.rpartition("_")
    return edge, idx


def _angle(a: float) -> float:
    return abs((a + math.pi) % (2.0 * math.pi) - math.pi)


def style_metrics(record: EpisodeRecord) -> dict[str, Any]:
    """The style figures of one episode (see the module doc); nan where undefined."""
    steps = record.steps
    nearest = [min(n.gap_m for n in s.nearby) for s in steps if s.nearby]
    accels = [s.a_mps2 for s in steps]
    jerks = [abs(b - a) / record.dt_s for a, b in zip(accels, accels[1:])]
    lc_gaps: list[float] = []
    jn_gaps: list[float] = []
    changes = 0
    for prev, cur in zip(steps, steps[1:]):
        p, c = edge_lane(prev.lane_id), edge_lane(cur.lane_id)
        if p is not None and c is not None and p[0] == c[0] and p[1] != c[1]:
            changes += 1
            entered = entered_lane_gaps(cur, left=int(c[1]) > int(p[1]))
            if entered:
                lc_gaps.append(min(entered))
        if p is not None and cur.lane_id is not None and cur.lane_id.startswith(":"):
            crossing = [n.gap_m for n in cur.nearby if n.v_mps >= MOVING_MPS
                        and _angle(n.yaw_rad - cur.yaw_rad) > CROSS_HEADING_RAD]
            if crossing:
                jn_gaps.append(min(crossing))
    pets = junction_pets(record)
    return {
        "mean_gap_m": round(statistics.fmean(nearest), 3) if nearest else math.nan,
        "min_gap_m": round(min(nearest), 3) if nearest else math.nan,
        "peak_decel_mps2": round(max(0.0, -min(accels)), 3) if accels else math.nan,
        "peak_jerk_mps3": round(max(jerks), 3) if jerks else math.nan,
        "lc_gap_m": round(min(lc_gaps), 3) if lc_gaps else math.nan,
        "lc_changes": changes,
        "junction_gap_m": round(min(jn_gaps), 3) if jn_gaps else math.nan,
        "junction_pet_s": round(min(pets.values()), 3) if pets else math.nan,
    }


def entered_lane_gaps(step: StepRecord, *, left: bool) -> list[float]:
    """The gaps to the vehicles in the lane the ego enters on ``step`` (to its left when
    ``left``; SUMO numbers lanes from the right): see ``lc_gap_m``."""
    side = 1.0 if left else -1.0
    out = []
    for n in step.nearby:
        if n.kind == "pedestrian" or _angle(n.yaw_rad - step.yaw_rad) > ALONG_RAD:
            continue
        dx, dy = n.x_m - step.x_m, n.y_m - step.y_m
        across = side * (-math.sin(n.yaw_rad) * dx + math.cos(n.yaw_rad) * dy)
        if 0.0 < across <= TARGET_LANE_BAND_M:
            out.append(n.gap_m)
    return out


def junction_pets(record: EpisodeRecord) -> dict[str, float]:
    """Per other vehicle whose path crosses the ego's on a junction, the post-encroachment
    time there (s; see the module doc, ``junction_pet_s``)."""
    steps = record.steps
    on_jn = [s for s in steps if s.lane_id is not None and s.lane_id.startswith(":")]
    if not on_jn:
        return {}
    ego = np.array([(s.t_s, s.x_m, s.y_m, s.yaw_rad) for s in on_jn])
    seen: dict[str, list[tuple[float, float, float, float]]] = {}
    for s in steps:
        for n in s.nearby:
            if n.kind != "pedestrian":
                seen.setdefault(n.id, []).append((s.t_s, n.x_m, n.y_m, n.yaw_rad))
    out: dict[str, float] = {}
    for vid, track in seen.items():
        o = np.array(track)
        d = np.hypot(ego[:, None, 1] - o[None, :, 1], ego[:, None, 2] - o[None, :, 2])
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[i, j] <= PET_CROSS_M and _angle(o[j, 3] - ego[i, 3]) > CROSS_HEADING_RAD:
            out[vid] = abs(float(o[j, 0] - ego[i, 0]))
    return out


def style_summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per family and style (over all its phrasings and scenes): counts of collisions and
    fails, means of time, O.C. and the style figures (nan-skipping; ``*_n``: how many
    scenes had a value)."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for family in sorted({r["family"] for r in rows}):
        out[family] = {}
        for style in STYLES:
            sel = [r for r in rows if r["family"] == family and r.get("style") == style]
            if not sel:
                continue
            agg: dict[str, Any] = {
                "runs": len(sel), "collisions": sum(int(r["collision"]) for r in sel),
                "fails": sum(int(r["fail"]) for r in sel)}
            for k in ("time_s", "overall_cost", "mean_gap_m", "min_gap_m", "peak_decel_mps2",
                      "peak_jerk_mps3", "lc_gap_m", "junction_gap_m", "junction_pet_s"):
                agg[k] = round(mean_finite(r.get(k) for r in sel), 3)
            for k in ("lc_gap_m", "junction_gap_m", "junction_pet_s"):
                agg[f"{k}_n"] = sum(1 for r in sel if finite(r.get(k)))
            out[family][style] = agg
    return out


def direction_share(rows: list[dict[str, Any]], key: str = "time_s", *,
                    min_diff: float = 0.05) -> dict[str, dict[str, Any]]:
    """Per family: of the scenes where the style can matter (the conservative and the
    aggressive mean of ``key`` over the phrasings differ by more than ``min_diff`` from
    each other or from normal), how many follow the expected order aggressive <= normal
    <= conservative with aggressive < conservative. A difference of ``min_diff`` itself is
    a tie (``min_diff`` plus 1e-6 against float rounding: 18.2 - 18.1 > 0.1). ``share_ci``:
    the share's 95 % Wilson interval (25 scenes leave a share of 80 % anywhere in
    61-91 %)."""
    tol = min_diff + 1e-6
    out: dict[str, dict[str, Any]] = {}
    for family in sorted({r["family"] for r in rows}):
        per: dict[int, dict[str, list[float]]] = {}
        for r in rows:
            if r["family"] == family and finite(r.get(key)) and r.get("style") in STYLES:
                per.setdefault(int(r["seed"]), {}).setdefault(r["style"], []).append(
                    float(r[key]))
        matter = follow = 0
        for by in per.values():
            if not all(s in by for s in STYLES):
                continue
            c, n, a = (statistics.fmean(by[s]) for s in STYLES)
            if max(c, n, a) - min(c, n, a) <= tol:
                continue
            matter += 1
            follow += int(a <= n + tol and n <= c + tol and a < c)
        lo, hi = wilson_interval(follow, matter)
        out[family] = {"matter": matter, "follow": follow,
                       "share": round(follow / matter, 3) if matter else math.nan,
                       "share_ci": (round(lo, 3), round(hi, 3))}
    return out


SHARE_FIGURES = {"time_s": 0.05, "junction_pet_s": 0.1, "lc_gap_m": 0.5}
"""The figures whose per-scene order the style table reports (``direction_shares``), each
with its tie tolerance (``min_diff``): the figure's resolution. Time: any difference (the
record's steps are 0.1 s); junction PET: one 0.1 s sample (the same crossing seen one
sample earlier or later is a tie, two samples are not); lane-change gap:
the same gap taken one 0.1 s step apart differs by the relative speed x 0.1 s (up to
~5 m/s on these roads). Until 2026-12-07 every figure used 0.05."""


def direction_shares(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """``direction_share`` of each of ``SHARE_FIGURES`` (families without a value left
    out)."""
    out = {}
    for key, tol in SHARE_FIGURES.items():
        per = {fam: s for fam, s in direction_share(rows, key, min_diff=tol).items()
               if s["matter"]}
        if per:
            out[key] = per
    return out


def style_table_md(summary: dict[str, dict[str, dict[str, Any]]],
                   shares: Optional[dict[str, dict[str, dict[str, Any]]]] = None) -> str:
    """The style table: one row a family and style; ``shares``: ``direction_shares``."""

    def f(v: Any, fmt: str) -> str:
        return format(v, fmt) if finite(v) else "-"

    rows = []
    for family, styles in summary.items():
        for style, a in styles.items():
            rows.append([
                family.upper(), style, f"{a['runs']}", f"{a['collisions']}", f"{a['fails']}",
                f(a["time_s"], ".1f"), f(a["mean_gap_m"], ".1f"), f(a["min_gap_m"], ".1f"),
                f(a["peak_decel_mps2"], ".1f"), f(a["peak_jerk_mps3"], ".1f"),
                f"{f(a['lc_gap_m'], '.1f')} ({a['lc_gap_m_n']})",
                f"{f(a['junction_gap_m'], '.1f')} ({a['junction_gap_m_n']})",
                f"{f(a.get('junction_pet_s'), '.1f')} ({a.get('junction_pet_s_n', 0)})",
                f(a["overall_cost"], ".1f")])
    text = markdown(["Scenario", "Style", "Runs", "Coll.", "Fail", "Time", "Mean gap",
                     "Min gap", "Peak decel", "Peak jerk", "LC gap (n)", "Junction gap (n)",
                     "Junction PET s (n)", "O.C."], rows)
    if shares:
        text += "\nPer scene, the figure in the expected order (aggressive <= normal <= " \
                "conservative, aggressive < conservative) where the style changes it " \
                "(gaps: scenes with a value for every style):\n\n"
        text += markdown(["Scenario", "Figure", "Scenes where style matters", "Follow",
                          "Share", "95 % interval"], [
            [fam.upper(), key, f"{s['matter']}", f"{s['follow']}", f(s["share"], ".0%"),
             "{}-{}".format(*(f(v, ".0%") for v in s["share_ci"]))]
            for key, per in shares.items() for fam, s in per.items()])
    return text
