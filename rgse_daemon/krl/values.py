"""Typed KRL values as a KR C4 holds them (``docs/krl-semantics.md`` gives the facts and their sources).

Python types: ``bool`` (BOOL), ``int`` (INT, always within 32 bits), ``float`` (REAL, always a value an IEEE
binary32 can hold), ``str`` (CHAR[]), :class:`~rgse_daemon.link.krlvalue.KrlEnum` (ENUM),
:class:`~rgse_daemon.link.krlvalue.KrlStruct` (structures: only the *initialised* fields are present),
:class:`KrlArray` (arrays other than CHAR[]) and :data:`UNKNOWN` (the interlock's "not a constant").

REAL arithmetic is done in binary64 and rounded to binary32 with :mod:`struct` (the C cast, round to nearest even):
for + − × / and √ of binary32 operands this gives the correctly rounded binary32 result, because binary64 has more
than twice binary32's precision. ``struct`` rather than ``numpy.float32``: the standard library is enough, raises on
overflow instead of giving infinity, and the simulator and the interlock need no numpy for it.

Whatever the controller's result is not documented for (INT overflow, a REAL outside binary32's normal range, a
rounding tie, an uninitialised structure field) raises :class:`Unsure`; a program error the controller reports at run
time (division by zero, a type mismatch) raises :class:`EvalError`.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from fractions import Fraction

from rgse_daemon.krl.ast import NOPOS, Pos
from rgse_daemon.link.krlvalue import KrlEnum, KrlStruct

INT_MIN = -(2**31)
INT_MAX = 2**31 - 1
#: Smallest positive normal binary32 (the KRL documentation's lower bound of the REAL range, 1.1E-38).
REAL_MIN_NORMAL = 2.0**-126
_F32 = struct.Struct("<f")
_U32 = struct.Struct("<I")

AXIS_FIELDS = ("A1", "A2", "A3", "A4", "A5", "A6")
EXT_FIELDS = ("E1", "E2", "E3", "E4", "E5", "E6")
CARTESIAN_FIELDS = ("X", "Y", "Z", "A", "B", "C")
#: Fields of the predefined structure types, in declaration order.
STRUCT_FIELDS: dict[str, tuple[str, ...]] = {
    "AXIS": AXIS_FIELDS,
    "E6AXIS": AXIS_FIELDS + EXT_FIELDS,
    "FRAME": CARTESIAN_FIELDS,
    "POS": (*CARTESIAN_FIELDS, "S", "T"),
    "E6POS": (*CARTESIAN_FIELDS, "S", "T", *EXT_FIELDS),
}
#: Structure fields of type INT (status and turn); every other predefined field is REAL.
INT_FIELDS = frozenset({"S", "T"})


class EvalError(Exception):
    """The controller stops the program here with a run-time error (``reason`` says which)."""

    def __init__(self, reason: str, pos: Pos = NOPOS) -> None:
        super().__init__(reason)
        self.reason = reason
        self.pos = pos


class Unsure(EvalError):
    """What the controller does here is not documented: the interlock refuses, the simulator stops."""


class _Unknown:
    _instance: _Unknown | None = None

    def __new__(cls) -> _Unknown:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "UNKNOWN"


#: A value the interlock cannot know before the program runs (a global, a system variable, a join of two paths).
UNKNOWN = _Unknown()


@dataclass
class KrlArray:
    """An array other than CHAR[]: element type, sizes, elements by 1-based index tuple (absent: uninitialised)."""

    type_name: str
    dims: tuple[int, ...]
    items: dict[tuple[int, ...], Value] = field(default_factory=dict)


Value = bool | int | float | str | KrlEnum | KrlStruct | KrlArray | _Unknown


# --- numbers ---
def is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_real(v: object) -> bool:
    return isinstance(v, float)


def is_number(v: object) -> bool:
    return is_int(v) or is_real(v)


def int32(n: int, pos: Pos = NOPOS) -> int:
    """``n`` if a 32-bit INT holds it; otherwise :class:`Unsure` (wrap-around or error is not documented)."""
    if not INT_MIN <= n <= INT_MAX:
        raise Unsure(f"INT overflow ({_short(n)} is outside -2147483648..2147483647)", pos)
    return n


def real32(x: float, pos: Pos = NOPOS) -> float:
    """``x`` rounded to the nearest binary32 (ties to even); :class:`Unsure` outside the normal REAL range."""
    try:
        y: float = _F32.unpack(_F32.pack(x))[0]
    except OverflowError:
        raise Unsure(f"REAL overflow ({_short(x)} is beyond ±3.4E+38)", pos) from None
    if not math.isfinite(y):
        raise Unsure(f"REAL value {x!r} is not a finite number", pos)
    if (y == 0.0 and x != 0.0) or (y != 0.0 and abs(y) < REAL_MIN_NORMAL):
        raise Unsure(f"REAL underflow ({x!r} is below the normal REAL range 1.1E-38)", pos)
    return y + 0.0  # -0.0 → 0.0


def real64(x: float, pos: Pos = NOPOS) -> float:
    """A binary64 intermediate of the wide lane: finite, else :class:`Unsure`."""
    if not math.isfinite(x):
        raise Unsure(f"REAL overflow ({x!r})", pos)
    return x


def _bits_neighbours(f: float) -> tuple[float, float]:
    """The binary32 values just below and above ``f`` (a finite binary32)."""
    bits = _U32.unpack(_F32.pack(f))[0]
    out = []
    for b in (bits - 1, bits + 1) if f > 0 else (bits + 1, bits - 1) if f < 0 else (0x80000001, 0x00000001):
        out.append(_F32.unpack(_U32.pack(b & 0xFFFFFFFF))[0])
    lo, hi = sorted(out)
    return lo, hi


def real_literal(value: float, text: str | None, pos: Pos = NOPOS) -> float:
    """The binary32 a REAL literal denotes (``value``: its binary64 reading, ``text``: its decimal text if known).

    Read directly or through binary64, the result is the same unless the binary64 value lies exactly halfway between
    two binary32 values while the decimal does not: then the two readings differ, and which one the compiler makes
    is not documented (:class:`Unsure`). An exact decimal tie rounds to even either way.
    """
    f = real32(value, pos)
    d = Fraction(value)
    if d == Fraction(f):
        return f
    gap = abs(d - Fraction(f))
    if any(math.isfinite(o) and abs(d - Fraction(o)) == gap for o in _bits_neighbours(f)):
        if text is None or Fraction(text) != d:
            raise Unsure(f"REAL literal {text or value!r}: its binary32 value depends on how it is read", pos)
    return f


def round_to_int(x: float, pos: Pos = NOPOS, strict: bool = True) -> int:
    """REAL → INT as assignment converts it: to the nearest whole number. A tie (x.5) is :class:`Unsure` when
    ``strict`` (the documentation does not say which way it goes), else rounded away from zero (the simulator's
    model)."""
    if not math.isfinite(x):
        raise Unsure(f"REAL {x!r} cannot become an INT", pos)
    lower = math.floor(x)
    frac = x - lower
    if frac == 0.5:
        if strict:
            raise Unsure(f"REAL {x!r} is halfway between two INTs: how the controller rounds it is not documented", pos)
        n = lower + 1 if x > 0 else lower
    else:
        n = lower + 1 if frac > 0.5 else lower
    return int32(int(n), pos)


def _short(n: float) -> str:
    text = repr(n)
    return text if len(text) <= 24 else text[:10] + "…" + text[-4:] + f" ({len(text)} digits)"


# --- assignment ---
def field_type(name: str) -> str:
    """The type of a predefined structure's field: S and T are INT, the rest REAL."""
    return "INT" if name in INT_FIELDS else "REAL"


