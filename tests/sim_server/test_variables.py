"""The simulated controller's variable store and the default program host (state machine of $PRO_STATE1)."""

from __future__ import annotations

import pytest

from rgse_daemon.errors import VariableError
from rgse_daemon.link.krlvalue import KrlStruct, parse_value
from simulators.krc4.variables import (
    CODE_ACCESS,
    CODE_ARGUMENT,
    Kind,
    ProgramControlError,
    ProgramHost,
    StateOnlyProgramHost,
    VariableStore,
    module_name,
)


@pytest.fixture
def store() -> VariableStore:
    return VariableStore()


def test_seeded_system_variables_read_as_a_kr_c4_answers(store: VariableStore) -> None:
    assert store.read("$MODE_OP") == "#T1"
    assert store.read("$ACCU_STATE") == "#CHARGE_OK"
    assert store.read("$TRACE.STATE") == "#T_END"
    assert store.read("$PRO_STATE1") == "#P_FREE"
    axes = parse_value(store.read("$AXIS_ACT"))
    assert isinstance(axes, KrlStruct) and axes.type_name == "E6AXIS"
    assert (axes["A2"], axes["A3"]) == (-90.0, 90.0)
    for i in range(1, 7):
        assert isinstance(parse_value(store.read(f"$TORQUE_AXIS_ACT[{i}]")), float)
        assert 250 < parse_value(store.read(f"$MOT_TEMP[{i}]")) < 400  # Kelvin
    assert parse_value(store.read("$LOAD"))["M"] == -1.0


def test_names_are_case_and_blank_insensitive(store: VariableStore) -> None:
    assert store.read("$torque_axis_act[ 3 ]") == store.read("$TORQUE_AXIS_ACT[3]")
    assert store.read(" $trace.state ") == "#T_END"


def test_unknown_names_fail_like_the_controller(store: VariableStore) -> None:
    with pytest.raises(VariableError) as err:
        store.read("RGSE_NOT_DECLARED")
    assert err.value.name == "RGSE_NOT_DECLARED"
    with pytest.raises(VariableError):
        store.write("RGSE_NOT_DECLARED", "1")
    with pytest.raises(VariableError):
        store.read("$TORQUE_AXIS_ACT")  # a whole array is not readable, only its elements
    with pytest.raises(VariableError):
        store.read("$TORQUE_AXIS_ACT[7]")


def test_read_only_system_variables_refuse_writes(store: VariableStore) -> None:
    for name in ("$MODE_OP", "$AXIS_ACT", "$TRACE.STATE", "$PRO_STATE1", "$TORQUE_AXIS_ACT[3]"):
        before = store.read(name)
        with pytest.raises(VariableError) as err:
            store.write(name, before)
        assert err.value.code == CODE_ACCESS
        assert store.read(name) == before


def test_writes_are_checked_against_kind_and_range_and_read_back_canonically(store: VariableStore) -> None:
    assert store.write("$OV_PRO", " 35 ") == "35"
    for bad in ("101", "-1", "35.5", '"35"', "abc", ""):
        with pytest.raises(VariableError) as err:
            store.write("$OV_PRO", bad)
        assert err.value.code == CODE_ARGUMENT
    assert store.read("$OV_PRO") == "35"
    assert store.write("$TRACE.NAME[]", '"m_01"') == '"m_01"'
    with pytest.raises(VariableError):
        store.write("$TRACE.NAME[]", "m_01")  # strings are written with quotes
    assert store.write("$TRACE.MODE", "#t_start") == "#T_START"
    with pytest.raises(VariableError):
        store.write("$TRACE.MODE", "#T_WAIT")
    loaded = store.write("$LOAD", "{M 12, CM {X 0, Y 0, Z 100, A 0, B 0, C 0}, J {X 0, Y 0, Z 0}}")
    assert loaded == "{M 12.0, CM {X 0.0, Y 0.0, Z 100.0, A 0.0, B 0.0, C 0.0}, J {X 0.0, Y 0.0, Z 0.0}}"


