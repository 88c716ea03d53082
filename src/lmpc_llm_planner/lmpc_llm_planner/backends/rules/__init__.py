"""A deterministic reasoner that applies traffic rules to the request's structured
inputs and answers the same JSON text an LLM would (so it goes through the same
validation and translation). docs/lmpc_llm_planner.md, "The rules backend", and
docs/lmpc_rules.md have the numbers; the rule numbers here are theirs.

One module per rule family, run in this order on one :class:`~.plan.Plan` by
:func:`~.backend.run_rules`:

- ``instruction``: the user's instruction as an :class:`Intent` (style, closed lanes, an
  emergency vehicle to make room for, pedestrians at the next junction, refused parts);
  it only chooses among options the rules offer anyway.
- ``backend``: rules 1-2 (the route candidate; the leader and nearby agents attended)
  and the answer JSON.
- ``left_turn``: rule 3, gap acceptance of a left turn (paper Fig. 1).
- ``roundabout``: rule 10, entering a roundabout (ring traffic has priority).
- ``lane``: rule 8, lane choice on multi-lane roads (closed / blocked lane, the route's
  lane, overtaking a slow leader; gap checks).
- ``path``: rule 5, braking for an agent in the ego's own path; rule 6, go.
- ``headway``: rule 9, a brake-or-swerve gap behind a moving leader.
- ``situation``: rule 11, run last: pedestrians at the next junction (slow approach),
  making room where there is no lane to give (slow down); it only lowers the speed.
- ``emergency``: rule 7, the emergency variant (same rules, hard braking only for a
  threat in the path under ``commit_ttc_s``).
- shared: ``plan`` (inputs and plan), ``junction`` (conflicts, clear times, rule 4:
  the approach speed to a turn),
  ``scene_helpers`` (leader, queues, path distance), ``intervals`` (interval choice).

The time and gap estimates are APPROXIMATIONS (constant speeds, straight agent paths),
documented in route.py.
"""
from .backend import RulesBackend
from .instruction import Intent, parse_instruction
from .junction import Conflict, travel_time_s

__all__ = ["Conflict", "Intent", "RulesBackend", "parse_instruction", "travel_time_s"]
