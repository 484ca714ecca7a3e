"""Shared fixtures: paths to the repository and to the read-only shared data."""

from pathlib import Path

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
