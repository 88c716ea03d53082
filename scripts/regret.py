#!/usr/bin/env python3
"""Regret of a recorded run: at every decision of a finished ``lmpc-*`` benchmark run, how
much better the best option of the oracle's decision space would have done (docs/ORACLE.md,
"Regret").

    regret.py RUN_DIR [--method lmpc-rules] [--out RUN_DIR/regret] [--lookahead-s 8]
              [--continuation none|rules] [--workers N] [--executor pool|ray]
    regret.py --merge REGRET_DIR [REGRET_DIR ...] --out DIR

Each scene of ``RUN_DIR/results.csv`` is run again in-process with the recorded method
(``lmpc-rules`` and ``lmpc-oracle`` are deterministic: the same method repeats the run;
an LLM method is repeated by ``lmpc-replay`` from ``RUN_DIR/decisions/``), with the run's
simulated latency and instruction. At every decision instant, after the planner decided,
the chosen decision and every option of ``method_oracle.decision_options`` are rolled out
for the oracle's lookahead with the oracle's score (``--continuation rules``: the rules
reasoner decides on after each option in its rollout, Table I's oracle judge), each in a
forked copy of the process
(``method_oracle.score_forked``, ``Episode.fork``); the episode itself is never restored
and goes on with the chosen decision exactly as the method's own run did. Regret =
chosen score - best score (O.C. units, >= 0: the chosen decision is one of the
candidates). Options take the chosen decision's
bookkeeping (id, latency, time to live): they differ from it only in content.

Writes OUT/regret.csv (one row per decision), OUT/summary.json, OUT/regret.md and
OUT/regret.png (regret over time of the scene with the largest total regret, and the
per-family distribution). Deterministic: the same run gives the same files (but the
wall-time cells).

``--merge`` writes the same four files for the decisions and scenes of several finished
regret folders (a long run split over sessions or machines), without re-running
anything; a scene found in two folders is refused.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import signal
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from lmpc_bridge.evaluation.executors import EXECUTORS, ExecutorError, workers_arg
from lmpc_bridge.evaluation.rows import percentile, scene_log_name
from lmpc_bridge.evaluation.scenes import FAMILY_MAX_TIME_S, SceneSpec, raise_interrupt
from lmpc_llm_planner.scene import Scene
from lmpc_llm_planner.validation import DecisionMeta
from lmpc_msgs_py.cli import folder_arg
from lmpc_msgs_py.messages import Decision

from lmpc_scripts import methods
from lmpc_scripts.method_oracle import (
    OracleConfig,
    continue_as_rules,
    Pricing,
    options_in,
    option_decision,
    oracle_meta,
    score_forked,
)

PARTS = ("reference", "bias", "weights", "attention")
PART_FIELDS = {"reference": ("ego_trajectory",), "bias": ("accel_interval", "steer_interval"),
               "weights": ("weights",), "attention": ("attention", "agent_predictions")}
"""The ``Decision`` fields of each part of a decision."""
COLUMNS = ("family", "seed", "t_s", "mode", "chosen", "best", "chosen_score", "best_score",
           "regret", "parts", *(f"gain_{p}" for p in PARTS), "options", "repeat_diff",
           "wall_s")
"""``chosen``: the option the chosen decision equals in content, ``chosen`` if none does
(``none``: the planner decided nothing at the instant, the oracle's ``none``); ``best``:
the best candidate (``chosen`` itself on a tie); ``parts``: what the best differs in
(reference / bias / weights / attention, ``+``-joined; empty when regret is 0; ``other``
when it has the chosen decision's content in all four, e.g. ``none`` against a decision
with the baseline's content);
``gain_<part>``: for a decision with a finite regret > 0, how much the chosen decision
gains with only that part taken from the best option (chosen score - score of the
swapped decision, rolled out like the options; with one part differing, the regret
itself, no extra rollout); empty where the part does not differ or either decision is
none. The gains need not add up to the regret (the parts interact);
``repeat_diff``: the chosen decision rolled out once more after the options, the
difference of its score from the first rollout (0 when the branches repeat exactly)."""
TIE_TOL = 1e-9
"""Scores closer than this count as a tie (regret 0)."""


class RegretError(Exception):
    """A run folder this tool cannot use (one-line message)."""


@dataclass
class _Context:
    """The regret state a wrapped planner carries (shared, never snapshotted)."""

    family: str
    seed: int
    oracle: OracleConfig
    part: tuple[int, int] = (0, 1)
    """(i, n): judge only the decision instants k with k % n == i (the episode runs in
    full: a scene split over n workers, ``run``)."""
    episode: Any = None
    rows: list[dict[str, Any]] = field(default_factory=list)
    instants: list[float] = field(default_factory=list)
    """Every decision instant of the re-run, judged here or not."""


def _content(d: Optional[Decision], baseline: tuple) -> tuple:
    """(reference, bias, weights, attention) of a decision; None: the baseline's."""
    if d is None:
        return baseline
    return (d.ego_trajectory.candidate_id, (d.accel_interval, d.steer_interval),
            d.weights.model_dump(), (tuple(sorted(d.attention)), tuple(sorted(
                (p.agent_id, p.trajectory.candidate_id) for p in d.agent_predictions))))


class RegretMixin:
    """Mixed into the recorded method's planner class (:func:`tap`): its ``_decide`` is
    the method's own, followed by the rollouts of the chosen decision and every option,
    each in a forked copy of the process (the episode then goes on with the chosen one)."""

    _regret: _Context

    def attach_episode(self, episode: Any) -> None:
        self._regret.episode = episode
        parent = getattr(super(), "attach_episode", None)
        if parent is not None:
            parent(episode)

    def _decide(self, scene: Scene, mode: Any) -> Optional[Decision]:
        if getattr(self, "_judging", False):  # a rollout's continuation (:meth:`_then`)
            return super()._decide(scene, mode)  # type: ignore[misc]
        core: Any = self
        ctx = self._regret
        if ctx.episode is None:
            raise RuntimeError("regret needs the episode (Episode.attach_episode)")
        previous = core.last_decision
        rules = None
        if core.backend.name == "rules":  # the rules' answer is an option, as in the oracle
            rules = core._ask(scene, mode, "all", {}, [])
        chosen: Optional[Decision] = super()._decide(scene, mode)  # type: ignore[misc]
        ctx.instants.append(round(scene.obs.stamp_s, 3))
        if (len(ctx.instants) - 1) % ctx.part[1] != ctx.part[0]:
            return chosen  # another part's instant (what follows only forks and reads)
        t0 = time.perf_counter()
        ep = ctx.episode
        dt = ep.sim.dt_s
        options = options_in(scene, core.space, rules, ctx.oracle)
        if chosen is not None:
            meta = DecisionMeta(
                decision_id=chosen.decision_id, seq=chosen.seq, source=chosen.source,
                mode=chosen.mode, latency_s=chosen.latency_s, tokens_in=chosen.tokens_in,
                tokens_out=chosen.tokens_out, ttl_s=chosen.ttl_s)
        else:
            meta = oracle_meta(core, scene, mode, dt, commit=False)
        decisions = [None if o.wire is None else option_decision(core, scene, o.wire, meta,
                                                                 previous) for o in options]
        # every rollout in a forked copy of the process (Episode.fork): the episode here
        # is never restored, so the re-run goes on exactly as the method's own run (a
        # restore is exact only up to SUMO's bookkeeping outside its state file;
        # docs/BRANCHING.md)
        pricing = Pricing.at(ep, ep.sim, scene.obs, ctx.oracle)
        chosen_score = self._score(chosen, pricing)
        scores = [self._score(d, pricing) for d in decisions]
        # the chosen one again, after the options: how exactly the branches repeat
        again = self._score(chosen, pricing)
        base = _baseline_content(scene, core.space)
        key = _content(chosen, base)
        name = next((o.name for o, d in zip(options, decisions)
                     if (d is None) == (chosen is None) and _content(d, base) == key),
                    "chosen")
        best_i = min(range(len(options)), key=lambda i: (scores[i], i))
        best_score = scores[best_i]
        if not best_score < chosen_score - TIE_TOL:  # chosen is (one of) the best
            best, best_score, regret, parts = name, chosen_score, 0.0, ""
        else:
            best = options[best_i].name
            regret = chosen_score - best_score
            other = _content(decisions[best_i], base)
            # "other": the same four parts, e.g. no decision against a decision with the
            # baseline's content, or a kept emergency trajectory
            parts = "+".join(p for p, a, b in zip(PARTS, key, other) if a != b) or "other"
        donor = None
        if parts != "":
            donor = decisions[best_i] if decisions[best_i] is not None else \
                self._baseline_decision(scene, options, decisions, meta, previous)
        gains = self._gains(chosen, donor, parts, chosen_score, regret, pricing)
        ctx.rows.append({
            "family": ctx.family, "seed": ctx.seed, "t_s": round(scene.obs.stamp_s, 3),
            "mode": mode, "chosen": name, "best": best, "chosen_score": chosen_score,
            "best_score": best_score, "regret": regret, "parts": parts,
            **{f"gain_{p}": gains.get(p, "") for p in PARTS}, "options": len(options),
            "repeat_diff": _diff(again, chosen_score),
            "wall_s": round(time.perf_counter() - t0, 3)})
        return chosen

    def _baseline_decision(self, scene: Scene, options: list[Any],
                           decisions: list[Optional[Decision]], meta: DecisionMeta,
                           previous: Optional[Decision]) -> Decision:
        """A decision with the baseline's content (the option ``route/a<neutral>``: route
        candidate, neutral bias, normal weights, baseline attention), the parts' donor
        when the best option is ``none``."""
        core: Any = self
        name = f"route/a{core.space.neutral_accel_index}"
        for o, d in zip(options, decisions):
            if o.name == name and d is not None:
                return d
        full = options_in(scene, core.space, None, dataclasses.replace(
            self._regret.oracle, max_options=1000, encoding="baseline"))
        wire = next(o.wire for o in full if o.name == name)
        assert wire is not None
        return option_decision(core, scene, wire, meta, previous)

    def _gains(self, chosen: Optional[Decision], best: Optional[Decision], parts: str,
               chosen_score: float, regret: float, pricing: Any) -> dict[str, float]:
        """``gain_<part>`` of the row (see ``COLUMNS``)."""
        differ = [p for p in parts.split("+") if p in PARTS]
        if chosen is None or best is None or not differ or not 0.0 < regret < math.inf:
            return {}
        if len(differ) == 1:
            return {differ[0]: regret}
        return {p: chosen_score - self._score(swap_part(chosen, best, p), pricing)
                for p in differ}

    def _score(self, decision: Optional[Decision], pricing: Any) -> float:
        """``decision``'s rollout score in a forked copy, under the judge's continuation."""
        ctx = self._regret
        return score_forked(ctx.episode, decision, ctx.oracle, pricing,
                            then=self._then(decision))

    def _then(self, decision: Optional[Decision]) -> Optional[Callable[[], Any]]:
        """What decides after ``decision`` in its rollout (``OracleConfig.continuation``,
        as in the oracle): with ``rules``, this planner in the forked copy, ``decision``
        taken as its last one, deciding from the next instant on as the rules planner
        does (the rules backend, whatever the recorded method's; the recorded method's
        cadence and latency), without regret rollouts and without writing a log; nothing
        after ``none`` or after no decision (the baseline stays the baseline)."""
        if self._regret.oracle.continuation == "none" or decision is None:
            return None

        def rules_from_here() -> Any:
            core: Any = self
            core._judging = True
            if hasattr(core, "_as_rules"):  # the oracle's own planner: decide as rules
                core._as_rules = True
            continue_as_rules(core, decision)
            return core

        return rules_from_here


def swap_part(decision: Decision, donor: Decision, part: str) -> Decision:
    """``decision`` with ``part`` (one of ``PARTS``) taken from ``donor``, its bookkeeping
    kept; validated (attention and predictions travel together)."""
    fields = PART_FIELDS[part]
    return Decision.model_validate(decision.model_copy(
        update={f: getattr(donor, f) for f in fields}).model_dump())


def _diff(a: float, b: float) -> float:
    """|a - b|, 0 for two equal infinities."""
    return 0.0 if a == b else abs(a - b)


def _baseline_content(scene: Scene, space: Any) -> tuple:
    """What no decision amounts to: the route, neutral bias, normal weights, every offered
    agent with its closest-heading prediction (the planner's fallback)."""
    from lmpc_msgs_py.messages import WeightLevels

    return (scene.route_candidate_id, (space.neutral_accel_index, space.neutral_steer_index),
            WeightLevels().model_dump(),
            (tuple(sorted(scene.agent_ids)),
             tuple(sorted((v.id, v.closest_heading_id) for v in scene.agents))))


def tap(planner: Any, ctx: _Context) -> Any:
    """``planner`` (a ``PlannerCore`` or subclass, e.g. the oracle's) with the regret
    rollouts after each of its decisions: its class becomes a subclass mixing in
    :class:`RegretMixin`; its state is untouched."""
    cls = type(planner)
    planner.__class__ = type(f"Regret{cls.__name__}", (RegretMixin, cls),
                             {"_SHARED": cls._SHARED + ("_regret",)})
    planner._regret = ctx
    return planner


# --- one scene -------------------------------------------------------------------------
def rerun_method(method: str) -> str:
    """The method that repeats a recorded ``method`` in-process."""
    if method in ("lmpc-rules", "lmpc-oracle"):
        return method
    if method in methods.LLM_METHODS:
        return "lmpc-replay"
    raise RegretError(f"cannot take the regret of {method!r}: one of lmpc-rules, lmpc-oracle, "
                      f"{', '.join(m for m in methods.LLM_METHODS if m != 'lmpc-rules')}")


def _latency(row: dict[str, Any]) -> tuple[Optional[float], Optional[float]]:
    def cell(v: Any) -> Optional[float]:
        return None if v in ("", None) or (isinstance(v, float) and math.isnan(v)) else float(v)
    return (cell(row.get("latency_s")), cell(row.get("emergency_latency_s")))


def _float(v: Any) -> float:
    return float(v) if v not in ("", None) else math.nan


def regret_of_scene(run_dir: Path, row: dict[str, Any], *, sim: Any, oracle: OracleConfig,
                    instruction: Optional[str] = None, build: Optional[Any] = None,
                    max_time_s: float = FAMILY_MAX_TIME_S, part: tuple[int, int] = (0, 1)
                    ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The regret rows of one recorded scene and how the re-run compares with the row.
    ``build``: the wiring factory (default the method registry's; a test passes the
    oracle with its own config); ``max_time_s``: the episode cap; ``part``: judge only
    that share of the decision instants (``_Context.part``; ``merge_parts`` joins them)."""
    from lmpc_bridge.episode import Episode

    method, family, seed = row["method"], row["family"], int(row["seed"])
    again = rerun_method(method)
    spec = SceneSpec(method=again, family=family, seed=seed, instruction=instruction,
                     replay=(str(run_dir.resolve()), method) if again == "lmpc-replay" else None,
                     latency=_latency(row))
    wiring = (build or methods.build)(spec)
    if wiring.planner is None:
        raise RegretError(f"{method} has no planner")
    ctx = _Context(family, seed, oracle, part=part)
    planner = tap(wiring.planner, ctx)
    t0 = time.perf_counter()
    episode = Episode(sim, family=family, seed=seed, controller=wiring.controller,
                      planner=planner, max_time_s=max_time_s)
    episode.start()
    episode.run()
    m = episode.result().metrics
    outcome = episode.sim.outcome
    recorded = recorded_instants(run_dir / "decisions" / scene_log_name(family, seed, method))
    scene = {
        "family": family, "seed": seed, "method": method, "rerun_as": again,
        "recorded": {"outcome": row["outcome"], "time_s": _float(row["time_s"]),
                     "overall_cost": _float(row["overall_cost"])},
        "rerun": {"outcome": outcome, "time_s": round(m.time_s, 3),
                  "overall_cost": round(m.overall_cost, 4)},
        "decisions": len(ctx.rows), "recorded_decisions": None if recorded is None
        else len(recorded),
        "wall_s": round(time.perf_counter() - t0, 2)}
    scene["repeats_recorded_row"] = (
        outcome == row["outcome"] and abs(round(m.time_s, 3) - _float(row["time_s"])) < 1e-6
        and abs(m.overall_cost - _float(row["overall_cost"])) <= 2e-4)
    scene["same_instants"] = recorded is not None and \
        [round(t, 3) for t in recorded] == ctx.instants
    return ctx.rows, scene


def merge_parts(parts: list[tuple[list[dict[str, Any]], dict[str, Any]]]
                ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """One scene's rows and record from its parts (``regret_of_scene(part=...)``: the same
    re-run, each judging its share of the instants); ``wall_s``: the slowest part's."""
    rows = sorted((r for got, _ in parts for r in got), key=lambda r: r["t_s"])
    scene = dict(parts[0][1], decisions=len(rows),
                 wall_s=max(sc["wall_s"] for _, sc in parts))
    if len(parts) > 1:
        scene["parts"] = len(parts)
    return rows, scene


def recorded_instants(log: Path) -> Optional[list[float]]:
    """Stamps of the decision instants of a recorded decision log (None: no log)."""
    if not log.is_file():
        return None
    out = []
    for line in log.read_text(encoding="utf-8").splitlines():
        rec = json.loads(line)
        if rec.get("kind") == "oracle" or ("decision_id" in rec and "kind" not in rec):
            out.append(float(rec["stamp_s"]))
    return out


# --- summary ---------------------------------------------------------------------------
def _num(x: float) -> Any:
    return ("inf" if x > 0 else "-inf") if math.isinf(x) else round(x, 6)


def summarise(rows: list[dict[str, Any]], scenes: list[dict[str, Any]]) -> dict[str, Any]:
    """Per family: decisions, median / p90 / mean regret, share at 0, regret by part, the
    ten worst decisions."""
    fams: dict[str, Any] = {}
    for fam in sorted({r["family"] for r in rows} | {s["family"] for s in scenes}):
        rs = [r for r in rows if r["family"] == fam]
        reg = [r["regret"] for r in rs]
        by_part: dict[str, float] = {}
        recovered = dict.fromkeys(PARTS, 0.0)
        finite = 0.0
        for r in rs:
            if r["regret"] > 0.0 and math.isfinite(r["regret"]):
                finite += r["regret"]
                for p in r["parts"].split("+"):
                    by_part[p] = by_part.get(p, 0.0) + r["regret"]
                for p in PARTS:
                    g = r.get(f"gain_{p}", "")
                    if g != "":  # a part alone recovers at most the regret, at least 0
                        recovered[p] += min(max(float(g), 0.0), r["regret"])
        worst = sorted(rs, key=lambda r: (-r["regret"], r["seed"], r["t_s"]))[:10]
        fams[fam] = {
            "decisions": len(rs),
            "regret_median": _num(statistics.median(reg)) if reg else None,
            "regret_p90": _num(percentile(reg, 0.9)) if reg else None,
            "regret_mean": _num(statistics.fmean(reg)) if reg else None,
            "share_zero": round(sum(x == 0.0 for x in reg) / len(reg), 4) if reg else None,
            "infinite": sum(math.isinf(x) for x in reg),
            "repeat_diff_max": _num(max((r["repeat_diff"] for r in rs), default=0.0)),
            "regret_by_part": {k: round(v, 4) for k, v in sorted(by_part.items())},
            "share_recovered_by_part": {p: round(v / finite, 4) if finite > 0 else None
                                        for p, v in recovered.items()},
            "worst": [{k: (_num(v) if isinstance(v, float) else v) for k, v in r.items()
                       if k != "wall_s"} for r in worst],
        }
    return {"families": fams, "scenes": scenes}


def summary_md(summary: dict[str, Any], run_dir: Path) -> str:
    lines = [f"# Regret of {run_dir}", "",
             "Regret = chosen decision's rollout score - best option's (O.C. units; "
             "docs/ORACLE.md, \"Regret\"). Judge: each rollout "
             f"{summary.get('lookahead_s', OracleConfig.lookahead_s):g} s, continuation "
             f"{summary.get('continuation', 'none')}.", "",
             "| family | decisions | median | p90 | mean | share 0 | by part | recovered by "
             "the part alone |",
             "|---|---|---|---|---|---|---|---|"]
    for fam, s in summary["families"].items():
        parts = ", ".join(f"{k} {v}" for k, v in s["regret_by_part"].items())
        alone = ", ".join(f"{k} {v:.0%}" for k, v in s["share_recovered_by_part"].items()
                          if v is not None)
        lines.append(f"| {fam} | {s['decisions']} | {s['regret_median']} | {s['regret_p90']} "
                     f"| {s['regret_mean']} | {s['share_zero']} | {parts} | {alone} |")
    lines += ["", "By part: the regret of every decision whose best option differs in that "
              "part (a decision counts in each part it differs in). Recovered by the part "
              "alone: the share of the finite regret won back by taking only that part from "
              "the best option (each decision's gain clipped to [0, its regret]; the shares "
              "need not add up to 100 %: the parts interact)."]
    for fam, s in summary["families"].items():
        lines += ["", f"## {fam}: the worst decisions", "",
                  "| seed | t (s) | chosen | best | regret | parts |", "|---|---|---|---|---|---|"]
        for r in s["worst"]:
            lines.append(f"| {r['seed']} | {r['t_s']} | {r['chosen']} | {r['best']} | "
                         f"{r['regret']} | {r['parts']} |")
    lines += ["", "Render one: `render.py run --family F --seed S --method lmpc-rules "
              "--max-time-s T+8 --out x.png`.", "",
              "| scene | recorded | re-run | repeats the row | same instants | decisions "
              "(recorded) | wall s |", "|---|---|---|---|---|---|---|"]
    for sc in summary["scenes"]:
        if "skipped" in sc:
            lines.append(f"| {sc['family']} {sc['seed']} | {sc['skipped']} | | | | | |")
            continue
        rec, again = sc["recorded"], sc["rerun"]
        lines.append(
            f"| {sc['family']} {sc['seed']} | {rec['outcome']} {rec['time_s']} s, "
            f"{rec['overall_cost']} | {again['outcome']} {again['time_s']} s, "
            f"{again['overall_cost']} | {sc['repeats_recorded_row']} | "
            f"{sc['same_instants']} | {sc['decisions']} ({sc['recorded_decisions']}) | "
            f"{sc['wall_s']} |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict[str, Any]], out: Path) -> Optional[Path]:
    """Regret over time of the scene with the largest finite total regret, and the
    per-family distribution (a strip of every decision's regret)."""
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    totals: dict[tuple[str, int], float] = {}
    for r in rows:
        if math.isfinite(r["regret"]):
            totals[(r["family"], r["seed"])] = totals.get((r["family"], r["seed"]), 0.0) \
                + r["regret"]
    scene = max(sorted(totals), key=lambda k: totals[k]) if totals else \
        (rows[0]["family"], rows[0]["seed"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    rs = [r for r in rows if (r["family"], r["seed"]) == scene and math.isfinite(r["regret"])]
    a.stem([r["t_s"] for r in rs], [r["regret"] for r in rs])
    a.set(xlabel="sim time (s)", ylabel="regret (O.C. units)",
          title=f"{scene[0]} seed {scene[1]}: regret per decision")
    fams = sorted({r["family"] for r in rows})
    for i, fam in enumerate(fams):
        vals = sorted(r["regret"] for r in rows if r["family"] == fam
                      and math.isfinite(r["regret"]))
        xs = [i + 0.3 * ((k % 7) / 6.0 - 0.5) for k in range(len(vals))]
        b.scatter(xs, vals, s=10, alpha=0.6)
        if vals:
            b.hlines([statistics.median(vals), percentile(vals, 0.9)], i - 0.25, i + 0.25,
                     colors=["k", "r"])
    b.set_xticks(range(len(fams)), fams)
    b.set(ylabel="regret (O.C. units)", title="per family (black median, red p90)")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (_num(v) if isinstance(v, float) and k != "t_s" else v)
                        for k, v in r.items()})


# --- command line ----------------------------------------------------------------------
def _pick_method(rows: list[dict[str, Any]], wanted: Optional[str]) -> str:
    found = sorted({r["method"] for r in rows if r["method"].startswith("lmpc-")
                    and r["method"] != "lmpc-replay"})
    if wanted is not None:
        if wanted not in found:
            raise RegretError(f"no {wanted} rows in the run (it has {', '.join(found) or 'none'})")
        return wanted
    if len(found) != 1:
        raise RegretError(f"the run has {len(found)} lmpc-* methods ({', '.join(found)}): "
                          "name one with --method")
    return found[0]


_WORKER_SIM: Any = None
"""The simulation of this worker process (libsumo: one per process), made by its first
scene."""


def regret_job(run_dir: str, row: dict[str, Any], oracle: OracleConfig,
               instruction: Optional[str], part: tuple[int, int] = (0, 1)
               ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """``regret_of_scene`` in a worker process of an executor (the local pool or a Ray
    task; ``lmpc_bridge.evaluation.executors``)."""
    global _WORKER_SIM
    if _WORKER_SIM is None:
        from lmpc_bridge.sim import SumoSim

        methods.prepare()
        _WORKER_SIM = SumoSim(work_dir=Path(tempfile.mkdtemp(prefix="lmpc-regret-")))
    return regret_of_scene(Path(run_dir), row, sim=_WORKER_SIM, oracle=oracle,
                           instruction=instruction, part=part)


def run(run_dir: Path, *, method: Optional[str] = None, out: Optional[Path] = None,
        oracle: OracleConfig = OracleConfig(), progress: bool = True, workers: int = 1,
        executor: str = "pool") -> dict[str, Any]:
    """The regret of every scene of ``run_dir`` (one method); writes the files to ``out``
    (default ``run_dir/regret``) and returns the summary. The scenes run in ``workers``
    processes of ``executor`` (``pool`` or ``ray``, as ``benchmark.py``'s; the rows do
    not depend on either); with fewer scenes than workers each scene is split into
    ``workers // scenes`` parts that each re-run it and judge every n-th decision instant.
    Ctrl-C or SIGTERM: the files get the finished scenes."""
    from lmpc_bridge.evaluation.executors import make_executor

    csv_path = run_dir / "results.csv"
    if not csv_path.is_file():
        raise RegretError(f"{csv_path} not found: pass a finished benchmark.py --out folder")
    with csv_path.open(newline="") as fh:
        raw = list(csv.DictReader(fh))
    method = _pick_method(raw, method)
    rerun_method(method)
    recorded = [dict(r, seed=int(r["seed"])) for r in raw if r["method"] == method]
    instruction = None
    if (run_dir / "summary.json").is_file():
        instruction = json.loads((run_dir / "summary.json").read_text()).get("instruction")
    out = out or run_dir / "regret"
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    scenes: list[dict[str, Any]] = []
    todo = []
    for row in sorted(recorded, key=lambda r: (r["family"], r["seed"])):
        if row["outcome"] == "error":
            scenes.append({"family": row["family"], "seed": row["seed"],
                           "skipped": f"error row: {row['detail']}"})
        else:
            todo.append(row)
    # by name from the package (a Ray worker cannot import this file as __main__)
    from lmpc_scripts.regret import regret_job as job

    # fewer scenes than workers: each scene's instants are split over several (every part
    # re-runs the whole episode and judges its share; the rows are those of one part)
    n_parts = max(1, workers // max(len(todo), 1))
    jobs = [(k, (i, n_parts)) for k in range(len(todo)) for i in range(n_parts)]
    t0 = time.monotonic()
    interrupted = False
    with make_executor(executor, workers) as ex:
        signal.signal(signal.SIGTERM, raise_interrupt)
        try:
            calls = [(str(run_dir), todo[k], oracle, instruction, part) for k, part in jobs]
            pending: dict[int, list[Any]] = {}
            done = 0
            for j, result in ex.results(job, calls):
                k = jobs[j][0]
                pending.setdefault(k, []).append(result)
                if len(pending[k]) < n_parts:
                    continue
                done += 1
                row = todo[k]
                results = pending.pop(k)
                failed = [r for r in results if isinstance(r, BaseException)]
                if failed:
                    scenes.append({"family": row["family"], "seed": row["seed"],
                                   "skipped": f"{type(failed[0]).__name__}: {failed[0]}"})
                    continue
                got, scene = merge_parts(results)
                rows += got
                scenes.append(scene)
                if progress:
                    elapsed = time.monotonic() - t0
                    print(f"[{done}/{len(todo)}] {row['family']} seed {row['seed']}: "
                          f"{len(got)} decisions, regret sum "
                          f"{sum(r['regret'] for r in got):.3f}, repeats row "
                          f"{scene['repeats_recorded_row']} ({scene['wall_s']} s; elapsed "
                          f"{elapsed:.0f} s, ETA {elapsed / done * (len(todo) - done):.0f} s)",
                          flush=True)
        except KeyboardInterrupt:
            interrupted = True
            ex.abort()
            print(f"regret.py: interrupted after {len(scenes)} of {len(recorded)} scenes; "
                  "writing those", file=sys.stderr, flush=True)
        finally:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return write_files(out, rows, scenes, run_dir, run_dir=str(run_dir), method=method,
                       lookahead_s=oracle.lookahead_s, continuation=oracle.continuation,
                       wall_time_s=round(time.monotonic() - t0, 1), workers=workers,
                       executor=executor, interrupted=interrupted)


def write_files(out: Path, rows: list[dict[str, Any]], scenes: list[dict[str, Any]],
                title: Path, **about: Any) -> dict[str, Any]:
    """regret.csv, summary.json (the summary plus ``about``), regret.md and regret.png in
    ``out``, rows and scenes sorted (the same files whatever order the scenes finished
    in); returns the summary."""
    rows.sort(key=lambda r: (r["family"], r["seed"], r["t_s"]))
    scenes.sort(key=lambda sc: (sc["family"], sc["seed"]))
    summary = summarise(rows, scenes)
    summary.update(about)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "regret.csv", rows)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "regret.md").write_text(summary_md(summary, title))
    plot(rows, out / "regret.png")
    return summary


_INT_COLUMNS = ("seed", "options")
_TEXT_COLUMNS = ("family", "mode", "chosen", "best", "parts")


def read_regret_csv(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``regret.csv`` with the types :func:`run` wrote them from (numbers;
    an empty gain cell stays empty)."""
    with path.open(newline="") as fh:
        raw = list(csv.DictReader(fh))
    out = []
    for r in raw:
        row: dict[str, Any] = {}
        for k in COLUMNS:
            v = r.get(k)
            if v is None:
                raise RegretError(f"{path}: column {k!r} missing")
            if k in _TEXT_COLUMNS or (k.startswith("gain_") and v == ""):
                row[k] = v
            elif k in _INT_COLUMNS:
                row[k] = int(v)
            else:
                row[k] = float(v)
        out.append(row)
    return out


def merge(dirs: Sequence[Path], out: Path) -> dict[str, Any]:
    """One set of regret files from several finished regret folders (``run``'s output)."""
    rows: list[dict[str, Any]] = []
    scenes: list[dict[str, Any]] = []
    sources = []
    for d in dirs:
        summary_path, csv_path = d / "summary.json", d / "regret.csv"
        for f in (summary_path, csv_path):
            if not f.is_file():
                raise RegretError(f"{f} not found: pass folders written by regret.py")
        part = json.loads(summary_path.read_text())
        seen = {(sc["family"], sc["seed"]) for sc in scenes}
        twice = sorted(f"{sc['family']} {sc['seed']}" for sc in part["scenes"]
                       if (sc["family"], sc["seed"]) in seen)
        if twice:
            raise RegretError(f"{d}: scenes already merged from another folder: "
                              + ", ".join(twice))
        scenes += part["scenes"]
        rows += read_regret_csv(csv_path)
        keys = ("run_dir", "method", "lookahead_s", "wall_time_s", "workers", "interrupted")
        # folders written before the continuation option judged without one
        sources.append({**{k: part.get(k) for k in keys},
                        "continuation": part.get("continuation", "none")})
    judges = {(s["method"], s["lookahead_s"], s["continuation"]) for s in sources}
    if len(judges) > 1:
        raise RegretError("the folders differ in method, lookahead or continuation: "
                          + ", ".join(f"{s['method']} {s['lookahead_s']} s continuation "
                                      f"{s['continuation']}" for s in sources))
    return write_files(out, rows, scenes, merged_title(dirs), method=sources[0]["method"],
                       lookahead_s=sources[0]["lookahead_s"],
                       continuation=sources[0]["continuation"],
                       merged_from=[str(d) for d in dirs], sources=sources)


def merged_title(dirs: Sequence[Path]) -> Path:
    return Path(" + ".join(map(str, dirs)))


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path, nargs="?",
                    help="a finished benchmark.py --out folder")
    ap.add_argument("--merge", type=Path, nargs="+", metavar="REGRET_DIR",
                    help="merge finished regret folders into --out (no re-run)")
    ap.add_argument("--method", help="the lmpc-* method of the run (needed if it has several)")
    ap.add_argument("--out", type=folder_arg, help="output folder (default RUN_DIR/regret)")
    ap.add_argument("--lookahead-s", type=float, default=OracleConfig.lookahead_s,
                    help="rollout length, s of sim time (default: the oracle's)")
    ap.add_argument("--continuation", choices=("none", "rules"),
                    default=OracleConfig.continuation,
                    help="what decides after an option in its rollout: none (default: the "
                         "option until it expires, then the MPC baseline) or rules (the "
                         "rules reasoner at the planner's cadence, as Table I's oracle rows "
                         "with --oracle-continuation rules)")
    ap.add_argument("--workers", type=workers_arg, default=1,
                    help="scenes at once (worker processes / Ray CPUs; default 1); with "
                         "fewer scenes, each is split over N // scenes workers")
    ap.add_argument("--executor", choices=EXECUTORS, default="pool",
                    help="pool: local worker processes (default); ray: Ray tasks, on the "
                         "cluster at $RAY_ADDRESS or a local Ray (docs/CLUSTER.md)")
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error(f"--workers must be >= 1, got {args.workers}")
    if args.merge:
        if args.run_dir is not None or args.out is None:
            ap.error("--merge takes regret folders and --out, no RUN_DIR")
        try:
            summary = merge(args.merge, args.out)
        except (RegretError, ValueError, KeyError) as exc:
            print(f"regret.py: {exc}", file=sys.stderr)
            return 2
        print(summary_md(summary, merged_title(args.merge)), end="")
        return 0
    if args.run_dir is None:
        ap.error("RUN_DIR is required (or --merge)")
    try:
        oracle = OracleConfig(lookahead_s=args.lookahead_s, continuation=args.continuation)
        summary = run(args.run_dir, method=args.method, out=args.out, oracle=oracle,
                      workers=args.workers, executor=args.executor)
    except (RegretError, ValueError, ExecutorError) as exc:
        print(f"regret.py: {exc}", file=sys.stderr)
        return 2
    print(summary_md(summary, args.run_dir), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
