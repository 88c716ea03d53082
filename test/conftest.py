"""Fixtures for graph tests: each test gets its own ROS_DOMAIN_ID."""
from __future__ import annotations

import pytest

from lmpc_msgs_py.discovery import stay_local
from graphkit import next_domain_id

stay_local()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that takes a ROS domain of its own starts node processes: it is a graph test
    (``make test`` runs those one at a time, the rest on two workers)."""
    for item in items:
        if "domain_id" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.graph)


@pytest.fixture
def domain_id(monkeypatch: pytest.MonkeyPatch) -> int:
    did = next_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(did))
    return did