def convert(type_name: str | None, value: Value, old: Value = UNKNOWN, pos: Pos = NOPOS, strict: bool = True) -> Value:
    """``value`` as a variable of ``type_name`` holds it after an assignment (``old``: its value before).

    INT ← REAL rounds, REAL ← INT widens to binary32, a structure takes the fields an aggregate names and keeps the
    others of ``old``. ``type_name`` ``None`` or an unknown type: no conversion (REALs still binary32).
    """
    if value is UNKNOWN:
        return UNKNOWN
    if type_name == "INT":
        if is_int(value):
            return int32(value, pos)  # type: ignore[arg-type]
        if is_real(value):
            return round_to_int(value, pos, strict)  # type: ignore[arg-type]
        raise EvalError(f"cannot assign {describe(value)} to an INT", pos)
    if type_name == "REAL":
        if is_number(value):
            return real32(float(value), pos)  # type: ignore[arg-type]
        raise EvalError(f"cannot assign {describe(value)} to a REAL", pos)
    if type_name == "BOOL":
        if isinstance(value, bool):
            return value
        raise EvalError(f"cannot assign {describe(value)} to a BOOL", pos)
    if type_name == "CHAR":
        if isinstance(value, str):
            return value
        raise EvalError(f"cannot assign {describe(value)} to a CHAR", pos)
    if type_name in STRUCT_FIELDS:
        if not isinstance(value, KrlStruct):
            raise EvalError(f"cannot assign {describe(value)} to a {type_name}", pos)
        return merge(type_name, old if isinstance(old, KrlStruct) else None, value, pos, strict)
    return _narrow(value, pos)


