"""``lmpc_msgs_py.discovery.stay_local``: discovery on this machine by default, the packaged
Fast DDS profile only where it applies, the user's own settings never overridden."""
from __future__ import annotations

import xml.etree.ElementTree as ET

from lmpc_msgs_py.discovery import LOCAL_PROFILE, PROFILE_ENVS, RANGE_ENV, stay_local

_NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_default_is_localhost_with_the_packaged_profile() -> None:
    env = stay_local({"PATH": "/bin"})
    assert env[RANGE_ENV] == "LOCALHOST"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(LOCAL_PROFILE)
    assert env["PATH"] == "/bin"


def test_localhost_set_by_the_user_in_any_case_gets_the_profile() -> None:
    env = stay_local({RANGE_ENV: "localhost"})
    assert env[RANGE_ENV] == "localhost"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(LOCAL_PROFILE)


def test_an_opened_up_range_is_kept_and_gets_no_profile() -> None:
    for rng in ("SUBNET", "SYSTEM_DEFAULT", "OFF"):
        env = stay_local({RANGE_ENV: rng})
        assert env == {RANGE_ENV: rng}


def test_the_users_own_profile_file_is_never_replaced() -> None:
    for key in PROFILE_ENVS:
        env = stay_local({key: "/etc/my_fastdds.xml"})
        assert env == {RANGE_ENV: "LOCALHOST", key: "/etc/my_fastdds.xml"}


def test_another_rmw_gets_no_fast_dds_profile() -> None:
    env = stay_local({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"})
    assert env == {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp", RANGE_ENV: "LOCALHOST"}
    env = stay_local({"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"})
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(LOCAL_PROFILE)


def test_the_profile_is_a_default_participant_profile_with_more_initial_announcements(
) -> None:
    """The packaged file is what Fast DDS loads: a default participant profile whose only
    setting is the initial announcements (3 s of them, not Fast DDS's 5 x 0.1 s), and no
    transport or locator of its own (the localhost range stays rmw_fastrtps's)."""
    root = ET.parse(LOCAL_PROFILE).getroot()
    parts = root.findall("p:participant", _NS)
    assert len(parts) == 1 and parts[0].get("is_default_profile") == "true"
    ann = parts[0].find("p:rtps/p:builtin/p:discovery_config/p:initialAnnouncements", _NS)
    assert ann is not None
    count = int(ann.findtext("p:count", namespaces=_NS) or 0)
    period_ns = int(ann.findtext("p:period/p:nanosec", namespaces=_NS) or 0)
    assert count * period_ns >= 2_000_000_000  # longer than the graph's start-up spread
    for tag in ("transport_descriptors", "participant/p:rtps/p:userTransports",
                "participant/p:rtps/p:builtin/p:metatrafficUnicastLocatorList",
                "participant/p:rtps/p:builtin/p:initialPeersList"):
        assert root.find("p:" + tag, _NS) is None, tag
