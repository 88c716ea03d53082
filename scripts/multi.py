"""Multi-vehicle episodes in-process (issue 18): wiring, rows and a small CLI.

Each ego ``ego_k`` gets its own MPC controller on its own compiled solver (a solver keeps
the warm start of the ego it serves) and, for the ``lmpc-*`` methods, its own planner core
(``methods.make_planner``). The coordination (``none|distributed|central``) comes from
``lmpc_llm_planner.coordination``; ``central`` uses a coordinator core with the backend
``--coordinator-backend`` (``rules``). ``benchmark.py`` sends the multi-ego families here
(``run_multi_scenes``); the rows: docs/MULTI.md.

    python scripts/multi.py --family narrow --seeds 0-2 --coordination central
"""
from __future__ import annotations

import argparse
import csv
import json
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

from lmpc_msgs_py.cli import folder_arg
from lmpc_scripts.methods import make_planner

MULTI_FAMILIES = ("narrow", "usi-multi", "merge")
"""Families whose scenes carry several egos (``params["egos"]``)."""
MODES = ("none", "distributed", "central")
MULTI_METHODS = ("mpc", "lmpc-rules")
"""The methods a multi-ego episode runs (per ego); the LLM backends are not wired yet."""
ROW_FIELDS = (
    "family", "seed", "method", "coordination", "egos", "reached", "ego_collisions",
    "other_collisions", "deadlock", "timeouts", "clear_s", "joint_oc", "end_s",
    "directives", "directives_refused", "hold_steps", "silent_steps", "min_gap_m", "wall_s",
    "per_ego", "detail")

_SOLVERS: list[Any] = []


def _solver(k: int) -> Any:
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.solver import MpcSolver

    while len(_SOLVERS) <= k:
        s = MpcSolver(load_mpc_config())
        s.warm_up()
        _SOLVERS.append(s)
    _SOLVERS[k].reset()
    return _SOLVERS[k]


class BlindController:
    """An ego's controller with every other vehicle removed from its observation: two
    blind egos collide wherever their paths meet (``--blind``: does a scene make the
    egos meet?)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def compute(self, obs: Any) -> Any:
        from lmpc_msgs_py.observation import Observation

        agents = obs.agents.model_copy(update={"agents": ()})
        return self.inner.compute(Observation(map=obs.map, ego=obs.ego, agents=agents,
                                              signals=obs.signals))

    def on_decision(self, decision: Any) -> Any:
        return self.inner.on_decision(decision)


def wire(method: str, ego_ids: list[str], mode: str, *, coordinator_backend: str = "rules",
         coordinator: Any = None, on_silence: str = "distributed", blind: bool = False
         ) -> tuple[dict[str, Any], Any]:
    """Per-ego wiring (controller, planner) and the coordination of one episode
    (``blind``: controllers that see no other vehicle, :class:`BlindController`)."""
    from lmpc_bridge.multi_episode import EgoWiring
    from lmpc_llm_planner.coordination import (
        Coordination,
        CoordinatorCore,
        make_coordinator_backend,
    )
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.controller import MpcController
    from lmpc_msgs_py.vocabulary import load_decision_space

    if method not in MULTI_METHODS:
        raise ValueError(f"multi-ego episodes run the methods mpc and lmpc-rules, not "
                         f"{method!r}")
    egos = {}
    for k, eid in enumerate(ego_ids):
        controller: Any = MpcController(load_mpc_config(), solver=_solver(k))
        if blind:
            controller = BlindController(controller)
        planner = make_planner(method) if method.startswith("lmpc-") else None
        egos[eid] = EgoWiring(controller=controller, planner=planner)
    if mode == "central" and coordinator is None:
        coordinator = CoordinatorCore(make_coordinator_backend(coordinator_backend))
    coordination = Coordination(mode, ego_ids, load_decision_space(), coordinator=coordinator,
                                on_silence=on_silence)
    return egos, coordination


def closest_approach_m(result: Any) -> Optional[float]:
    """The smallest centre-to-centre distance of two egos at the same step (the egos'
    records; None without records): how close the egos came to each other."""
    import math

    steps: dict[int, list[tuple[float, float]]] = {}
    for rec in getattr(result, "records", {}).values():
        for s in rec.steps:
            steps.setdefault(s.step, []).append((s.x_m, s.y_m))
    gaps = [math.dist(a, b) for pts in steps.values()
            for i, a in enumerate(pts) for b in pts[i + 1:]]
    return min(gaps) if gaps else None


def result_row(result: Any, method: str, mode: str, wall_s: float) -> dict[str, Any]:
    per_ego = {e.ego_id: {"outcome": e.outcome, "time_s": round(e.metrics.time_s, 3),
                          "oc": round(e.metrics.overall_cost, 4),
                          "collided_with": e.collided_with} for e in result.egos}
    st = result.stats
    gap = closest_approach_m(result)
    return {
        "family": result.family, "seed": result.seed, "method": method, "coordination": mode,
        "egos": len(result.egos), "reached": sum(e.outcome == "reached" for e in result.egos),
        "ego_collisions": result.ego_collisions, "other_collisions": result.other_collisions,
        "deadlock": int(result.deadlock),
        "timeouts": sum(e.outcome == "timeout" for e in result.egos),
        "clear_s": "" if result.clear_s is None else round(result.clear_s, 3),
        "joint_oc": round(result.joint_oc, 4), "end_s": round(result.end_s, 3),
        "directives": st.get("directives", 0),
        "directives_refused": st.get("directives_refused", 0),
        "hold_steps": st.get("hold_steps", 0), "silent_steps": st.get("silent_steps", 0),
        "min_gap_m": "" if gap is None else round(gap, 2),
        "wall_s": round(wall_s, 2),
        "per_ego": json.dumps(per_ego, sort_keys=True),
        "detail": "; ".join([f"{e.ego_id}: {e.detail}" for e in result.egos if e.detail]
                            + [f"traffic: {w}" for w in result.warnings])[:500]}


def run_one(family: str, seed: int, method: str, mode: str, work_dir: Path, *,
            coordinator: Any = None, on_silence: str = "distributed",
            max_time_s: float = 120.0, blind: bool = False) -> tuple[Any, dict[str, Any]]:
    from lmpc_bridge.multi_episode import run_multi_episode
    from lmpc_bridge.multi_scene import ego_specs
    from lmpc_bridge.multi_sim import MultiSumoSim
    from lmpc_bridge.scenarios import build_scene

    ids = [s.ego_id for s in ego_specs(build_scene(family, seed, work_dir=work_dir))]
    egos, coordination = wire(method, ids, mode, coordinator=coordinator,
                              on_silence=on_silence, blind=blind)
    started = time.perf_counter()
    result = run_multi_episode(MultiSumoSim(work_dir=work_dir), family=family, seed=seed,
                               egos=egos, coordination=coordination, max_time_s=max_time_s)
    return result, result_row(result, method, mode, time.perf_counter() - started)


def run_multi_scenes(families: list[str], seeds: list[int], methods: list[str],
                     modes: list[str], out: Path, *, max_time_s: float = 120.0,
                     blind: bool = False) -> Path:
    """Every (family, seed, method, mode) in this process; rows to ``out/multi_results.csv``
    (written as they come)."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / "multi_results.csv"
    work_dir = Path(tempfile.mkdtemp(prefix="lmpc-multi-"))  # scene files stay out of ``out``
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=ROW_FIELDS)
        writer.writeheader()
        for family in families:
            for seed in seeds:
                for method in methods:
                    for mode in modes:
                        try:
                            _, row = run_one(family, seed, method, mode, work_dir,
                                             max_time_s=max_time_s, blind=blind)
                        except Exception as exc:  # noqa: BLE001 - one scene, one error row
                            row = {"family": family, "seed": seed, "method": method,
                                   "coordination": mode,
                                   "detail": f"error: {type(exc).__name__}: {exc}"[:500]}
                        writer.writerow(row)
                        fh.flush()
                        print(f"{family} {seed} {method} {mode}: reached {row.get('reached')}"
                              f"/{row.get('egos')} ego-coll {row.get('ego_collisions')} "
                              f"deadlock {row.get('deadlock')} clear {row.get('clear_s')} "
                              f"{row.get('detail', '')[:120]}", flush=True)
    table = multi_table_md(path)
    (out / "multi_table.md").write_text(table)
    print(table)
    return path


