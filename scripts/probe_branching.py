#!/usr/bin/env python3
"""Probe: what escapes ``Episode.restore``? (issue 16; docs/BRANCHING.md)

    probe_branching.py [--family usi --seed 100 --until 40] [--at 0,2.5] [--options all]
                       [--lookahead 8] [--all-diffs] [--states] [--b-first]

Run A: ``lmpc-rules`` on FAMILY/SEED undisturbed. Run B: the same, but at the decision
instants AT (empty: every instant), after the planner decided: snapshot, roll out
OPTIONS (oracle option names, or ``all``) for LOOKAHEAD s each, restore (planner
untouched, as regret.py / the oracle do), go on with the planner's decision. Per step
both runs capture the step record, the bridge's state, every SUMO vehicle (position,
speed, lane, lateral offset, acceleration, waiting time, time loss, lane-change state,
route index, leader, follower, neighbours, junction foes, next links and signals, best
lanes) and every lane's vehicles, the controller's state with the solver's warm start,
the planner's state, and with ``--states`` SUMO's own state file. Differences are
printed field by field (the first step, or every step with ``--all-diffs``). Both runs
share the process (B second: libsumo carries state across simulations; ``--b-first``
swaps them). Development seeds only.
"""
from __future__ import annotations

import argparse
import copy
import difflib
import sys
import tempfile
from pathlib import Path

import libsumo
import numpy as np

from lmpc_bridge.episode import Episode
from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import methods
from lmpc_scripts.method_oracle import OracleConfig, options_in, option_decision, roll_out


def sumo_vehicles() -> dict:
    out = {}
    v = libsumo.vehicle
    for vid in sorted(v.getIDList()):
        out[vid] = dict(
            pos=v.getPosition(vid), speed=v.getSpeed(vid), angle=v.getAngle(vid),
            lane=v.getLaneID(vid), lanepos=v.getLanePosition(vid),
            lat=v.getLateralLanePosition(vid), acc=v.getAcceleration(vid),
            wait=v.getWaitingTime(vid), accwait=v.getAccumulatedWaitingTime(vid),
            lcl=v.getLaneChangeState(vid, 1), lcr=v.getLaneChangeState(vid, -1),
            route=v.getRouteIndex(vid), leader=v.getLeader(vid, 50.0),
            follower=v.getFollower(vid, 50.0), speedmode=v.getSpeedMode(vid),
            lcmode=v.getLaneChangeMode(vid), foes=(
                tuple(v.getJunctionFoes(vid, 50.0)) if vid == "ego" else None),
            nexttls=v.getNextTLS(vid), best=tuple(
                (b[0], b[1], b[2], b[3], b[4], tuple(b[5])) for b in v.getBestLanes(vid)))
    for lid in libsumo.lane.getIDList():
        ids = libsumo.lane.getLastStepVehicleIDs(lid)
        if ids:
            out["lane:" + lid] = tuple(ids)
    for vid in sorted(v.getIDList()):
        out[vid]["links"] = tuple(tuple(x) for x in v.getNextLinks(vid))
        out[vid]["neigh"] = tuple(v.getNeighbors(vid, mode) for mode in range(4))
        out[vid]["ttl"] = v.getTimeLoss(vid)
    for pid in sorted(libsumo.person.getIDList()):
        p = libsumo.person
        out["p:" + pid] = dict(pos=p.getPosition(pid), speed=p.getSpeed(pid),
                               lane=p.getLaneID(pid))
    return out


def ctrl_state(ctrl) -> dict:
    own = {k: v for k, v in ctrl.__dict__.items() if k not in ctrl._SHARED}
    s = ctrl.solver
    own["__solver__"] = {k: v for k, v in s.__dict__.items()
                         if k not in ("_compiled", "_rti", "_cpu0", "over_budget", "config",
                                      "vehicle")}
    if own.get("_route_s"):
        own["_route_s"] = own["_route_s"][1:]  # [0] is id(map): differs between runs
    return copy.deepcopy(own)