def test_user_globals_are_declared_then_readable_and_writable(store: VariableStore) -> None:
    store.declare_global("RGSE_LOOPS", Kind.INT, "10")
    store.declare_global("rgse_speed", Kind.REAL, "2")
    assert store.read("RGSE_SPEED") == "2.0"
    assert store.write("rgse_loops", "3") == "3"
    assert store.write("RGSE_SPEED", "1") == "1.0"
    with pytest.raises(VariableError):
        store.write("RGSE_LOOPS", "TRUE")
    with pytest.raises(VariableError):
        store.declare_global("$MY", Kind.INT, "1")
    with pytest.raises(VariableError):
        store.declare_global("RGSE_BAD", Kind.BOOL, "1")
    assert "RGSE_LOOPS" in store.names()


def test_getter_computes_value_on_read(store: VariableStore) -> None:
    angle = [0.0]
    store.register_getter("$AXIS_ACT", lambda: f"{{E6AXIS: A1 {angle[0]}}}")
    angle[0] = 12.5
    assert store.read("$AXIS_ACT") == "{E6AXIS: A1 12.5}"


def test_setter_sees_accepted_writes_and_can_refuse(store: VariableStore) -> None:
    seen: list[str] = []

    def on_mode(value: str) -> None:
        if store.read("$TRACE.CONFIG[]") == '""':
            raise VariableError("$TRACE.MODE", "no trace configuration selected")
        seen.append(value)
        store.update("$TRACE.STATE", "#T_WAIT" if value == "#T_START" else "#T_END")

    store.register_setter("$TRACE.MODE", on_mode)
    with pytest.raises(VariableError):
        store.write("$TRACE.MODE", "#T_START")
    assert store.read("$TRACE.MODE") == "#T_STOP" and seen == []
    store.write("$TRACE.CONFIG[]", '"12_ms_v2.xml"')
    store.write("$TRACE.MODE", "#T_START")
    assert seen == ["#T_START"] and store.read("$TRACE.STATE") == "#T_WAIT"
    with pytest.raises(VariableError):
        store.write("$TRACE.MODE", "bad value")  # kind check comes before the setter
    assert seen == ["#T_START"]


def test_update_bypasses_read_only_for_the_simulator(store: VariableStore) -> None:
    store.update("$MODE_OP", "#T2")
    assert store.read("$MODE_OP") == "#T2"


def test_module_name() -> None:
    assert module_name("KRC:\\R1\\PROGRAM\\Rgse_Mass.src") == "RGSE_MASS"
    assert module_name("/R1/TEST") == "TEST"


def test_default_program_host_follows_the_interpreter_state_machine(store: VariableStore) -> None:
    host = StateOnlyProgramHost(store, exists=lambda n: "MISSING" not in n.upper())
    assert isinstance(host, ProgramHost)
    state = lambda: store.read("$PRO_STATE1")  # noqa: E731

    with pytest.raises(ProgramControlError):
        host.start(1)  # nothing selected
    with pytest.raises(ProgramControlError) as err:
        host.select("/R1/MISSING", "", False)
    assert err.value.code == CODE_ARGUMENT
    host.select("KRC:\\R1\\PROGRAM\\TEST.SRC", "", False)
    assert (state(), store.read("$PRO_NAME1[]")) == ("#P_RESET", '"TEST"')
    host.start(1)
    assert state() == "#P_ACTIVE"
    for refused in (lambda: host.select("/R1/OTHER", "", True), lambda: host.cancel(1), lambda: host.reset(1)):
        with pytest.raises(ProgramControlError):
            refused()
    assert state() == "#P_ACTIVE"
    host.stop(1)
    assert state() == "#P_STOP"
    host.stop(1)
    assert state() == "#P_STOP"
    host.start(1)
    host.stop(1)
    host.reset(1)
    assert state() == "#P_RESET"
    host.cancel(1)
    assert (state(), store.read("$PRO_NAME1[]")) == ("#P_FREE", '""')
    with pytest.raises(ProgramControlError):
        host.reset(1)
    host.run("/R1/TEST", "", False)
    assert state() == "#P_ACTIVE"
    with pytest.raises(ProgramControlError):
        host.start(5)  # no such interpreter


def test_default_program_host_submit_interpreter(store: VariableStore) -> None:
    host = StateOnlyProgramHost(store)
    assert store.read("$PRO_STATE0") == "#P_ACTIVE"
    host.stop(0)
    assert store.read("$PRO_STATE0") == "#P_STOP"
    host.reset(0)
    assert store.read("$PRO_STATE0") == "#P_RESET"
    host.start(0)
    assert store.read("$PRO_STATE0") == "#P_ACTIVE"