def merge(
    type_name: str | None, old: KrlStruct | None, new: KrlStruct, pos: Pos = NOPOS, strict: bool = True
) -> KrlStruct:
    """Assigning ``new`` to a ``type_name`` variable holding ``old``: the named fields change, the others stay
    (uninitialised ones stay uninitialised, i.e. absent). A type this module does not know (a system structure such as
    $TOOL, ``None``): the fields of ``old`` in their order, then new ones, without conversion."""
    known = STRUCT_FIELDS.get(type_name or "")
    if known is not None and new.type_name is not None and new.type_name != type_name:
        raise EvalError(f"cannot assign a {new.type_name} aggregate to a {type_name}", pos)
    before = dict(old.fields) if old is not None else {}
    order = known if known is not None else (*before, *(n for n in new if n not in before))
    unknown = [n for n in new if n not in order]
    if unknown:
        raise EvalError(f"{type_name} has no field {', '.join(unknown)}", pos)
    given = dict(new.fields)
    out = []
    for name in order:
        if name in given:
            v = given[name]
            out.append((name, convert(field_type(name), v, UNKNOWN, pos, strict) if known is not None else v))
        elif name in before:
            out.append((name, before[name]))
    result_type = type_name if known is not None else (old.type_name if old is not None else None) or new.type_name
    return KrlStruct(result_type, tuple(out))  # type: ignore[arg-type]


def _narrow(value: Value, pos: Pos) -> Value:
    """REALs inside ``value`` rounded to binary32 (a value stored without a known type)."""
    if isinstance(value, float):
        return real32(value, pos)
    if isinstance(value, KrlStruct):
        return KrlStruct(value.type_name, tuple((n, _narrow(v, pos)) for n, v in value.fields))  # type: ignore[misc]
    return value


def default_value(type_name: str, dims: tuple[int, ...] = ()) -> Value:
    """A freshly declared variable: an empty array, an all-uninitialised structure, or a scalar's initial value.

    Scalars: the controller leaves them uninitialised too; 0/0.0/FALSE/"" is the simulator's model, the interlock
    never reads a scalar it has not seen assigned (see :mod:`rgse_daemon.krl.abstract`).
    """
    if dims and type_name != "CHAR":
        return KrlArray(type_name, dims)
    if type_name in STRUCT_FIELDS:
        return KrlStruct(type_name, ())
    return {"INT": 0, "REAL": 0.0, "BOOL": False, "CHAR": ""}.get(type_name, UNKNOWN)


# --- access ---
def member(value: Value, name: str, pos: Pos = NOPOS) -> Value:
    """``value.NAME``; an uninitialised field is :class:`Unsure` (the controller stops with an error)."""
    if value is UNKNOWN:
        return UNKNOWN
    if isinstance(value, KrlStruct):
        if name in value:
            return value[name]
        if value.type_name in STRUCT_FIELDS and name in STRUCT_FIELDS[value.type_name]:
            raise Unsure(f"field {name} is read before it was assigned", pos)
    raise EvalError(f"{describe(value)} has no field {name}", pos)


def element(value: Value, idx: tuple[int, ...], pos: Pos = NOPOS) -> Value:
    """``value[i, j]`` (1-based); ``CHAR[]`` strings give one character, ``s[]`` the whole string."""
    if value is UNKNOWN:
        return UNKNOWN
    if isinstance(value, str):
        if idx == ():
            return value
        if len(idx) == 1 and 1 <= idx[0] <= len(value):
            return value[idx[0] - 1]
        raise EvalError(f"string index {list(idx)} out of range", pos)
    if isinstance(value, KrlArray):
        check_index(value, idx, pos)
        if idx not in value.items:
            if value.type_name in STRUCT_FIELDS:
                return KrlStruct(value.type_name, ())
            raise Unsure(f"array element {list(idx)} is read before it was assigned", pos)
        return value.items[idx]
    raise EvalError(f"cannot index {describe(value)}", pos)


def check_index(array: KrlArray, idx: tuple[int, ...], pos: Pos = NOPOS) -> None:
    if len(idx) != len(array.dims) or any(not 1 <= i <= d for i, d in zip(idx, array.dims, strict=True)):
        raise EvalError(f"index {list(idx)} outside the array's size {list(array.dims)}", pos)


def describe(value: Value) -> str:
    if isinstance(value, bool):
        return f"BOOL {'TRUE' if value else 'FALSE'}"
    if is_int(value):
        return f"INT {_short(value)}"  # type: ignore[arg-type]
    if is_real(value):
        return f"REAL {value!r}"
    if isinstance(value, str):
        return f'CHAR[] "{value}"'
    if isinstance(value, KrlEnum):
        return f"ENUM #{value.name}"
    if isinstance(value, KrlStruct):
        return f"a {value.type_name or 'structure'}"
    if isinstance(value, KrlArray):
        return f"an array of {value.type_name}"
    return "an unknown value"
