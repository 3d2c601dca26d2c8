"""KRL expressions evaluated as the controller evaluates them: operators by operand type, the built-in functions.

One evaluator serves the interlock's abstract interpreter (:mod:`rgse_daemon.krl.abstract`) and the simulator's
interpreter (``simulators/krc4/krl.py``). The caller supplies how variables are read (``read``: a Name, Index or
Member node → its value) and how user functions are called (``call``). Facts and sources: ``docs/krl-semantics.md``.

* INT op INT is an INT (``/`` truncates toward zero); any REAL operand makes the operation REAL. Results outside
  32 bits are :class:`~rgse_daemon.krl.values.Unsure`; division by zero is an
  :class:`~rgse_daemon.krl.values.EvalError`.
* REAL operations are rounded to binary32 after each operation (``wide=False``). Whether the controller keeps
  intermediates of one expression wider is not documented, so the interlock also evaluates with ``wide=True``
  (binary64 intermediates and literals, rounded where a value is stored) and refuses when the two lanes differ.
* Comparisons bind loosest (see :data:`~rgse_daemon.krl.ast.BINARY_LEVELS`); ``==``/``<>`` compare numbers, BOOLs
  and ENUMs; AND/OR/EXOR/NOT take BOOLs; B_AND/B_OR/B_EXOR/B_NOT take INTs.
* Built-ins: exactly KRL's arithmetic functions :data:`BUILTINS` (angles in degrees). ``strict`` (the interlock):
  a result the documentation does not fix to the last bit (SIN/COS/TAN/ACOS/ATAN2 except at exact points, ABS of an
  INT) is :class:`~rgse_daemon.krl.values.Unsure`; otherwise (the simulator) it is computed in binary64 and rounded.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from rgse_daemon.krl import ast as k
from rgse_daemon.krl.values import (
    UNKNOWN,
    EvalError,
    KrlEnum,
    KrlStruct,
    Unsure,
    Value,
    describe,
    int32,
    is_int,
    is_number,
    is_real,
    real32,
    real64,
    real_literal,
)

#: KRL's arithmetic built-in functions and their argument counts (KSS 8 system software manual, "Standard
#: functions"). ASIN and ATAN are not among them: a call of either is a call of an unknown function.
BUILTINS: dict[str, int] = {"ABS": 1, "SQRT": 1, "SIN": 1, "COS": 1, "TAN": 1, "ACOS": 1, "ATAN2": 2}
#: Deepest expression tree evaluated (a longer chain is refused, not a Python RecursionError).
MAX_EXPR_DEPTH = 200

Reader = Callable[[k.Expr], Value]
Caller = Callable[[k.Call], Value]


def expr_depth(expr: k.Expr) -> int:
    """Depth of an expression tree, counted without recursion (so that any depth can be measured)."""
    deepest = 0
    stack: list[tuple[k.Expr, int]] = [(expr, 1)]
    while stack:
        node, d = stack.pop()
        deepest = max(deepest, d)
        match node:
            case k.Binary(left=a, right=b):
                stack += [(a, d + 1), (b, d + 1)]
            case k.Unary(operand=a) | k.Member(base=a):
                stack.append((a, d + 1))
            case k.Index(base=a, indices=idx):
                stack += [(a, d + 1), *((i, d + 1) for i in idx)]
            case k.Call(args=args):
                stack += [(a, d + 1) for a in args]
            case k.Aggregate(items=items):
                stack += [(i.value, d + 1) for i in items]
    return deepest


@dataclass
class Evaluator:
    """Evaluates expressions with ``read`` for variables and ``call`` for user functions (see the module docs)."""

    read: Reader
    call: Caller
    wide: bool = False
    strict: bool = True

    def evaluate(self, expr: k.Expr) -> Value:
        if expr_depth(expr) > MAX_EXPR_DEPTH:
            raise Unsure(f"expression nested deeper than {MAX_EXPR_DEPTH} levels: too complex to verify", expr.pos)
        return self.value(expr)

    def value(self, expr: k.Expr) -> Value:
        match expr:
            case k.IntLit(value=v):
                if v == -(2**31):  # read as -(2147483648) or as one literal? not documented
                    raise Unsure("INT literal -2147483648", expr.pos)
                return int32(v, expr.pos)
            case k.RealLit(value=v, text=text):
                return real64(v, expr.pos) if self.wide else real_literal(v, text, expr.pos)
            case k.BoolLit(value=v) | k.StrLit(value=v):
                return v
            case k.EnumLit(name=n):
                return KrlEnum(n)
            case k.Name() | k.Index() | k.Member():
                return self.read(expr)
            case k.Aggregate(type_name=t, items=items):
                values = tuple((i.name, self.value(i.value)) for i in items)
                if any(v is UNKNOWN for _, v in values):
                    return UNKNOWN
                return KrlStruct(t, values)  # type: ignore[arg-type]
            case k.Unary(op=op, operand=operand):
                return self.unary(op, self.value(operand), expr.pos)
            case k.Binary(op=op, left=left, right=right):
                return self.binary(op, self.value(left), self.value(right), expr.pos)
            case k.Call(name=name, args=args):
                if name not in BUILTINS:
                    return self.call(expr)
                return self.builtin(name, tuple(self.value(a) for a in args), expr.pos)
        raise EvalError(f"cannot evaluate {type(expr).__name__}", getattr(expr, "pos", k.NOPOS))

    # --- numbers ------------------------------------------------------------------------------------------------------
    def real(self, x: int | float, pos: k.Pos) -> float:
        """A number as a REAL operand: binary32 (narrow lane) or binary64 (wide lane)."""
        return real64(float(x), pos) if self.wide else real32(float(x), pos)

    def unary(self, op: str, v: Value, pos: k.Pos) -> Value:
        if v is UNKNOWN:
            return UNKNOWN
        if op == "NOT":
            if isinstance(v, bool):
                return not v
            raise EvalError(f"NOT needs a BOOL, not {describe(v)}", pos)
        if op == "B_NOT":
            if is_int(v):
                return ~v  # type: ignore[operator]
            raise EvalError(f"B_NOT needs an INT, not {describe(v)}", pos)
        if is_int(v):
            return int32(-v if op == "-" else v, pos)  # type: ignore[operator]
        if is_real(v):
            return -v if op == "-" else v  # type: ignore[operator]
        raise EvalError(f"{op} needs a number, not {describe(v)}", pos)

    def binary(self, op: str, a: Value, b: Value, pos: k.Pos) -> Value:
        if a is UNKNOWN or b is UNKNOWN:
            return UNKNOWN
        if op in ("AND", "OR", "EXOR"):
            if not (isinstance(a, bool) and isinstance(b, bool)):
                raise EvalError(f"{op} needs BOOLs, not {describe(a)} and {describe(b)}", pos)
            return (a and b) if op == "AND" else (a or b) if op == "OR" else (a != b)
        if op in ("B_AND", "B_OR", "B_EXOR"):
            if not (is_int(a) and is_int(b)):
                raise EvalError(f"{op} needs INTs, not {describe(a)} and {describe(b)}", pos)
            x, y = int(a), int(b)  # type: ignore[arg-type]
            return x & y if op == "B_AND" else x | y if op == "B_OR" else x ^ y
        if op in ("==", "<>") and not (is_number(a) and is_number(b)):
            same_kind = (isinstance(a, bool) and isinstance(b, bool)) or (
                isinstance(a, KrlEnum) and isinstance(b, KrlEnum)
            )
            if not same_kind:
                raise EvalError(f"cannot compare {describe(a)} with {describe(b)}", pos)
            return (a == b) if op == "==" else (a != b)
        if not (is_number(a) and is_number(b)):
            raise EvalError(f"{op} needs numbers, not {describe(a)} and {describe(b)}", pos)
        if is_int(a) and is_int(b):
            return self._int_op(op, int(a), int(b), pos)  # type: ignore[arg-type]
        x, y = self.real(a, pos), self.real(b, pos)  # type: ignore[arg-type]
        if op in ("==", "<>", "<", ">", "<=", ">="):
            return _compare(op, x, y)
        if op == "/" and y == 0.0:
            raise EvalError("division by zero", pos)
        r = {"+": x + y, "-": x - y, "*": x * y, "/": x / y if y else 0.0}.get(op)
        if r is None:
            raise EvalError(f"unknown operator {op}", pos)
        return real64(r, pos) if self.wide else real32(r, pos)

    @staticmethod
    def _int_op(op: str, x: int, y: int, pos: k.Pos) -> Value:
        if op in ("==", "<>", "<", ">", "<=", ">="):
            return _compare(op, x, y)
        if op == "/":
            if y == 0:
                raise EvalError("division by zero", pos)
            q = abs(x) // abs(y)
            return int32(q if (x >= 0) == (y >= 0) else -q, pos)  # INT / INT cuts off the decimals
        r = {"+": x + y, "-": x - y, "*": x * y}.get(op)
        if r is None:
            raise EvalError(f"unknown operator {op}", pos)
        return int32(r, pos)

    # --- built-in functions -------------------------------------------------------------------------------------------
    def builtin(self, name: str, args: tuple[Value, ...], pos: k.Pos) -> Value:
        if len(args) != BUILTINS[name]:
            raise EvalError(f"{name} takes {BUILTINS[name]} argument(s), got {len(args)}", pos)
        if any(a is UNKNOWN for a in args):
            return UNKNOWN
        if not all(is_number(a) for a in args):
            raise EvalError(f"{name} needs numbers, not {', '.join(describe(a) for a in args)}", pos)
        if name == "ABS":
            (a,) = args
            if is_int(a):
                if self.strict:
                    raise Unsure("ABS of an INT: whether the result is an INT or a REAL is not documented", pos)
                return int32(abs(a), pos)  # type: ignore[arg-type]
            return abs(a)  # type: ignore[arg-type]
        x = [self.real(a, pos) for a in args]  # type: ignore[arg-type]
        if name == "SQRT":
            if x[0] < 0.0:
                raise EvalError(f"SQRT of a negative number ({x[0]!r})", pos)
            return self._round(math.sqrt(x[0]), pos)  # IEEE square root: correctly rounded
        exact = _exact_point(name, x)
        if exact is not None:
            return exact
        if self.strict:
            raise Unsure(f"{name}: the controller's result is not documented to the last bit", pos)
        if name == "ACOS" and not -1.0 <= x[0] <= 1.0:
            raise EvalError(f"ACOS of {x[0]!r}: outside -1..1", pos)
        functions: dict[str, Callable[..., float]] = {
            "SIN": lambda v: math.sin(math.radians(v)),
            "COS": lambda v: math.cos(math.radians(v)),
            "TAN": lambda v: math.tan(math.radians(v)),
            "ACOS": lambda v: math.degrees(math.acos(v)),
            "ATAN2": lambda y, v: math.degrees(math.atan2(y, v)),
        }
        return self._round(functions[name](*x), pos)

    def _round(self, r: float, pos: k.Pos) -> float:
        return real64(r, pos) if self.wide else real32(r, pos)


def _exact_point(name: str, x: list[float]) -> float | None:
    """The few arguments where a trigonometric function's result is exact whatever its implementation."""
    if name in ("SIN", "TAN") and x[0] == 0.0:
        return 0.0
    if name == "COS" and x[0] == 0.0:
        return 1.0
    if name == "ACOS" and x[0] == 1.0:
        return 0.0
    if name == "ATAN2" and x[0] == 0.0 and x[1] > 0.0:
        return 0.0
    return None


def _compare(op: str, x: float, y: float) -> bool:
    return {"==": x == y, "<>": x != y, "<": x < y, ">": x > y, "<=": x <= y, ">=": x >= y}[op]
