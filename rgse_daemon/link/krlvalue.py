"""KRL value strings as KUKAVARPROXY / C3 Bridge carry them (``docs/controller.md`` §4), parsed and formatted.

No dependencies beyond the standard library, so the simulator's variable store can use it too.

Python types of KRL values (``KrlValue``)
-----------------------------------------
===========================  ==========================================  ==========================
KRL                          text on the wire                            Python
===========================  ==========================================  ==========================
BOOL                         ``TRUE`` / ``FALSE``                        ``bool``
INT                          ``-12``                                     ``int``
REAL                         ``-1320.46``, ``1.0E-05``                   ``float``
CHAR[] (string)              ``"12_ms_v2.xml"``                          ``str``
ENUM                         ``#T1``                                     :class:`KrlEnum` (``.name``)
bit string                   ``B100000``                                 :class:`KrlBits` (``.bits``)
STRUC (E6AXIS, E6POS, LOAD)  ``{E6AXIS: A1 0.0, ...}``, ``{M -1.0, CM {X 0.0}}``   :class:`KrlStruct`
===========================  ==========================================  ==========================

API: ``parse_value(text) -> KrlValue`` (``ProtocolError`` on anything else, naming the position),
``format_value(value) -> str`` (``ProtocolError`` for values KRL cannot hold: NaN, infinities, strings with
``"``, bad identifiers). ``format_value(parse_value(s))`` is canonical text; ``parse_value(format_value(v)) == v``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from rgse_daemon.errors import ProtocolError

_IDENT = re.compile(r"[A-Za-z_$][A-Za-z0-9_$]*")
_ENUM = re.compile(r"#[A-Za-z_$][A-Za-z0-9_$]*")
_BITS = re.compile(r"B[01]+")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INT = re.compile(r"[+-]?\d+")
_DELIMS = ",}"


@dataclass(frozen=True)
class KrlEnum:
    """An enumeration value; ``name`` without the leading ``#`` (``KrlEnum("T1")`` is ``#T1``)."""

    name: str

    def __post_init__(self) -> None:
        if not _IDENT.fullmatch(self.name):
            raise ProtocolError(f"KRL enum name {self.name!r} is not an identifier")

    def __str__(self) -> str:
        return "#" + self.name


@dataclass(frozen=True)
class KrlBits:
    """A bit string such as ``$BRAKE_SIG`` = ``B100000``; ``bits`` is the text of 0s and 1s, first bit first."""

    bits: str

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[01]+", self.bits):
            raise ProtocolError(f"KRL bit string {self.bits!r} is not made of 0 and 1")

    def __str__(self) -> str:
        return "B" + self.bits


@dataclass(frozen=True, eq=True)
class KrlStruct(Mapping[str, "KrlValue"]):
    """A structure value: optional ``type_name`` (``E6AXIS``, ``E6POS``, ``FRAME``…) and ordered fields.

    Behaves as a read-only mapping from field name to value (``pos["X"]``); ``fields`` keeps wire order.
    """

    type_name: str | None
    fields: tuple[tuple[str, KrlValue], ...]

    def __post_init__(self) -> None:
        if self.type_name is not None and not _IDENT.fullmatch(self.type_name):
            raise ProtocolError(f"KRL structure type {self.type_name!r} is not an identifier")
        seen: set[str] = set()
        for name, _ in self.fields:
            if not _IDENT.fullmatch(name):
                raise ProtocolError(f"KRL structure field {name!r} is not an identifier")
            if name in seen:
                raise ProtocolError(f"KRL structure field {name!r} appears twice")
            seen.add(name)

    @classmethod
    def of(cls, type_name: str | None = None, /, **fields: KrlValue) -> KrlStruct:
        """``KrlStruct.of("E6AXIS", A1=0.0, A2=-90.0)``."""
        return cls(type_name, tuple(fields.items()))

    def __getitem__(self, key: str) -> KrlValue:
        for name, value in self.fields:
            if name == key:
                return value
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return (name for name, _ in self.fields)

    def __len__(self) -> int:
        return len(self.fields)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, KrlStruct):
            return NotImplemented
        return self.type_name == other.type_name and self.fields == other.fields

    def __hash__(self) -> int:
        return hash((self.type_name, self.fields))


KrlValue = bool | int | float | str | KrlEnum | KrlBits | KrlStruct


