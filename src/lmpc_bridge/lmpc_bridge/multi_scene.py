"""The egos of a multi-vehicle scene (issue 18): ``Scene.params["egos"]`` (JSON) as specs.

A multi-ego family (``narrow``) builds a normal :class:`Scene` for ``ego_1`` (so a single-ego
run works too) and lists every ego in ``params["egos"]``: id, SUMO route id, route edges,
depart lane / position / speed and target. :func:`ego_scene` is the scene as ego ``k``
sees it (its route and target), which ``mapping.build_map`` turns into its map.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

from lmpc_bridge.scenarios.base import Scene, SceneError, TargetSpec


@dataclass(frozen=True)
class EgoSpec:
    ego_id: str
    route_id: str
    route_edges: tuple[str, ...]
    depart_lane: int
    depart_pos_m: float
    depart_speed_mps: float
    target: TargetSpec


def ego_specs(scene: Scene) -> tuple[EgoSpec, ...]:
    """The egos of ``scene`` (``SceneError`` when it lists none or a broken entry)."""
    raw = scene.params.get("egos")
    if not isinstance(raw, str):
        raise SceneError(f"scene {scene.family}/{scene.seed} has one ego (no params['egos']): "
                         f"run it with SumoSim")
    try:
        specs = []
        for item in json.loads(raw):
            t = item["target"]
            specs.append(EgoSpec(
                ego_id=str(item["ego_id"]), route_id=str(item["route_id"]),
                route_edges=tuple(item["route_edges"]), depart_lane=int(item["depart_lane"]),
                depart_pos_m=float(item["depart_pos_m"]),
                depart_speed_mps=float(item["depart_speed_mps"]),
                target=TargetSpec(edge_id=t["edge_id"], lane_ids=tuple(t["lane_ids"]),
                                  lane_pos_m=float(t["lane_pos_m"]),
                                  center=(float(t["center"][0]), float(t["center"][1])),
                                  radius_m=float(t["radius_m"]))))
    except (KeyError, TypeError, ValueError) as exc:
        raise SceneError(f"scene {scene.family}/{scene.seed}: broken params['egos']: "
                         f"{exc!r}") from None
    ids = [s.ego_id for s in specs]
    if len(specs) < 2 or ids != [f"ego_{k + 1}" for k in range(len(specs))]:
        raise SceneError(f"scene {scene.family}/{scene.seed}: egos must be ego_1 ... ego_N "
                         f"(N >= 2), got {ids}")
    return tuple(specs)


def ego_scene(scene: Scene, spec: EgoSpec) -> Scene:
    """``scene`` with ``spec``'s route, start and target as the ego's."""
    return dataclasses.replace(
        scene, ego_route_edges=spec.route_edges, ego_depart_lane=spec.depart_lane,
        ego_depart_pos_m=spec.depart_pos_m, ego_depart_speed_mps=spec.depart_speed_mps,
        target=spec.target)
