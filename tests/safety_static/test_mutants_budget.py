"""Each reading stage of the static check honours the check's one time budget itself, and a data list's errors name
the data list (issue #31: survivors of mutmut on ``safety/static.py``, sample seed 31).

The budget counts from the check's first byte, and the tokenizer, the parser and the checker each look at that one
deadline. With a budget of 0 s every look finds it passed, so the stage that looks first refuses: the tokenizer at its
256th line, the parser at its 256th token. Each program below holds, beyond that point, an error the stage would
raise if it read on (a character KRL does not use, a statement that does not parse): the check refuses on time
(``COMPLEXITY``) only if that stage itself stopped; a stage that ignored the deadline would read on and raise the
syntax error instead (a later stage would still have refused on time, which is why these mutants survived tests that
only looked at the refusal's rule).
"""

from __future__ import annotations

import time
import types

import pytest

from rgse_daemon.errors import KrlSyntaxError
from rgse_daemon.krl.lexer import DEADLINE_STRIDE, tokenize
from rgse_daemon.safety import static
from rgse_daemon.safety.static import CheckContext, Violation, check_program

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
#: The deadline passes as the check starts: the first look of any stage at the clock refuses.
SPENT = CheckContext(start_axes_deg=MEAS, time_budget_s=0.0)
SHORT_SRC = "&ACCESS RVP\n&REL 1\nDEF budget( )\nEND\n"
ON_TIME = "not read within 0 s: too complex to verify"


def program(body: str) -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF budget( )\n{body}END\n"


def data_list(body: str) -> str:
    return f"DEFDAT budget\n{body}ENDDAT\n"


def test_the_programs_tokenizer_stops_at_the_deadline() -> None:
    """300 comment lines, then a '?' (not a KRL character) on line 304: the tokenizer refuses at line 256, before
    it; read to the end, the program would be a syntax error."""
    src = program("  ; filler\n" * 300 + "  RGSE_STEP = 1 ? 2\n")
    with pytest.raises(KrlSyntaxError, match=r"budget\.src:304:17: unexpected character '\?'"):
        check_program(src, None, CheckContext(start_axes_deg=MEAS), "budget.src")
    assert check_program(src, None, SPENT, "budget.src") == [Violation(DEADLINE_STRIDE, 0, "COMPLEXITY", ON_TIME)]


def test_the_data_lists_tokenizer_stops_at_the_deadline() -> None:
    """A short program (read without a look at the clock) and a data list whose line 302 holds an unterminated
    string: the data list's tokenizer refuses at its line 256."""
    dat = data_list("  ; filler\n" * 300 + '  DECL CHAR NAME[4] = "open\n')
    with pytest.raises(KrlSyntaxError, match=r"budget\.dat:302:23: unterminated string"):
        check_program(SHORT_SRC, dat, CheckContext(start_axes_deg=MEAS), "budget.src")
    assert check_program(SHORT_SRC, dat, SPENT, "budget.src") == [Violation(DEADLINE_STRIDE, 0, "COMPLEXITY", ON_TIME)]


def _parser_stop_line(text: str) -> int:
    """The line of the token whose consumption brings the parser to its first look at the clock."""
    return tokenize(text)[DEADLINE_STRIDE - 1].line


def test_the_programs_parser_stops_at_the_deadline() -> None:
    """40 lines of 18 tokens (fewer than 256 lines: the tokenizer never looks at the clock), then a statement that
    does not parse: the parser refuses at its 256th token, on line 17."""
    src = program("  RGSE_STEP = 1 + 2 + 3 + 4 + 5 + 6 + 7 + 8\n" * 40 + "  RGSE_STEP = = 1\n")
    with pytest.raises(KrlSyntaxError, match=r"budget\.src:44:"):
        check_program(src, None, CheckContext(start_axes_deg=MEAS), "budget.src")
    assert _parser_stop_line(src) == 17
    assert check_program(src, None, SPENT, "budget.src") == [Violation(17, 0, "COMPLEXITY", ON_TIME)]


def test_the_data_lists_parser_stops_at_the_deadline() -> None:
    """80 declarations of 6 tokens each, then one without a name: the data list's parser refuses at its 256th
    token, on line 44; read to the end, the data list would be a syntax error."""
    dat = data_list("".join(f"  DECL INT V{i} = 1\n" for i in range(80)) + "  DECL INT = 1\n")
    with pytest.raises(KrlSyntaxError, match=r"budget\.dat:82:"):
        check_program(SHORT_SRC, dat, CheckContext(start_axes_deg=MEAS), "budget.src")
    assert _parser_stop_line(dat) == 44
    assert check_program(SHORT_SRC, dat, SPENT, "budget.src") == [Violation(44, 0, "COMPLEXITY", ON_TIME)]


def test_the_checker_counts_the_budget_from_the_checks_first_byte(monkeypatch: pytest.MonkeyPatch) -> None:
    """The checker takes over the budget the reading started, it does not start a fresh one. A reading that took
    an hour is made by starting the check's clock an hour early (only ``check_program``'s clock: the tokenizer and
    the parser of this short program never look at theirs): the checker refuses at its first look, at the main
    routine; given a budget of its own it would allow the program (as it does without the hour)."""
    src = program("  RGSE_STEP = 1\n")
    ctx = CheckContext(start_axes_deg=MEAS)
    assert check_program(src, None, ctx, "budget.src") == []
    monkeypatch.setattr(static, "time", types.SimpleNamespace(monotonic=lambda: time.monotonic() - 3600.0))
    assert check_program(src, None, ctx, "budget.src") == [
        Violation(3, 1, "COMPLEXITY", "not verified within 20 s: too complex to verify")]


# --- the data list's errors name the data list ---------------------------------------------------------------------
def test_a_data_list_the_tokenizer_refuses_is_named() -> None:
    """An unterminated string in the data list is found by the first reading (for refused keywords), before the
    data list is parsed: its error names the .dat, not the program (it named ``budget.src`` before session 17)."""
    dat = data_list('  DECL CHAR NAME[4] = "open\n')
    with pytest.raises(KrlSyntaxError, match=r"^measure_point\.dat:2:23: unterminated string$") as info:
        check_program(SHORT_SRC, dat, CheckContext(start_axes_deg=MEAS), "measure_point.src")
    assert (info.value.file, info.value.line, info.value.column) == ("measure_point.dat", 2, 23)
    with pytest.raises(KrlSyntaxError, match=r"^measure_point\.dat:2:3: unexpected character '\?'$"):
        check_program(SHORT_SRC, data_list("  ?\n"), CheckContext(start_axes_deg=MEAS), "measure_point.src")
    # the program's own such errors name the program
    with pytest.raises(KrlSyntaxError, match=r"^measure_point\.src:4:3: unexpected character '\?'$"):
        check_program(program("  ?\n"), None, CheckContext(start_axes_deg=MEAS), "measure_point.src")
