"""Hypothesis fuzz of the header parser: a mutated valid header gives a DataError or a valid TraceFile, nothing else."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rgse_daemon.errors import DataError
from rgse_daemon.trace import read_trace_file
from rgse_daemon.trace.diadem import parse_header
from tests.support.tracehelpers import write_small_set

DAT = "run1_NextGenDrive#3.dat"

# Tokens a mutation may splice in: the header's own vocabulary, numbers at the edges, separators.
TOKENS = [
    "#BEGINCHANNELHEADER", "#ENDCHANNELHEADER", "#BEGINGLOBALHEADER", "#ENDGLOBALHEADER", "IMPLIZIT", "EXPLIZIT",
    "IMPLICIT", "BLOCK", "CHANNEL", "REAL64", "REAL32", "Zeit", "Istmoment", "run1_NextGenDrive#3.r64",
    "run1_NextGenDrive#3.dat", "0", "-1", "1", "7", "39", "40", "41", "1e308", "-1e308", "nan", "inf", "1e-320",
    "99999999999999999999", ",", "\r\n", "\n", "\r", "\x00", "²", " ", "200,", "221,", "241,", "220,",
]  # fmt: skip


@st.composite
def mutations(draw: st.DrawFn) -> list[tuple[str, int, int, str]]:
    """A few edits (kind, position, length, text) applied in order to the header text."""
    kinds = st.sampled_from(["delete", "insert", "replace", "dup_line", "drop_line", "truncate"])
    text = st.one_of(st.sampled_from(TOKENS), st.text(st.characters(max_codepoint=255), max_size=6))
    return draw(
        st.lists(
            st.tuples(kinds, st.integers(0, 10_000), st.integers(1, 12), text),
            min_size=1,
            max_size=4,
        )
    )


def _mutate(text: str, edits: list[tuple[str, int, int, str]]) -> str:
    for kind, pos, length, token in edits:
        pos %= max(len(text), 1)
        lines = text.split("\r\n")
        line_no = pos % len(lines)
        if kind == "delete":
            text = text[:pos] + text[pos + length :]
        elif kind == "insert":
            text = text[:pos] + token + text[pos:]
        elif kind == "replace":
            text = text[:pos] + token + text[pos + len(token) :]
        elif kind == "dup_line":
            text = "\r\n".join([*lines[: line_no + 1], lines[line_no], *lines[line_no + 1 :]])
        elif kind == "drop_line":
            text = "\r\n".join(lines[:line_no] + lines[line_no + 1 :])
        else:
            text = text[:pos]
    return text


@pytest.fixture(scope="module")
def valid_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("fuzz")
    write_small_set(directory)
    return directory


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=mutations())
def test_mutated_header_gives_data_error_or_valid_file(valid_set: Path, edits: list) -> None:
    original = (valid_set / DAT).read_bytes().decode("iso-8859-1")
    mutated = valid_set / "fuzz_NextGenDrive#3.dat"
    mutated.write_bytes(_mutate(original, edits).encode("iso-8859-1", errors="replace"))
    try:
        tf = read_trace_file(mutated)
    except DataError as exc:
        assert str(mutated) in str(exc) or str(valid_set) in str(exc)
        return
    assert tf.period_s > 0.0
    assert np.isfinite(tf.period_s)
    assert tf.time_s().size == tf.n_samples
    for channel in tf.channels.values():
        assert channel.values.shape == (tf.n_samples,)
        assert np.isfinite(channel.values).all()


@settings(max_examples=300, deadline=None)
@given(text=st.text(st.characters(max_codepoint=255), max_size=400))
def test_parse_header_on_arbitrary_text(text: str) -> None:
    try:
        global_header, channels = parse_header(text, "x.dat")
    except DataError as exc:
        assert str(exc).startswith("x.dat")
        return
    assert channels
    assert all(isinstance(code, int) for block in [global_header, *channels] for code in block)
