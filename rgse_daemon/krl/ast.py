"""Typed syntax tree of the KRL subset the daemon writes and checks.

Every node carries its source position (``pos``, 1-based line and column) for error messages and the interlock's
violation reports. Positions are excluded from equality, so two trees that differ only in layout compare equal
(``parse(format(tree)) == tree``). Names (identifiers, enum literals, type names) are stored upper-case because KRL
is case-insensitive; string literals keep their case.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeAlias


@dataclass(frozen=True, order=True)
class Pos:
    """A place in a source file: 1-based line and column (0/0 for synthesised nodes)."""

    line: int = 0
    column: int = 0


#: Position of nodes built in code rather than parsed.
NOPOS = Pos()


# --- expressions ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class IntLit:
    value: int
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class RealLit:
    """A REAL literal: ``value`` as binary64, ``text`` the source's decimal text (``None`` when built in code)."""

    value: float
    pos: Pos = field(default=NOPOS, compare=False, repr=False)
    text: str | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class BoolLit:
    value: bool
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class StrLit:
    """A double-quoted ``CHAR[]`` literal (KRL has no escapes; a string cannot contain ``"``)."""

    value: str
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class EnumLit:
    """``#T_START``: ``name`` without the ``#``."""

    name: str
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Name:
    """A variable reference: ``COUNTER``, ``$OV_PRO``."""

    name: str
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Index:
    """``base[i, j]``; an empty ``indices`` is the whole-array form ``$TRACE.NAME[]``."""

    base: Expr
    indices: tuple[Expr, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Member:
    """``base.FIELD`` (``$VEL.CP``, ``$TRACE.MODE``)."""

    base: Expr
    member: str
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Call:
    """A function call in an expression: ``ABS(X)``, a ``DEFFCT``."""

    name: str
    args: tuple[Expr, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Unary:
    """``op`` is ``-``, ``+``, ``NOT`` or ``B_NOT``."""

    op: str
    operand: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Binary:
    """``op`` is one of ``* / + - AND B_AND EXOR B_EXOR OR B_OR == <> < > <= >=`` (upper-case)."""

    op: str
    left: Expr
    right: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class AggItem:
    """One ``FIELD value`` entry of an aggregate."""

    name: str
    value: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Aggregate:
    """``{E6AXIS: A1 0, A2 -90}`` (``type_name`` ``"E6AXIS"``) or ``{X 1, Y 2}`` (``type_name`` ``None``)."""

    type_name: str | None
    items: tuple[AggItem, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)

    def get(self, name: str) -> Expr | None:
        """The value given for field ``name`` (case-insensitive), or ``None`` if the aggregate leaves it out."""
        key = name.upper()
        for item in self.items:
            if item.name == key:
                return item.value
        return None


Expr: TypeAlias = (
    IntLit | RealLit | BoolLit | StrLit | EnumLit | Name | Index | Member | Call | Unary | Binary | Aggregate
)

#: Binary operators by KRL priority, loosest first (KUKA System Software manual, "Priority of operators"):
#: comparisons bind *loosest*, so ``A > 0 AND B`` means ``A > (0 AND B)``; write ``(A > 0) AND B``.
BINARY_LEVELS: tuple[tuple[str, ...], ...] = (
    ("==", "<>", "<", ">", "<=", ">="),
    ("OR", "B_OR"),
    ("EXOR", "B_EXOR"),
    ("AND", "B_AND"),
    ("+", "-"),
    ("*", "/"),
)


# --- declarations ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DeclName:
    """One declared name; ``dims`` are the array sizes (``CHAR NAME[32]`` → ``(32,)``), empty for a scalar."""

    name: str
    dims: tuple[int, ...] = ()
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Decl:
    """``DECL [GLOBAL] [CONST] TYPE name[dims], ... [= init]`` (an initial value only with a single name)."""

    type_name: str
    names: tuple[DeclName, ...]
    init: Expr | None = None
    is_global: bool = False
    is_const: bool = False
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


# --- statements -------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Assign:
    """``target = value``; ``target`` is a :class:`Name`, :class:`Index` or :class:`Member` chain."""

    target: Expr
    value: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


MOTION_KINDS = ("PTP", "PTP_REL", "LIN", "LIN_REL")
APPROX_KINDS = ("C_PTP", "C_DIS", "C_VEL", "C_ORI")


@dataclass(frozen=True)
class Motion:
    """``PTP|PTP_REL|LIN|LIN_REL target [C_PTP|C_DIS|C_VEL|C_ORI]``: target is an aggregate or a variable."""

    kind: str
    target: Expr
    approx: str | None = None
    pos: Pos = field(default=NOPOS, compare=False, repr=False)

    @property
    def relative(self) -> bool:
        return self.kind.endswith("_REL")


@dataclass(frozen=True)
class WaitSec:
    """``WAIT SEC seconds`` (simulated seconds)."""

    seconds: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class WaitFor:
    """``WAIT FOR condition``: blocks until the condition holds (polls variables)."""

    condition: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class For:
    """``FOR var = start TO stop [STEP step] ... ENDFOR`` (``step`` ``None`` means 1)."""

    var: str
    start: Expr
    stop: Expr
    step: Expr | None
    body: tuple[Stmt, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class If:
    condition: Expr
    then_body: tuple[Stmt, ...]
    else_body: tuple[Stmt, ...] = ()
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class While:
    condition: Expr
    body: tuple[Stmt, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Repeat:
    """``REPEAT ... UNTIL condition``: the body runs at least once."""

    body: tuple[Stmt, ...]
    condition: Expr
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Loop:
    """``LOOP ... ENDLOOP``: endless until ``EXIT``."""

    body: tuple[Stmt, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Exit:
    """``EXIT``: leaves the innermost FOR/WHILE/REPEAT/LOOP."""

    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Halt:
    """``HALT``: the program stops (``#P_STOP``) until started again."""

    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Brake:
    """``BRAKE`` (``fast``: ``BRAKE F``): only in an interrupt routine; the robot stops on its path (a ramp-down
    stop; ``F``: a path-maintaining emergency stop) and the routine goes on once it is at rest."""

    fast: bool = False
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class InterruptDecl:
    """``INTERRUPT DECL prio WHEN condition DO routine(args)``: declares interrupt ``prio`` (1, 2, 4..39, 81..128);
    it is off until ``INTERRUPT ON prio``, then ``routine`` runs when ``condition`` turns from FALSE to TRUE."""

    prio: Expr
    condition: Expr
    routine: str
    args: tuple[Expr, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class InterruptCtl:
    """``INTERRUPT ON|OFF|ENABLE|DISABLE [prio]`` (``prio`` ``None``: every declared interrupt)."""

    action: str
    prio: Expr | None
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Return:
    """``RETURN [value]`` (a value only in a ``DEFFCT``)."""

    value: Expr | None = None
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class CallStmt:
    """A subprogram call as a statement: ``BAS(#INITMOV, 0)``, ``WARMUP()``."""

    name: str
    args: tuple[Expr, ...]
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


Stmt: TypeAlias = (
    Decl | Assign | Motion | WaitSec | WaitFor | For | If | While | Repeat | Loop | Exit | Halt | Return | CallStmt
    | Brake | InterruptDecl | InterruptCtl
)


# --- modules ---------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """A routine parameter: ``NAME:IN`` or ``NAME:OUT`` (``direction`` ``None`` if not given)."""

    name: str
    direction: str | None = None
    pos: Pos = field(default=NOPOS, compare=False, repr=False)


@dataclass(frozen=True)
class Routine:
    """``[GLOBAL] DEF name(params) ... END`` or ``[GLOBAL] DEFFCT type name(params) ... ENDFCT``.

    ``body`` starts with the declarations (KRL allows them only before the first executable statement).
    """

    name: str
    params: tuple[Param, ...]
    body: tuple[Stmt, ...]
    return_type: str | None = None
    is_global: bool = False
    pos: Pos = field(default=NOPOS, compare=False, repr=False)

    @property
    def is_function(self) -> bool:
        return self.return_type is not None


@dataclass(frozen=True)
class Module:
    """A ``.src`` file: its ``&`` header lines and routines (the first one is the module's main routine)."""

    routines: tuple[Routine, ...]
    headers: tuple[str, ...] = ()
    file: str = field(default="<string>", compare=False)

    @property
    def main(self) -> Routine:
        return self.routines[0]


@dataclass(frozen=True)
class DataList:
    """A ``.dat`` file: ``DEFDAT name [PUBLIC] ... ENDDAT`` with its declarations."""

    name: str
    decls: tuple[Decl, ...]
    public: bool = False
    headers: tuple[str, ...] = ()
    pos: Pos = field(default=NOPOS, compare=False, repr=False)
    file: str = field(default="<string>", compare=False)

    @property
    def globals(self) -> tuple[Decl, ...]:
        """The ``DECL GLOBAL`` declarations: visible to every program and to the link (``PUBLIC`` lists only)."""
        return tuple(d for d in self.decls if d.is_global)


Node: TypeAlias = Expr | Stmt | Routine | Module | DataList | DeclName | AggItem | Param
