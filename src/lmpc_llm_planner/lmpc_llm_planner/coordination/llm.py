"""LLM backends of the central coordinator (issue 18: ``openai``, ``local``, ``replay``).

The paper's central LLM reads the vehicles' local statuses and issues coordinated
commands. Here a coordinator round with an LLM backend is:

1. **prompt**: the task, the egos in a shared conflict (one line each, from their
   :class:`EgoStatus`: speed, intent, distances to the conflict's entry / hold point /
   exit, whether it can still stop before the hold point, the vehicles it sees coming)
   and the answer's form (:func:`coordinator_prompt`); the statuses are the egos' own
   reports, so nothing in the prompt is user text;
2. **answer**: one JSON object ``{"reasoning", "verdicts": [{"ego_id", "command",
   "priority"}]}`` constrained by :func:`coordinator_schema` (the ego ids offered as an
   enum) — the same structured-output call the planner makes
   (``OpenAIBackend.complete_json``, ``LocalBackend.complete_json``);
3. **validation** (:func:`parse_verdicts`): JSON, the schema, ego ids in the round, one
   verdict per ego, and the safety rule of the fixed rule set: **two directions of one
   conflict may not both proceed**, and an ego that can no longer stop before its hold
   point is not told to yield (it goes through whatever it is told). A refused or failed
   answer is a silent round: no directive; the egos' silent-coordinator fallback
   (``session.py``: the distributed rule set) takes over until the coordinator speaks
   again. Counted per kind in ``errors``;
4. **log**: one JSON line per call (stamp, prompt and its sha256, answer text, error,
   latency, source) when ``log_path`` is set; :class:`ReplayCoordinator` answers a later
   run from it by prompt hash, so a recorded LLM coordination repeats without the model.

The LLM only orders the egos; the speed band and deadline of each directive come from
``CoordinatorCore`` as for the ``rules`` backend, and each ego's MPC keeps its own
safety checks.
"""
from __future__ import annotations

import hashlib
import json
import threading
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, Optional

from lmpc_msgs_py.coordination import EgoStatus

from lmpc_llm_planner.backends.base import BackendError, BackendReply
from lmpc_llm_planner.coordination.rules import ENGAGE_M, Verdict, committed

Ask = Callable[[str, str, dict[str, Any], float], BackendReply]
"""``ask(system, user, schema, deadline_s)``: one structured completion."""

DEADLINE_S = 8.0
MAX_REASONING_CHARS = 300

SYSTEM_PROMPT = (
    "You are the central coordinator of several autonomous cars that share a conflict "
    "zone (a one-lane section, a junction or a merge). Each car reports its status; you "
    "decide which car goes first. Answer with exactly one JSON object matching the schema "
    "in the user message: \"reasoning\" first and short, then one verdict per car listed. "
    "No Markdown, no text before or after the object."
)


def participants(statuses: Sequence[EgoStatus]) -> list[EgoStatus]:
    """The egos a round is about: a conflict ahead within ``ENGAGE_M``, not yet through
    (as the fixed rule set counts them)."""
    return sorted((st for st in statuses
                   if st.conflict is not None and st.intent not in ("done", "through")
                   and st.conflict.dist_to_exit_m > 0.0
                   and st.conflict.dist_to_entry_m <= ENGAGE_M),
                  key=lambda st: st.ego_id)


def coordinator_schema(egos: Sequence[EgoStatus], *,
                       max_reasoning_chars: int = MAX_REASONING_CHARS) -> dict[str, Any]:
    """The answer's JSON schema for a round with ``egos`` (their ids as an enum)."""
    ids = [st.ego_id for st in egos]
    return {
        "type": "object",
        "properties": {
            "reasoning": {"type": "string", "maxLength": max_reasoning_chars},
            "verdicts": {
                "type": "array", "minItems": len(ids), "maxItems": len(ids),
                "items": {
                    "type": "object",
                    "properties": {
                        "ego_id": {"type": "string", "enum": ids},
                        "command": {"type": "string", "enum": ["proceed", "yield"]},
                        "priority": {"type": "integer", "minimum": 0,
                                     "maximum": max(len(ids) - 1, 0)},
                    },
                    "required": ["ego_id", "command", "priority"],
                    "additionalProperties": False,
                },
            },
        },
        "required": ["reasoning", "verdicts"],
        "additionalProperties": False,
    }


