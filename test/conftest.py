"""Shared fixtures: paths to the repository and to the read-only shared data."""

import inspect
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


# A test module that can start ROS nodes: it imports rclpy or the node package, runs the
# command-line subcommands that launch the node set (``nodes``, ``demo``) or the node benchmark.
ROS_MODULE = re.compile(r'\brclpy\b|mr_suspension\.nodes\b|from mr_suspension import nodes'
                        r'|\[\s*[\'"](nodes|demo)[\'"]|\bbench_nodes\b')


def pytest_configure(config):
    """Register the ``ros`` and ``slow`` marks."""
    config.addinivalue_line('markers', 'ros: the test starts ROS nodes (real-time timeouts)')
    config.addinivalue_line('markers', 'slow: a further truth seed of a behaviour CI checks on '
                                       'its first seed (scripts/test.sh runs it with '
                                       'MR_TEST_FULL=1)')


ROS_PACKAGES = ('rclpy', 'mr_suspension.nodes')


def _reached_source(func, module, seen):
    """Source of ``func`` and of the module's own functions and fixtures it reaches."""
    func = inspect.unwrap(getattr(func, '__func__', func))
    if func in seen or getattr(func, '__module__', None) != module.__name__:
        return ''
    seen.add(func)
    try:
        text = inspect.getsource(func)
    except (OSError, TypeError):
        return ''
    names = set(re.findall(r'[A-Za-z_][A-Za-z0-9_]*', text))
    for name in names:
        obj = getattr(module, name, None)
        if obj is None:
            continue
        origin = getattr(obj, '__module__', None) or getattr(obj, '__name__', '')
        if isinstance(origin, str) and origin.startswith(ROS_PACKAGES):
            text += f'\n# uses {origin}\n'
        elif callable(obj):
            text += _reached_source(obj, module, seen)
    return text


def _starts_nodes(item, memo):
    """Tell whether ``item`` may start ROS nodes.

    Its module must name ROS (:data:`ROS_MODULE`), and the test, a fixture or a helper of that
    module it reaches must name it too; a module whose source cannot be followed counts whole.
    """
    path = Path(item.path)
    if path not in memo:
        memo[path] = bool(ROS_MODULE.search(path.read_text(encoding='utf-8')))
    if not memo[path]:
        return False
    module = getattr(item, 'module', None)
    func = getattr(item, 'function', None)
    if module is None or func is None:
        return True
    seen = set()
    text = _reached_source(func, module, seen)
    for name in getattr(item, 'fixturenames', ()):
        fixture = getattr(module, name, None)
        if fixture is not None:
            text += _reached_source(fixture, module, seen)
    return not text or bool(ROS_MODULE.search(text))


def pytest_collection_modifyitems(config, items):
    """Mark every test that may start ROS nodes ``ros``.

    ``scripts/test.sh`` runs them first, one at a time in one process on an otherwise idle
    machine (their nodes keep real-time watchdogs and lock-step re-sends of tens of ms, and a
    lock-step run under full CPU load was seen to differ from the offline one), then the pure
    numerics in two pytest-xdist workers.
    """
    memo = {}
    for item in items:
        if _starts_nodes(item, memo):
            item.add_marker(pytest.mark.ros)
