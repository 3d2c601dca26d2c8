"""Walking a KRL syntax tree: every statement, in source order, with what encloses it.

The interlock's static check needs each motion with its target, the settings assigned before it, every variable
written and every WAIT, wherever they sit (inside FOR/IF/WHILE/REPEAT/LOOP bodies of any routine). A linear walk
in source order gives exactly that; ``enclosing`` says which loops and branches a statement depends on.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from rgse_daemon.krl.ast import (
    Aggregate,
    Assign,
    Binary,
    Call,
    DataList,
    Decl,
    Expr,
    For,
    If,
    Index,
    Loop,
    Member,
    Module,
    Motion,
    Name,
    Repeat,
    Routine,
    Stmt,
    Unary,
    WaitFor,
    WaitSec,
    While,
)

Block = For | If | While | Repeat | Loop


@dataclass(frozen=True)
class Visit:
    """One statement found by :func:`walk`.

    ``routine`` is ``None`` for declarations of a data list; ``enclosing`` lists the compound statements around
    ``stmt``, outermost first; ``in_else`` is true when the innermost enclosing IF holds it in its ELSE branch.
    """

    stmt: Stmt
    routine: Routine | None
    enclosing: tuple[Block, ...] = ()
    in_else: bool = False

    @property
    def in_loop(self) -> bool:
        return any(isinstance(b, For | While | Repeat | Loop) for b in self.enclosing)


def child_blocks(stmt: Stmt) -> list[tuple[tuple[Stmt, ...], bool]]:
    """The statement lists directly inside ``stmt`` as ``(body, is_else_branch)`` pairs, in source order."""
    if isinstance(stmt, If):
        return [(stmt.then_body, False), (stmt.else_body, True)]
    if isinstance(stmt, For | While | Repeat | Loop):
        return [(stmt.body, False)]
    return []


def walk(node: Module | DataList | Routine | tuple[Stmt, ...]) -> Iterator[Visit]:
    """Every statement of ``node`` depth-first in source order (a compound statement before its body)."""
    if isinstance(node, DataList):
        for decl in node.decls:
            yield Visit(decl, None)
    elif isinstance(node, Module):
        for routine in node.routines:
            yield from _walk_body(routine.body, routine, ())
    elif isinstance(node, Routine):
        yield from _walk_body(node.body, node, ())
    else:
        yield from _walk_body(node, None, ())


def _walk_body(
    body: tuple[Stmt, ...], routine: Routine | None, enclosing: tuple[Block, ...], in_else: bool = False
) -> Iterator[Visit]:
    for stmt in body:
        yield Visit(stmt, routine, enclosing, in_else)
        if isinstance(stmt, For | If | While | Repeat | Loop):
            for inner, is_else in child_blocks(stmt):
                yield from _walk_body(inner, routine, (*enclosing, stmt), is_else)


def motions(node: Module | Routine) -> Iterator[Visit]:
    """The visits whose statement is a PTP/PTP_REL/LIN/LIN_REL motion."""
    return (v for v in walk(node) if isinstance(v.stmt, Motion))


def waits(node: Module | Routine) -> Iterator[Visit]:
    """The visits whose statement is a ``WAIT SEC`` or ``WAIT FOR``."""
    return (v for v in walk(node) if isinstance(v.stmt, WaitSec | WaitFor))


def root_name(target: Expr) -> str | None:
    """The variable a target expression belongs to: ``$VEL_AXIS[1]`` → ``$VEL_AXIS``, ``$VEL.CP`` → ``$VEL``."""
    while isinstance(target, Index | Member):
        target = target.base
    return target.name if isinstance(target, Name) else None


def written_targets(stmt: Stmt) -> list[Expr]:
    """What ``stmt`` itself writes: an assignment's target, a FOR counter, a declaration's initialised name.

    Calls are not followed (a subprogram's OUT parameters are its own business: the interlock refuses unknown calls).
    """
    if isinstance(stmt, Assign):
        return [stmt.target]
    if isinstance(stmt, For):
        return [Name(stmt.var, stmt.pos)]
    if isinstance(stmt, Decl) and stmt.init is not None:
        return [Name(n.name, n.pos) for n in stmt.names]
    return []


def iter_exprs(expr: Expr) -> Iterator[Expr]:
    """``expr`` and all its sub-expressions, pre-order."""
    yield expr
    if isinstance(expr, Index):
        yield from iter_exprs(expr.base)
        for i in expr.indices:
            yield from iter_exprs(i)
    elif isinstance(expr, Member):
        yield from iter_exprs(expr.base)
    elif isinstance(expr, Call):
        for a in expr.args:
            yield from iter_exprs(a)
    elif isinstance(expr, Unary):
        yield from iter_exprs(expr.operand)
    elif isinstance(expr, Binary):
        yield from iter_exprs(expr.left)
        yield from iter_exprs(expr.right)
    elif isinstance(expr, Aggregate):
        for item in expr.items:
            yield from iter_exprs(item.value)