def _line(st: EgoStatus) -> str:
    c = st.conflict
    assert c is not None
    stop = "no (committed: it goes through)" if committed(st) else "yes"
    seen = ", ".join(c.oncoming) or "none"
    follows = ", ".join(c.inbound) or "none"
    return (f"- {st.ego_id}: {st.v_mps:.1f} m/s, intent {st.intent}, conflict "
            f"{c.conflict_id} ({c.kind}) in direction {c.via}; {c.dist_to_entry_m:.0f} m to "
            f"its entry, {c.dist_to_hold_m:.0f} m to its hold point, {c.dist_to_exit_m:.0f} m "
            f"until it has left it; inside: {'yes' if c.inside else 'no'}; can still stop "
            f"before the hold point: {stop}; other vehicles coming against it: {seen}; "
            f"following it in: {follows}.")


def coordinator_prompt(egos: Sequence[EgoStatus], now_s: float, *,
                       max_reasoning_chars: int = MAX_REASONING_CHARS) -> str:
    """The user message of a round (see the module docstring)."""
    lines = [f"Time {now_s:.1f} s. Cars in a shared conflict:", *(_line(st) for st in egos),
             "",
             "Rules: cars of only ONE direction may be in a conflict at a time; a car that "
             "cannot stop before its hold point must proceed; give the conflict to the "
             "direction of the car that is committed or nearest to the entry; a car yields "
             "while another vehicle comes against it. Priority 0 goes first.",
             f"Answer: {{\"reasoning\": \"<at most {max_reasoning_chars} characters>\", "
             "\"verdicts\": [{\"ego_id\": \"<id>\", \"command\": \"proceed\" or \"yield\", "
             "\"priority\": <0 = first>}, ...]} with one verdict for each car above."]
    return "\n".join(lines)


def parse_verdicts(text: str, egos: Sequence[EgoStatus]) -> list[Verdict]:
    """The verdicts of an answer; ``ValueError`` (one line) when it is not valid."""
    try:
        obj = json.loads(text)
    except ValueError:
        raise ValueError(f"answer is not JSON: {text[:80]!r}") from None
    if not isinstance(obj, dict) or not isinstance(obj.get("verdicts"), list):
        raise ValueError("answer has no 'verdicts' list")
    by_id = {st.ego_id: st for st in egos}
    reasoning = str(obj.get("reasoning", ""))[:MAX_REASONING_CHARS]
    out: dict[str, Verdict] = {}
    for item in obj["verdicts"]:
        if not isinstance(item, dict):
            raise ValueError("a verdict is not an object")
        eid, cmd, prio = item.get("ego_id"), item.get("command"), item.get("priority")
        if eid not in by_id:
            raise ValueError(f"verdict for {eid!r}, not a car of this round "
                             f"({', '.join(sorted(by_id))})")
        if eid in out:
            raise ValueError(f"two verdicts for {eid}")
        if cmd not in ("proceed", "yield"):
            raise ValueError(f"{eid}: command {cmd!r} is not proceed or yield")
        if not isinstance(prio, int) or isinstance(prio, bool) or not 0 <= prio <= 999:
            raise ValueError(f"{eid}: priority {prio!r} is not an integer in 0..999")
        st = by_id[eid]
        if cmd == "yield" and committed(st):
            cmd = "proceed"  # it cannot stop before its hold point: it goes through anyway
        out[eid] = Verdict(eid, st.conflict.conflict_id, cmd, prio,  # type: ignore[union-attr]
                           reasoning or "llm")
    missing = sorted(set(by_id) - set(out))
    if missing:
        raise ValueError(f"no verdict for {', '.join(missing)}")
    going: dict[str, set[str]] = {}
    for v in out.values():
        c = by_id[v.ego_id].conflict
        if v.command == "proceed" and c is not None:
            going.setdefault(v.conflict_id, set()).add(c.via)
    for cid, dirs in sorted(going.items()):
        if len(dirs) > 1:
            raise ValueError(f"unsafe: directions {', '.join(sorted(dirs))} both proceed into "
                             f"{cid}")
    return sorted(out.values(), key=lambda v: v.ego_id)


