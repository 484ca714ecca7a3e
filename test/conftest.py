"""Shared fixtures: paths to the repository and to the read-only shared data."""

from pathlib import Path
import re

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / 'shared'


@pytest.fixture(scope='session')
def repo_root():
    """Return the repository root."""
    return REPO


@pytest.fixture(scope='session')
def shared_dir():
    """Return ``../shared`` (seeds and measured data); it must exist (CI has it)."""
    assert SHARED.is_dir(), f'{SHARED} is missing: tests need ../shared beside the repo'
    return SHARED


# A test module that can start ROS nodes: it imports rclpy or the node package, or runs the
# command-line subcommands that launch the node set (``nodes``, ``demo``).
ROS_MODULE = re.compile(r'\brclpy\b|mr_suspension\.nodes\b|from mr_suspension import nodes'
                        r'|\[\s*[\'"](nodes|demo)[\'"]')


def pytest_configure(config):
    """Register the ``ros`` and ``slow`` marks."""
    config.addinivalue_line('markers', 'ros: the test starts ROS nodes (real-time timeouts)')
    config.addinivalue_line('markers', 'slow: a further truth seed of a behaviour CI checks on '
                                       'its first seed (scripts/test.sh runs it with '
                                       'MR_TEST_FULL=1)')


def pytest_collection_modifyitems(config, items):
    """Mark every test of a module that starts ROS nodes ``ros``.

    ``scripts/test.sh`` runs them first, one at a time in one process on an otherwise idle
    machine (their nodes keep real-time watchdogs and lock-step re-sends of tens of ms, and a
    lock-step run under full CPU load was seen to differ from the offline one), then the pure
    numerics in two pytest-xdist workers.
    """
    ros = {}
    for item in items:
        path = Path(item.path)
        if path not in ros:
            ros[path] = bool(ROS_MODULE.search(path.read_text(encoding='utf-8')))
        if ros[path]:
            item.add_marker(pytest.mark.ros)
