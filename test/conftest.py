"""Fixtures for graph tests: each test gets its own ROS_DOMAIN_ID."""
from __future__ import annotations

import os

import pytest

from graphkit import next_domain_id

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@pytest.fixture
def domain_id(monkeypatch: pytest.MonkeyPatch) -> int:
    did = next_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(did))
    return did