def multi_table_md(path: Path) -> str:
    """Per (family, method, coordination): the joint figures of ``multi_results.csv``."""
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    groups: dict[tuple[str, str, str], list[dict[str, str]]] = {}
    for r in rows:
        groups.setdefault((r["family"], r["method"], r["coordination"]), []).append(r)
    lines = ["| family | method | coordination | scenes | all through | ego-ego collisions "
             "| collisions with others | deadlocks | egos timed out | errors "
             "| time to clear, s (mean, all through) | joint O.C. (mean) "
             "| closest egos, m (min / median) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for (family, method, mode), rs in groups.items():
        ok = [r for r in rs if r.get("reached") not in (None, "")]
        errors = len(rs) - len(ok)
        through = [r for r in ok if r["reached"] == r["egos"]]
        clear = [float(r["clear_s"]) for r in through if r["clear_s"]]
        occ = [float(r["joint_oc"]) for r in ok]
        gaps = sorted(float(r["min_gap_m"]) for r in ok if r.get("min_gap_m"))
        lines.append(
            f"| {family} | {method} | {mode} | {len(rs)} | {len(through)} "
            f"| {sum(int(r['ego_collisions']) for r in ok)} "
            f"| {sum(int(r['other_collisions']) for r in ok)} "
            f"| {sum(int(r['deadlock']) for r in ok)} "
            f"| {sum(int(r['timeouts']) for r in ok)} | {errors} "
            f"| {sum(clear) / len(clear) if clear else float('nan'):.1f} "
            f"| {sum(occ) / len(occ) if occ else float('nan'):.1f} "
            f"| {_gaps(gaps)} |")
    return "\n".join(lines) + "\n"


def _gaps(gaps: list[float]) -> str:
    if not gaps:
        return "-"
    n = len(gaps)
    median = gaps[n // 2] if n % 2 else (gaps[n // 2 - 1] + gaps[n // 2]) / 2.0
    return f"{gaps[0]:.1f} / {median:.1f}"


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", default="narrow", choices=MULTI_FAMILIES)
    ap.add_argument("--blind", action="store_true",
                    help="controllers see no other vehicle (do the egos of a scene meet?)")
    ap.add_argument("--seeds", type=_seeds, default=[0])
    ap.add_argument("--methods", default="lmpc-rules")
    ap.add_argument("--coordination", default="none,distributed,central")
    ap.add_argument("--max-time", type=float, default=120.0)
    ap.add_argument("--out", type=folder_arg, default=Path("runs/multi"))
    args = ap.parse_args(argv)
    modes = args.coordination.split(",")
    bad = [m for m in modes if m not in MODES]
    if bad:
        ap.error(f"--coordination {','.join(bad)}: choose from {', '.join(MODES)}")
    path = run_multi_scenes([args.family], args.seeds, args.methods.split(","), modes,
                            args.out, max_time_s=args.max_time, blind=args.blind)
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
