"""The adapters' tests run from the repository root (plugins and files are named from there), with no plugin loaded
before or after each test."""

from pathlib import Path

import pytest

from crosscheck import backends

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def fresh(monkeypatch):
    monkeypatch.chdir(ROOT)
    backends.reset()
    yield
    backends.reset()
