"""DDS discovery for the project's processes: on this machine only, and not missing a
participant that starts a little later.

Every node, script and test calls :func:`stay_local` before rclpy creates a participant
(or on the environment it gives a child process). It sets
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the user set a range (README, "Across
machines"), and with the localhost range it points Fast DDS at the packaged profile
``config/fastdds_local_discovery.xml`` unless the user names a profile file of their own
(``FASTRTPS_DEFAULT_PROFILES_FILE`` / ``FASTDDS_DEFAULT_PROFILES_FILE``) or runs another
RMW. Why the profile: see its header and docs/RESULTS.md, "Discovery that does not miss a
late starter". No rclpy here: this runs before it is imported.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import MutableMapping

RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
PROFILE_ENVS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
"""Where Fast DDS (2.x / 3.x) reads its default XML profile file from."""
LOCAL_PROFILE = Path(__file__).resolve().parent / "config" / "fastdds_local_discovery.xml"
_FASTDDS_RMWS = ("", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


def stay_local(env: MutableMapping[str, str] = os.environ) -> MutableMapping[str, str]:
    """Make ``env`` (default: this process's environment) keep DDS discovery on this
    machine unless the user opened it up, with the packaged Fast DDS profile where it
    applies (module doc). Returns ``env``."""
    env.setdefault(RANGE_ENV, "LOCALHOST")
    if env[RANGE_ENV].strip().upper() == "LOCALHOST" \
            and not any(env.get(k) for k in PROFILE_ENVS) \
            and env.get("RMW_IMPLEMENTATION", "") in _FASTDDS_RMWS:
        env[PROFILE_ENVS[0]] = str(LOCAL_PROFILE)
    return env
