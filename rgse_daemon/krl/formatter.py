"""Turn a KRL syntax tree back into source text (what the daemon pushes; ``parse(format(tree)) == tree``).

Layout is canonical: upper-case keywords and names, two-space indentation, ``DECL`` always written, parentheses
only where KRL's operator priorities need them.
"""

from __future__ import annotations

from rgse_daemon.krl.ast import (
    BINARY_LEVELS,
    Aggregate,
    Assign,
    Binary,
    BoolLit,
    Brake,
    Call,
    CallStmt,
    DataList,
    Decl,
    EnumLit,
    Exit,
    Expr,
    For,
    Halt,
    If,
    Index,
    InterruptCtl,
    InterruptDecl,
    IntLit,
    Loop,
    Member,
    Module,
    Motion,
    Name,
    RealLit,
    Repeat,
    Return,
    Routine,
    Stmt,
    StrLit,
    Unary,
    WaitFor,
    WaitSec,
    While,
)

_LEVEL_OF = {op: level for level, ops in enumerate(BINARY_LEVELS) for op in ops}
_INDENT = "  "


def format_real(value: float) -> str:
    """A REAL literal that reads back as the same float (``repr`` is exact; KRL needs a digit before the dot)."""
    text = repr(float(value))
    if text in ("inf", "-inf", "nan"):
        raise ValueError(f"KRL has no literal for {text}")
    return text.upper()


def format_expr(expr: Expr) -> str:
    """KRL source of one expression."""
    match expr:
        case IntLit(value=v):
            return str(v)
        case RealLit(value=v):
            return format_real(v)
        case BoolLit(value=v):
            return "TRUE" if v else "FALSE"
        case StrLit(value=v):
            if '"' in v or "\n" in v or "\r" in v:
                raise ValueError(f"a KRL string cannot contain quotes or line breaks: {v!r}")
            return f'"{v}"'
        case EnumLit(name=n):
            return f"#{n}"
        case Name(name=n):
            return n
        case Index(base=b, indices=ix):
            return f"{_postfix_base(b)}[{', '.join(format_expr(i) for i in ix)}]"
        case Member(base=b, member=m):
            return f"{_postfix_base(b)}.{m}"
        case Call(name=n, args=args):
            return f"{n}({', '.join(format_expr(a) for a in args)})"
        case Unary(op=op, operand=operand):
            inner = format_expr(operand)
            if isinstance(operand, Binary | IntLit | RealLit):
                inner = f"({inner})"  # -(5) stays a Unary; a bare -5 would read back as the literal -5
            return f"{op} {inner}" if op in ("NOT", "B_NOT") else f"{op}{inner}"
        case Binary(op=op, left=left, right=right):
            level = _LEVEL_OF[op]
            return f"{_operand(left, level, False)} {op} {_operand(right, level, True)}"
        case Aggregate(type_name=t, items=items):
            body = ", ".join(f"{i.name} {format_expr(i.value)}" for i in items)
            return f"{{{t}: {body}}}" if t else f"{{{body}}}"
    raise TypeError(f"not a KRL expression: {expr!r}")


def _postfix_base(expr: Expr) -> str:
    text = format_expr(expr)
    return f"({text})" if isinstance(expr, Binary | Unary) or _negative_literal(expr) else text


def _negative_literal(expr: Expr) -> bool:
    return isinstance(expr, IntLit | RealLit) and (expr.value < 0 or str(expr.value).startswith("-"))


def _operand(expr: Expr, level: int, right: bool) -> str:
    text = format_expr(expr)
    if isinstance(expr, Binary):
        inner = _LEVEL_OF[expr.op]
        if inner < level or (right and inner == level):
            return f"({text})"
    return text


def _decl(decl: Decl) -> str:
    words = ["DECL"]
    if decl.is_global:
        words.append("GLOBAL")
    if decl.is_const:
        words.append("CONST")
    words.append(decl.type_name)
    names = ", ".join(n.name + (f"[{', '.join(map(str, n.dims))}]" if n.dims else "") for n in decl.names)
    text = " ".join(words) + " " + names
    if decl.init is not None:
        text += " = " + format_expr(decl.init)
    return text


