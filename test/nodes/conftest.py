"""Fixtures of the node tests: processes started for a test are stopped after it."""

import pytest


@pytest.fixture
def procs(tmp_path):
    """Start nodes and devices (``ros_helpers.Processes``); stop them all afterwards."""
    from ros_helpers import Processes
    group = Processes(tmp_path)
    try:
        yield group
    finally:
        group.stop_all()
