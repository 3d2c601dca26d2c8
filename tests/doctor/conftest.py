"""The doctor tests pin the simulated server's default variant unless a test sets one (see test_doctor)."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _default_server_variant(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RGSE_SIM_LISTING", raising=False)
    monkeypatch.delenv("RGSE_SIM_PATHS", raising=False)