class LlmCoordinator:
    """A coordinator backend that asks an LLM (see the module docstring)."""

    def __init__(self, ask: Ask, name: str, *, deadline_s: float = DEADLINE_S,
                 log_path: Optional[Path] = None,
                 max_reasoning_chars: int = MAX_REASONING_CHARS) -> None:
        self.ask = ask
        self.max_reasoning_chars = max_reasoning_chars
        self.name = name
        self.deadline_s = deadline_s
        self.log_path = Path(log_path) if log_path is not None else None
        self.calls = 0
        self.errors: Counter[str] = Counter()
        """Silent rounds by cause: ``timeout``, ``transport``, ``invalid``."""
        self.last_error = ""
        """The newest silent round's cause (one line)."""
        self._lock = threading.Lock()

    def verdicts(self, statuses: Sequence[EgoStatus], now_s: float) -> list[Verdict]:
        egos = participants(statuses)
        if not egos:
            return []
        cap = self.max_reasoning_chars
        prompt = coordinator_prompt(egos, now_s, max_reasoning_chars=cap)
        reply = self.ask(SYSTEM_PROMPT, prompt,
                         coordinator_schema(egos, max_reasoning_chars=cap), self.deadline_s)
        self.calls += 1
        error, out = "", []
        if not reply.ok:
            error = f"{reply.error_kind}: {reply.error}"
            self.errors[reply.error_kind or "transport"] += 1
        else:
            try:
                out = parse_verdicts(reply.text or "", egos)
            except ValueError as exc:
                error = f"invalid: {exc}"
                self.errors["invalid"] += 1
        if error:
            self.last_error = error
        self._log({"stamp_s": now_s, "source": self.name, "max_reasoning_chars": cap,
                   "prompt": prompt,
                   "prompt_sha256": _sha(prompt), "text": reply.text, "error": error,
                   "latency_s": round(reply.latency_s, 4)})
        return out

    def _log(self, record: dict[str, Any]) -> None:
        if self.log_path is None:
            return
        with self._lock:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            with self.log_path.open("a", encoding="utf-8") as f:
                f.write(json.dumps(record) + "\n")