def plan_state(pl) -> dict:
    return copy.deepcopy({k: v for k, v in pl.__dict__.items()
                          if k not in pl._SHARED and k not in ("_regret", "_decide")})


def diff(a, b, path="") -> list[str]:
    out = []
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a2, b2 = np.asarray(a), np.asarray(b)
        if a2.shape != b2.shape or not np.array_equal(a2, b2, equal_nan=True):
            d = (np.nanmax(np.abs(a2 - b2)) if a2.shape == b2.shape
                 and a2.dtype.kind == "f" else "shape/type")
            out.append(f"{path}: arrays differ (max {d})")
        return out
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'A' if k in a else 'B'}")
            else:
                out += diff(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{path}: len {len(a)} vs {len(b)}"]
        for i, (x, y) in enumerate(zip(a, b)):
            out += diff(x, y, f"{path}[{i}]")
        return out
    if hasattr(a, "__dict__") and type(a) is type(b) and not hasattr(a, "model_dump"):
        return diff(vars(a), vars(b), path)
    if hasattr(a, "model_dump") and type(a) is type(b):
        return diff(a.model_dump(), b.model_dump(), path)
    try:
        eq = a == b
        if isinstance(eq, np.ndarray):
            eq = bool(eq.all())
    except Exception:  # noqa: BLE001
        eq = False
    if not eq and not (isinstance(a, float) and isinstance(b, float) and a != a and b != b):
        out.append(f"{path}: {a!r} vs {b!r}")
    return out


def capture(ep, planner, states: bool, tmp: Path) -> dict:
    sim = ep.sim
    c = dict(step=sim.step_index, pose=sim.pose, rec=sim.record().steps[-1].model_dump(
        exclude={"solve_time_ms"}) if sim.record().steps else None,
        seen=dict(sim._seen), hist={k: tuple(v) for k, v in sim._history.items()},
        lane=(sim._ego_lane, sim._ego_lane_pos_m, sim._route_index, sim._dist_to_target_m),
        signals=sim._signals)
    if sim.outcome == "running":
        c["sumo"] = sumo_vehicles()
    c["ctrl"] = ctrl_state(ep.controller)
    c["plan"] = plan_state(planner)
    # run B asks the rules once more per instant (the regret tap's option): not a state
    c["plan"]["counters"] = {k: v for k, v in vars(c["plan"]["counters"]).items()
                             if k != "backend_calls"}
    c["loop"] = {k: v for k, v in ep._loop.items()
                 if k not in ("solve_ms", "wall_ms", "pending")}
    if states and sim.outcome == "running":
        f = tmp / f"s{sim.step_index}.xml"
        libsumo.simulation.saveState(str(f))
        c["xml"] = f.read_text()
    return c


def run(family: str, seed: int, until_s: float, at: set | None, option_names, lookahead: float,
        states: bool, tag: str) -> list[dict]:
    tmp = Path(tempfile.mkdtemp(prefix=f"probe-{tag}-"))
    sim = SumoSim(work_dir=tmp / "scenes")
    wiring = methods.build(SceneSpec("lmpc-rules", family, seed, log_path=tmp / "log.jsonl"))
    planner = wiring.planner
    wiring.controller.solver.set_warm_state((None, None, False, 0))  # shared per process
    ep = Episode(sim, family=family, seed=seed, controller=wiring.controller,
                 planner=planner, state_dir=tmp / "st")
    oracle = OracleConfig(lookahead_s=lookahead, max_options=32)
    hooked = {"done": []}
    orig_decide = planner._decide

    def decide(scene, mode):
        core = planner
        rules = core._ask(scene, mode, "all", {}, []) if at is not None else None
        chosen = orig_decide(scene, mode)
        t = round(scene.obs.stamp_s, 3)
        if at is not None and (not at or t in at):
            options = options_in(scene, core.space, rules, oracle)
            meta_src = chosen
            from lmpc_llm_planner.validation import DecisionMeta
            meta = DecisionMeta(
                decision_id=meta_src.decision_id, seq=meta_src.seq, source=meta_src.source,
                mode=meta_src.mode, latency_s=meta_src.latency_s,
                tokens_in=meta_src.tokens_in, tokens_out=meta_src.tokens_out,
                ttl_s=meta_src.ttl_s)
            names = [o.name for o in options]
            sel = [o for o in options if option_names == "all" or o.name in option_names]
            decs = [None if o.wire is None else option_decision(core, scene, o.wire, meta,
                                                                core.last_decision)
                    for o in sel]
            snap = ep.snapshot()
            outs = []
            for o, d in zip(sel, decs):
                r = roll_out(ep, snap, d, lookahead_s=lookahead)
                outs.append(f"{o.name}:{r.outcome}")
            ep.restore(snap, planner=False)
            ep.discard(snap)
            hooked["done"].append((t, names, outs))
            print(f"[{tag}] t={t} options={names} rolled={outs}", file=sys.stderr)
        return chosen

    if at is not None:
        planner._decide = decide
    caps = []
    try:
        ep.start()
        while ep.running and ep.time_s < until_s - 1e-9:
            ep.step()
            caps.append(capture(ep, planner, states, tmp))
    finally:
        sim.close()
    return caps


def _state_body(text: str) -> list[str]:
    """A state file's lines after its header (the options differ between the runs)."""
    return text[text.index("<snapshot"):].splitlines()[1:]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--family", default="usi")
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--until", type=float, default=40.0)
    ap.add_argument("--at", default="", help="comma list of instants (s); empty: every one")
    ap.add_argument("--options", default="all")
    ap.add_argument("--lookahead", type=float, default=8.0)
    ap.add_argument("--states", action="store_true")
    ap.add_argument("--base-ask", action="store_true",
                    help="run A also asks the rules twice (as the regret tap does)")
    ap.add_argument("--a-at", default=None, help="run A branches too (as B's --at)")
    ap.add_argument("--a-options", default="all")
    ap.add_argument("--a-lookahead", type=float, default=8.0)
    ap.add_argument("--all-diffs", action="store_true")
    ap.add_argument("--b-first", action="store_true")
    ap.add_argument("--max-report", type=int, default=40)
    a = ap.parse_args()
    at = {round(float(x), 3) for x in a.at.split(",") if x}
    names = "all" if a.options == "all" else set(a.options.split(","))
    if a.b_first:
        B = run(a.family, a.seed, a.until, at, names, a.lookahead, a.states, "B")
    if a.a_at is not None:
        a_at = {round(float(x), 3) for x in a.a_at.split(",") if x}
        a_names = "all" if a.a_options == "all" else set(a.a_options.split(","))
        A = run(a.family, a.seed, a.until, a_at, a_names, a.a_lookahead, a.states, "A")
    else:
        A = run(a.family, a.seed, a.until, set([-1.0]) if a.base_ask else None, names,
                a.lookahead, a.states, "A")
    if not a.b_first:
        B = run(a.family, a.seed, a.until, at, names, a.lookahead, a.states, "B")
    print(f"A: {len(A)} steps, B: {len(B)} steps")
    n_diff = 0
    print("A end:", A[-1]["rec"]["t_s"], A[-1]["rec"]["x_m"], "B end:", B[-1]["rec"]["t_s"],
          B[-1]["rec"]["x_m"])
    for x, y in zip(A, B):
        d = diff({k: v for k, v in x.items() if k != "xml"},
                 {k: v for k, v in y.items() if k != "xml"})
        if "xml" in x and "xml" in y and x["xml"] != y["xml"]:
            xl, yl = _state_body(x["xml"]), _state_body(y["xml"])
            d += ["xml: " + ln for ln in list(difflib.unified_diff(xl, yl, lineterm="", n=0))[:30]]
        if d:
            n_diff += 1
            if n_diff == 1 or a.all_diffs:
                print(f"DIFFERENCE after step {x['step']} (t={x['step'] * 0.1:.1f} s):")
                for line in d[:a.max_report]:
                    print("  ", line[:400])
                print(f"   ... {len(d)} differing fields")
            if not a.all_diffs:
                return
    print("no difference" if not n_diff else f"{n_diff} steps differ")


if __name__ == "__main__":
    main()
