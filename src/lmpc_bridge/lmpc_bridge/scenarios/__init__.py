"""Scenario suite: a registry of families, one seeded generator each (DESIGN §6).

``build_scene(family, seed, work_dir=...)`` returns a :class:`Scene`; importing this
package registers every family module listed below.
"""
from lmpc_bridge.scenarios import (  # noqa: F401  (register the families)
    merge,
    narrow,
    rab,
    road,
    si,
    usi,
    usi_multi,
)
from lmpc_bridge.scenarios.base import (
    DEFAULT_MAX_TIME_S,
    GENERATOR_VERSION,
    Scene,
    SceneError,
    TargetSpec,
    build_scene,
    families,
    register_family,
    unknown_families,
)

__all__ = ["DEFAULT_MAX_TIME_S", "GENERATOR_VERSION", "Scene", "SceneError", "TargetSpec",
           "build_scene", "families", "register_family", "unknown_families"]
