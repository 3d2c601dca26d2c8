"""The two small safety policies the interlock reads, as pure functions (issue #31 item 6: fast enough for mutmut):
the write allow-list (what the daemon may write over the link) and the view of the safety inputs."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from rgse_daemon.safety.allowlist import WATCHDOG_CONDITION, WATCHDOG_VARIABLES, WRITABLE_VARIABLES, writable
from rgse_daemon.safety.inputs import SafetyInputs


@pytest.mark.parametrize(("name", "ok"), [
    ("$OV_PRO", True), (" $ov_pro ", True), ("$TRACE.CONFIG[]", True), ("$TRACE.NAME[]", True),
    ("$trace.mode", True), ("$TRACE.STATE", False), ("$TRACE.NAME[1]", False), ("$OUT[1]", False),
    ("$TIMER[16]", True), ("$timer_stop[16]", True), ("$TIMER[15]", False), ("$TIMER_FLAG[16]", False),
    ("RGSE_X", True), ("rgse_arr[3]", True), ("RGSE_ARR[1,2]", True), ("RGSE_ARR[]", True), ("RGSE_S.A", True),
    ("RGSE_A[1].B.C", True), ("RGSE_9", True), ("RGSE_", False), ("RGSE_X[1", False), ("XRGSE_A", False),
    ("RGSE_A-B", False), ("RGSE_A[1,]", False), ("RGSE_A.B[1]", False),
    ("RGSE_A[1]X", False), ("RGSE_A B", False), ("", False),
])
def test_the_write_allow_list(name: str, ok: bool) -> None:
    assert writable(name) is ok


def test_the_allow_list_and_the_watchdog_names() -> None:
    assert WRITABLE_VARIABLES == {"$OV_PRO", "$TRACE.CONFIG[]", "$TRACE.NAME[]", "$TRACE.MODE"}
    assert WATCHDOG_VARIABLES == {"$TIMER[16]", "$TIMER_STOP[16]"}
    assert WATCHDOG_CONDITION == "$TIMER_FLAG[16] OR $TIMER_STOP[16]"


NOW = datetime(2026, 11, 28, 20, 0, tzinfo=UTC)


@pytest.mark.parametrize("bad", range(4))
def test_safety_inputs_are_safe_only_when_all_are_good_and_valid(bad: int) -> None:
    good = [True, True, True, True]
    assert SafetyInputs(*good, time_utc=NOW).safe is True
    good[bad] = False
    view = SafetyInputs(*good, time_utc=NOW)
    assert view.safe is False
    assert view.key() == tuple(good)


def test_the_key_is_the_safety_relevant_part() -> None:
    a = SafetyInputs(True, False, True, True, NOW, "")
    assert a.key() == (True, False, True, True)
    assert SafetyInputs(True, False, True, True, NOW + timedelta(seconds=1), "other").key() == a.key()


def test_an_unsafe_view_says_why_and_when() -> None:
    view = SafetyInputs.unsafe("link lost", NOW)
    assert view == SafetyInputs(False, False, False, False, NOW, "link lost")
    before = datetime.now(UTC)
    now_view = SafetyInputs.unsafe("stale")
    assert before <= now_view.time_utc <= datetime.now(UTC) and now_view.time_utc.tzinfo is UTC
    assert now_view.reason == "stale" and not now_view.safe and now_view.key() == (False,) * 4
