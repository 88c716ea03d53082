"""Helpers of the rules-backend tests (lanes, headway, roundabout): hand-made agents and
observations on ``lmpc_mpc.synthetic`` maps, and one rules answer validated as the
planner validates it. Plain functions (conftest.py puts this folder on ``sys.path``)."""
from __future__ import annotations

from lmpc_mpc import synthetic as syn

from lmpc_msgs_py.messages import Agent

from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision

RIGHT_Y_M = -4.8
"""``straight_road``: the right lane ``E0_0``."""
LEFT_Y_M = -1.6
"""``straight_road``: the left lane ``E0_1``."""
CAR_LENGTH_M = 4.5


def car(aid: str, *, x_m: float, v_mps: float, left: bool = False, a_mps2: float = 0.0
        ) -> Agent:
    """An eastbound car on ``straight_road`` (right lane, or left with ``left``)."""
    lane = "E0_1" if left else "E0_0"
    y = LEFT_Y_M if left else RIGHT_Y_M
    return syn.agent(aid, x_m=x_m, y_m=y, yaw_rad=0.0, v_mps=v_mps, lane_id=lane) \
        .model_copy(update={"lane_pos_m": x_m + 2.25, "a_mps2": a_mps2})


def road_obs(road, agents=(), *, x_m: float = 50.0, v_mps: float = 12.0, left: bool = False,
             stamp_s: float = 0.0):
    """The ego eastbound on ``straight_road`` at ``x_m`` (right lane, or left), observed at
    ``stamp_s`` (simulation time)."""
    lane = "E0_1" if left else "E0_0"
    y = LEFT_Y_M if left else RIGHT_Y_M
    ego = syn.ego_state(x_m=x_m, y_m=y, yaw_rad=0.0, v_mps=v_mps, lane_id=lane,
                        stamp_s=stamp_s) \
        .model_copy(update={"lane_pos_m": x_m + 2.25})
    return syn.observation(road, ego, agents)


def ask(obs, planner_config, mpc_config, instruction=None, mode="normal"):
    """The rules answer to ``obs``, validated: ``(wire decision, scene)``."""
    scene = build_scene(obs, lookahead_m=60.0, max_agents=20)
    req = build_request(scene, config=planner_config, space=mpc_config,
                        instruction=instruction, mode=mode)
    reply = RulesBackend(planner_config.rules).complete(req)
    res = parse_decision(reply.text, request=req)
    assert res.success, res.message  # the rules answer passes the same validation
    return res.wire, scene


def accel_mid(wire, mpc_config) -> float:
    """The midpoint of the chosen acceleration interval (the bias), m/s^2."""
    return 0.5 * sum(mpc_config.accel_intervals_mps2[wire.action_guidance.accel_interval])


def chosen_label(wire, scene) -> str:
    """The label of the chosen ego candidate."""
    return scene.ego_candidates[wire.scenario_encoding.ego_trajectory].label