class ReplayCoordinator:
    """Answers from a coordinator log of :class:`LlmCoordinator` by prompt hash (a prompt
    seen several times: its answers in order, then the last one again). ``match``
    ``hash_or_stamp`` (default): a prompt the log does not have gets the answer recorded
    for a round at the same stamp on the same egos (counted in ``stamp_matches``;
    validated against the statuses of now, as any answer), as the planner's replay does
    (in the ROS graph a directive reaches its ego a step earlier or later from run to
    run, so the statuses and with them the prompt's numbers can differ); ``hash``: only
    the same prompt. A round with no answer is silent (counted in ``misses``)."""

    def __init__(self, log_path: Path, *, match: str = "hash_or_stamp") -> None:
        if match not in ("hash", "hash_or_stamp"):
            raise ValueError(f"replay coordinator: match {match!r} is not hash or "
                             "hash_or_stamp")
        self.match = match
        self._by_stamp: dict[tuple[int, tuple[str, ...]], list[Optional[str]]] = {}
        self.stamp_matches = 0
        path = Path(log_path)
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise BackendError(f"replay coordinator: cannot read {path}: {exc}") from None
        self._answers: dict[str, list[Optional[str]]] = {}
        sources: Counter[str] = Counter()
        caps: Counter[int] = Counter()
        for line in lines:
            try:
                rec = json.loads(line)
                sha, text = str(rec["prompt_sha256"]), rec.get("text")
                cap = int(rec.get("max_reasoning_chars", MAX_REASONING_CHARS))
            except (ValueError, KeyError, TypeError):
                continue  # not a record of this log
            self._answers.setdefault(sha, []).append(text)
            self._by_stamp.setdefault(_round_key(rec.get("stamp_s"), rec.get("prompt")),
                                      []).append(text)
            sources[str(rec.get("source", "replay"))] += 1
            caps[cap] += 1
        if not self._answers:
            raise BackendError(f"replay coordinator: {path} holds no coordinator records")
        self.name = sources.most_common(1)[0][0]
        self.max_reasoning_chars = caps.most_common(1)[0][0]
        """The recorded prompts' reasoning cap (part of the prompt, so of its hash)."""
        self._used: Counter[str] = Counter()
        self.misses = 0

    def verdicts(self, statuses: Sequence[EgoStatus], now_s: float) -> list[Verdict]:
        egos = participants(statuses)
        if not egos:
            return []
        prompt = coordinator_prompt(egos, now_s, max_reasoning_chars=self.max_reasoning_chars)
        key = sha = _sha(prompt)
        answers = self._answers.get(sha)
        if not answers and self.match == "hash_or_stamp":
            key = repr(_round_key(now_s, prompt))
            answers = self._by_stamp.get(_round_key(now_s, prompt))
            self.stamp_matches += bool(answers)
        if not answers:
            self.misses += 1
            return []
        text = answers[min(self._used[key], len(answers) - 1)]
        self._used[key] += 1
        if text is None:
            return []  # the recorded call failed: silent then, silent now
        try:
            return parse_verdicts(text, egos)
        except ValueError:
            return []


def _round_key(stamp_s: Any, prompt: Any) -> tuple[int, tuple[str, ...]]:
    """A round by its stamp (0.1 s) and the egos its prompt lists."""
    try:
        k = round(float(stamp_s) * 10.0)
    except (TypeError, ValueError):
        k = -1
    ids = tuple(line[2:].split(":", 1)[0] for line in str(prompt or "").splitlines()
                if line.startswith("- "))
    return k, ids


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def openai_coordinator(config: Any, *, log_path: Optional[Path] = None) -> LlmCoordinator:
    """The ``openai`` backend: ``config`` is the planner's ``OpenAIConfig`` (endpoint,
    model and key from the environment as for the planner)."""
    from lmpc_llm_planner.backends.openai import OpenAIBackend

    client = OpenAIBackend.from_env(config)
    return LlmCoordinator(
        lambda system, user, schema, deadline: client.complete_json(
            system, user, schema, deadline_s=deadline), client.name, log_path=log_path)


def local_coordinator(config: Any, *, log_path: Optional[Path] = None,
                      deadline_s: float = 90.0) -> LlmCoordinator:
    """The ``local`` backend: the embedded llama.cpp model of the planner's ``LocalConfig``
    (SmolLM2-135M by default; ~seconds per round on one core, hence the longer deadline)."""
    from lmpc_llm_planner.backends.local import LocalBackend

    model = LocalBackend.from_config(config)
    return LlmCoordinator(
        lambda system, user, schema, deadline: model.complete_json(
            system, user, schema, deadline_s=deadline),
        model.name, deadline_s=deadline_s, log_path=log_path,
        max_reasoning_chars=config.max_reasoning_chars)


__all__ = ["LlmCoordinator", "ReplayCoordinator", "coordinator_prompt",
           "coordinator_schema", "local_coordinator", "openai_coordinator", "parse_verdicts",
           "participants"]