# --- parsing ----------------------------------------------------------------------------------------------------
class _Parser:
    def __init__(self, text: str) -> None:
        self.s = text
        self.i = 0

    def fail(self, problem: str) -> ProtocolError:
        shown = self.s if len(self.s) <= 80 else self.s[:77] + "..."
        return ProtocolError(f"KRL value {shown!r}: {problem} at position {self.i}")

    def ws(self) -> None:
        while self.i < len(self.s) and self.s[self.i] in " \t\r\n":
            self.i += 1

    def value(self, depth: int) -> KrlValue:
        if depth > 32:
            raise self.fail("structures nested too deeply")
        self.ws()
        if self.i >= len(self.s):
            raise self.fail("value expected")
        c = self.s[self.i]
        if c == "{":
            return self.struct(depth)
        if c == '"':
            end = self.s.find('"', self.i + 1)
            if end < 0:
                raise self.fail("unterminated string")
            out = self.s[self.i + 1 : end]
            self.i = end + 1
            return out
        if c == "#":
            m = _ENUM.match(self.s, self.i)
            if not m:
                raise self.fail("bad enum value")
            self.i = m.end()
            return KrlEnum(m.group()[1:])
        m = _IDENT.match(self.s, self.i)
        if m:
            word = m.group()
            if word.upper() in ("TRUE", "FALSE"):
                self.i = m.end()
                return word.upper() == "TRUE"
            b = _BITS.fullmatch(word)
            if b:
                self.i = m.end()
                return KrlBits(word[1:])
            raise self.fail(f"unexpected word {word!r}")
        m = _NUMBER.match(self.s, self.i)
        if m:
            self.i = m.end()
            text = m.group()
            if _INT.fullmatch(text):
                try:
                    return int(text)
                except ValueError:  # more digits than int() converts (4300): no KRL INT is that long
                    raise self.fail("integer out of range") from None
            number = float(text)
            if not math.isfinite(number):
                raise self.fail("number out of range")
            return number
        raise self.fail(f"unexpected character {c!r}")

    def struct(self, depth: int) -> KrlStruct:
        self.i += 1  # "{"
        self.ws()
        type_name: str | None = None
        m = _IDENT.match(self.s, self.i)
        if m:
            j = m.end()
            while j < len(self.s) and self.s[j] in " \t":
                j += 1
            if j < len(self.s) and self.s[j] == ":":
                type_name = m.group()
                self.i = j + 1
        fields: list[tuple[str, KrlValue]] = []
        seen: set[str] = set()
        self.ws()
        if self.i < len(self.s) and self.s[self.i] == "}":
            self.i += 1
            return KrlStruct(type_name, ())
        while True:
            self.ws()
            m = _IDENT.match(self.s, self.i)
            if not m:
                raise self.fail("field name expected")
            name = m.group()
            if name in seen:
                raise self.fail(f"field {name!r} appears twice")
            seen.add(name)
            self.i = m.end()
            value = self.value(depth + 1)
            fields.append((name, value))
            self.ws()
            if self.i >= len(self.s):
                raise self.fail("'}' expected")
            c = self.s[self.i]
            self.i += 1
            if c == "}":
                return KrlStruct(type_name, tuple(fields))
            if c != ",":
                self.i -= 1
                raise self.fail("',' or '}' expected")


def parse_value(text: str) -> KrlValue:
    """Parse one KRL value string (as read over #0/#4/#6) into its Python type; ``ProtocolError`` otherwise."""
    if not isinstance(text, str):
        raise ProtocolError(f"KRL value must be text, got {type(text).__name__}")
    p = _Parser(text)
    value = p.value(0)
    p.ws()
    if p.i != len(text):
        raise p.fail("trailing characters")
    return value


# --- formatting -------------------------------------------------------------------------------------------------
def _format_real(x: float) -> str:
    if not math.isfinite(x):
        raise ProtocolError(f"KRL REAL cannot hold {x!r}")
    text = repr(float(x))
    if "e" in text:
        mantissa, exp = text.split("e")
        if "." not in mantissa:
            mantissa += ".0"
        text = f"{mantissa}E{exp}"
    return text


def format_value(value: KrlValue) -> str:
    """KRL text for ``value``, as written over #1/#5/#7 (and as the simulator answers reads)."""
    if isinstance(value, bool):
        return "TRUE" if value else "FALSE"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return _format_real(value)
    if isinstance(value, str):
        if '"' in value:
            raise ProtocolError(f"KRL string {value[:40]!r} cannot contain a double quote")
        return f'"{value}"'
    if isinstance(value, KrlEnum | KrlBits):
        return str(value)
    if isinstance(value, KrlStruct):
        body = ", ".join(f"{name} {format_value(v)}" for name, v in value.fields)
        head = f"{value.type_name}: " if value.type_name else ""
        return "{" + head + body + "}"
    raise ProtocolError(f"not a KRL value: {value!r} ({type(value).__name__})")
