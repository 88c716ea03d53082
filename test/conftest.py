"""Fixtures for graph tests: each test gets its own ROS_DOMAIN_ID."""
from __future__ import annotations

import pytest

from lmpc_msgs_py.discovery import stay_local
from graphkit import next_domain_id

stay_local()


@pytest.fixture
def domain_id(monkeypatch: pytest.MonkeyPatch) -> int:
    did = next_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(did))
    return did