def format_stmt(stmt: Stmt, indent: int = 0) -> list[str]:
    """Lines (without line ends) of one statement, nested blocks indented."""
    pad = _INDENT * indent
    match stmt:
        case Decl():
            return [pad + _decl(stmt)]
        case Assign(target=t, value=v):
            return [f"{pad}{format_expr(t)} = {format_expr(v)}"]
        case Motion(kind=k, target=t, approx=a):
            return [f"{pad}{k} {format_expr(t)}" + (f" {a}" if a else "")]
        case WaitSec(seconds=s):
            return [f"{pad}WAIT SEC {format_expr(s)}"]
        case WaitFor(condition=c):
            return [f"{pad}WAIT FOR {format_expr(c)}"]
        case For(var=var, start=a, stop=b, step=s, body=body):
            head = f"{pad}FOR {var} = {format_expr(a)} TO {format_expr(b)}" + (f" STEP {format_expr(s)}" if s else "")
            return [head, *_body(body, indent + 1), f"{pad}ENDFOR"]
        case If(condition=c, then_body=then_body, else_body=else_body):
            lines = [f"{pad}IF {format_expr(c)} THEN", *_body(then_body, indent + 1)]
            if else_body:
                lines += [f"{pad}ELSE", *_body(else_body, indent + 1)]
            return [*lines, f"{pad}ENDIF"]
        case While(condition=c, body=body):
            return [f"{pad}WHILE {format_expr(c)}", *_body(body, indent + 1), f"{pad}ENDWHILE"]
        case Repeat(body=body, condition=c):
            return [f"{pad}REPEAT", *_body(body, indent + 1), f"{pad}UNTIL {format_expr(c)}"]
        case Loop(body=body):
            return [f"{pad}LOOP", *_body(body, indent + 1), f"{pad}ENDLOOP"]
        case Exit():
            return [pad + "EXIT"]
        case Halt():
            return [pad + "HALT"]
        case Brake(fast=fast):
            return [pad + ("BRAKE F" if fast else "BRAKE")]
        case InterruptDecl(prio=prio, condition=c, routine=r, args=args):
            call = f"{r}({', '.join(format_expr(a) for a in args)})"
            return [f"{pad}INTERRUPT DECL {format_expr(prio)} WHEN {format_expr(c)} DO {call}"]
        case InterruptCtl(action=action, prio=prio):
            return [f"{pad}INTERRUPT {action}" + (f" {format_expr(prio)}" if prio is not None else "")]
        case Return(value=v):
            return [pad + "RETURN" + (f" {format_expr(v)}" if v is not None else "")]
        case CallStmt(name=n, args=args):
            return [f"{pad}{n}({', '.join(format_expr(a) for a in args)})"]
    raise TypeError(f"not a KRL statement: {stmt!r}")


def _body(stmts: tuple[Stmt, ...], indent: int) -> list[str]:
    return [line for s in stmts for line in format_stmt(s, indent)]


def format_routine(routine: Routine) -> list[str]:
    params = ", ".join(p.name + (f":{p.direction}" if p.direction else "") for p in routine.params)
    prefix = "GLOBAL " if routine.is_global else ""
    if routine.return_type is not None:
        head, end = f"{prefix}DEFFCT {routine.return_type} {routine.name}({params})", "ENDFCT"
    else:
        head, end = f"{prefix}DEF {routine.name}({params})", "END"
    return [head, *_body(routine.body, 1), end]


def format_module(module: Module | DataList) -> str:
    """Source text of a ``.src`` module or a ``.dat`` data list, CRLF-free, ending with a line end."""
    lines = list(module.headers)
    if isinstance(module, DataList):
        lines.append(f"DEFDAT {module.name}" + (" PUBLIC" if module.public else ""))
        lines += [_INDENT + _decl(d) for d in module.decls]
        lines.append("ENDDAT")
    else:
        for i, routine in enumerate(module.routines):
            if i:
                lines.append("")
            lines += format_routine(routine)
    return "\n".join(lines) + "\n"
