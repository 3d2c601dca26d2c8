"""KRL tokenizer: one job, turning text into positioned tokens.

KRL is line-oriented (one statement per line), so line ends are tokens. Comments (``;`` to the end of the line,
including ``;FOLD``/``;ENDFOLD`` markers) vanish; ``&ACCESS``/``&REL``/``&PARAM`` lines become ``HEADER`` tokens.
Identifiers and enum literals are upper-cased (KRL is case-insensitive); strings keep their case.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from enum import Enum

from rgse_daemon.errors import KrlSyntaxError


class Tok(Enum):
    NAME = "name"
    INT = "integer"
    REAL = "real number"
    STR = "string"
    ENUM = "enum literal"
    OP = "operator"
    HEADER = "header line"
    NEWLINE = "end of line"
    EOF = "end of file"


@dataclass(frozen=True)
class Token:
    kind: Tok
    text: str  # upper-cased for NAME/ENUM, the value without quotes for STR, the symbol for OP
    line: int
    column: int
    value: int | float | None = None  # the number for INT/REAL

    def describe(self) -> str:
        if self.kind in (Tok.NEWLINE, Tok.EOF):
            return self.kind.value
        if self.kind is Tok.STR:
            return f'string "{self.text}"'
        return f"'{self.text}'"


_OPS2 = ("==", "<>", "<=", ">=")
_OPS1 = "=<>+-*/()[]{},:."
_NAME_START = set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_$")
_NAME_CHARS = _NAME_START | set("0123456789")
_DIGITS = set("0123456789")


class OutOfTime(Exception):
    """Reading took past the caller's ``deadline`` (``time.monotonic()``); ``line``: where it stopped."""

    def __init__(self, line: int) -> None:
        super().__init__(f"reading stopped at line {line}: out of time")
        self.line = line


#: Lines (lexer) or tokens (parser) between two looks at the deadline.
DEADLINE_STRIDE = 256


def tokenize(text: str, file: str = "<string>", deadline: float | None = None) -> list[Token]:
    """Split KRL source into tokens, ending with one ``EOF``; consecutive line ends collapse into one ``NEWLINE``.
    ``deadline``: raise :class:`OutOfTime` once ``time.monotonic()`` passes it (checked every few lines).

    Raises
    ------
    KrlSyntaxError
        An unterminated string, a malformed number or a character that KRL does not use, with its position.
    """
    tokens: list[Token] = []

    def emit_newline(line: int, column: int) -> None:
        if tokens and tokens[-1].kind is not Tok.NEWLINE:
            tokens.append(Token(Tok.NEWLINE, "\n", line, column))

    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    for line_no, line in enumerate(lines, 1):
        if deadline is not None and line_no % DEADLINE_STRIDE == 0 and time.monotonic() > deadline:
            raise OutOfTime(line_no)
        i = 0
        n = len(line)
        stripped = line.lstrip()
        if stripped.startswith("&"):
            tokens.append(Token(Tok.HEADER, stripped.rstrip(), line_no, n - len(stripped) + 1))
            emit_newline(line_no, n + 1)
            continue
        while i < n:
            ch = line[i]
            col = i + 1
            if ch in " \t\f\v":
                i += 1
            elif ch == ";":
                break
            elif ch == '"':
                end = line.find('"', i + 1)
                if end < 0:
                    raise KrlSyntaxError("unterminated string", file, line_no, col)
                tokens.append(Token(Tok.STR, line[i + 1 : end], line_no, col))
                i = end + 1
            elif ch == "'":
                i = _bit_literal(line, i, line_no, file, tokens)
            elif ch in _DIGITS:
                i = _number(line, i, line_no, file, tokens)
            elif ch in _NAME_START:
                j = i + 1
                while j < n and line[j] in _NAME_CHARS:
                    j += 1
                tokens.append(Token(Tok.NAME, line[i:j].upper(), line_no, col))
                i = j
            elif ch == "#":
                j = i + 1
                while j < n and line[j] in _NAME_CHARS:
                    j += 1
                if j == i + 1:
                    raise KrlSyntaxError("'#' must be followed by an enum name", file, line_no, col)
                tokens.append(Token(Tok.ENUM, line[i + 1 : j].upper(), line_no, col))
                i = j
            elif line[i : i + 2] in _OPS2:
                tokens.append(Token(Tok.OP, line[i : i + 2], line_no, col))
                i += 2
            elif ch in _OPS1:
                tokens.append(Token(Tok.OP, ch, line_no, col))
                i += 1
            else:
                raise KrlSyntaxError(f"unexpected character {ch!r}", file, line_no, col)
        emit_newline(line_no, n + 1)
    last_line = len(lines)
    tokens.append(Token(Tok.EOF, "", last_line, len(lines[-1]) + 1))
    return tokens


def _number(line: str, i: int, line_no: int, file: str, out: list[Token]) -> int:
    n = len(line)
    j = i
    while j < n and line[j] in _DIGITS:
        j += 1
    is_real = False
    if j < n and line[j] == "." and j + 1 < n and line[j + 1] in _DIGITS:
        is_real = True
        j += 1
        while j < n and line[j] in _DIGITS:
            j += 1
    if j < n and line[j] in "eE":
        k = j + 1
        if k < n and line[k] in "+-":
            k += 1
        if k < n and line[k] in _DIGITS:
            is_real = True
            j = k
            while j < n and line[j] in _DIGITS:
                j += 1
    if j < n and line[j] in _NAME_CHARS:
        raise KrlSyntaxError(f"malformed number {line[i : j + 1]!r}", file, line_no, i + 1)
    text = line[i:j]
    if is_real:
        out.append(Token(Tok.REAL, text, line_no, i + 1, float(text)))
    else:
        out.append(Token(Tok.INT, text, line_no, i + 1, int(text)))
    return j


def _bit_literal(line: str, i: int, line_no: int, file: str, out: list[Token]) -> int:
    """``'B0101'`` (binary) or ``'H1F'`` (hexadecimal) integer literals."""
    end = line.find("'", i + 1)
    body = line[i + 1 : end].upper() if end > 0 else ""
    allowed = {"B": "01", "H": "0123456789ABCDEF"}.get(body[:1])
    if allowed is None or len(body) < 2 or any(c not in allowed for c in body[1:]):
        raise KrlSyntaxError("malformed binary/hex literal (expected 'B0101' or 'H1F')", file, line_no, i + 1)
    value = int(body[1:], 2 if body[0] == "B" else 16)
    out.append(Token(Tok.INT, line[i : end + 1], line_no, i + 1, value))
    return end + 1
