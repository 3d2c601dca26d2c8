"""Recursive-descent parser for the KRL subset of the daemon's templates (see :mod:`rgse_daemon.krl.ast`).

Entry points: :func:`parse_src` (a ``.src`` module of ``DEF``/``DEFFCT`` routines), :func:`parse_dat` (a ``.dat``
data list), :func:`parse` (either, by its first keyword) and :func:`parse_expression` (also used to read KRL value
strings such as ``{E6AXIS: A1 0.0, ...}``). Every syntax problem raises :class:`KrlSyntaxError` with file, line and
column; nothing else escapes.
"""

from __future__ import annotations

import time

from rgse_daemon.errors import KrlSyntaxError
from rgse_daemon.krl.ast import (
    APPROX_KINDS,
    BINARY_LEVELS,
    MOTION_KINDS,
    AggItem,
    Aggregate,
    Assign,
    Binary,
    BoolLit,
    Brake,
    Call,
    CallStmt,
    DataList,
    Decl,
    DeclName,
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
    Param,
    Pos,
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
from rgse_daemon.krl.lexer import DEADLINE_STRIDE, OutOfTime, Tok, Token, tokenize

#: Words that cannot name a variable (struct members and aggregate fields may still use them).
KEYWORDS = (
    frozenset(
        """DEF END DEFFCT ENDFCT DEFDAT ENDDAT DECL GLOBAL PUBLIC CONST IF THEN ELSE ENDIF FOR TO STEP ENDFOR
    LOOP ENDLOOP WHILE ENDWHILE REPEAT UNTIL EXIT WAIT SEC HALT RETURN NOT AND OR EXOR B_NOT B_AND B_OR B_EXOR
    TRUE FALSE
    SWITCH CASE DEFAULT ENDSWITCH GOTO INTERRUPT TRIGGER CONTINUE BRAKE""".split()
    )
    | frozenset(MOTION_KINDS)
    | frozenset(APPROX_KINDS)
)

#: Built-in data types that may be declared without the DECL keyword.
BUILTIN_TYPES = frozenset("INT REAL BOOL CHAR E6AXIS E6POS AXIS POS FRAME LOAD".split())

#: Deepest nesting of blocks, parentheses, aggregates and unary operators (keeps Python's stack safe).
MAX_NESTING = 64


class _Parser:
    def __init__(self, text: str, file: str, deadline: float | None = None) -> None:
        self.file = file
        self.deadline = deadline
        self.toks = tokenize(text, file, deadline)
        self.i = 0
        self.depth = 0

    # --- token helpers ---------------------------------------------------------------------------------------------
    @property
    def tok(self) -> Token:
        return self.toks[self.i]

    def peek(self, ahead: int = 1) -> Token:
        return self.toks[min(self.i + ahead, len(self.toks) - 1)]

    def advance(self) -> Token:
        tok = self.toks[self.i]
        if tok.kind is not Tok.EOF:
            self.i += 1
            if self.deadline is not None and self.i % DEADLINE_STRIDE == 0 and time.monotonic() > self.deadline:
                raise OutOfTime(tok.line)
        return tok

    def error(self, message: str, tok: Token | None = None) -> KrlSyntaxError:
        tok = tok or self.tok
        return KrlSyntaxError(message, self.file, tok.line, tok.column)

    def is_word(self, *words: str) -> bool:
        return self.tok.kind is Tok.NAME and self.tok.text in words

    def is_op(self, *ops: str) -> bool:
        return self.tok.kind is Tok.OP and self.tok.text in ops

    def expect_word(self, word: str) -> Token:
        if not self.is_word(word):
            raise self.error(f"expected {word}, found {self.tok.describe()}")
        return self.advance()

    def expect_op(self, op: str) -> Token:
        if not self.is_op(op):
            raise self.error(f"expected '{op}', found {self.tok.describe()}")
        return self.advance()

    def expect_name(self, what: str = "a name") -> Token:
        if self.tok.kind is not Tok.NAME or self.tok.text in KEYWORDS:
            raise self.error(f"expected {what}, found {self.tok.describe()}")
        return self.advance()

    def expect_eol(self) -> None:
        if self.tok.kind is Tok.EOF:
            return
        if self.tok.kind is not Tok.NEWLINE:
            raise self.error(f"expected end of line, found {self.tok.describe()}")
        self.advance()

    def skip_newlines(self) -> None:
        while self.tok.kind is Tok.NEWLINE:
            self.advance()

    @staticmethod
    def pos(tok: Token) -> Pos:
        return Pos(tok.line, tok.column)

    # --- files -------------------------------------------------------------------------------------------------------
    def headers(self) -> tuple[str, ...]:
        found = []
        self.skip_newlines()
        while self.tok.kind is Tok.HEADER:
            found.append(self.advance().text)
            self.skip_newlines()
        return tuple(found)

    def src_module(self) -> Module:
        headers = self.headers()
        routines = []
        while self.tok.kind is not Tok.EOF:
            routines.append(self.routine())
            self.skip_newlines()
        if not routines:
            raise self.error("expected DEF or DEFFCT: the file holds no routine")
        seen: dict[str, Routine] = {}
        for r in routines:
            if r.name in seen:
                raise KrlSyntaxError(f"routine {r.name} defined twice", self.file, r.pos.line, r.pos.column)
            seen[r.name] = r
        return Module(tuple(routines), headers, self.file)

    def routine(self) -> Routine:
        start = self.tok
        is_global = False
        if self.is_word("GLOBAL"):
            self.advance()
            is_global = True
        return_type: str | None = None
        if self.is_word("DEF"):
            self.advance()
            end_word = "END"
        elif self.is_word("DEFFCT"):
            self.advance()
            return_type = self.expect_name("the function's return type").text
            end_word = "ENDFCT"
        else:
            raise self.error(f"expected DEF or DEFFCT, found {self.tok.describe()}")
        name = self.expect_name("the routine's name").text
        self.expect_op("(")
        params: list[Param] = []
        if not self.is_op(")"):
            while True:
                ptok = self.expect_name("a parameter name")
                direction = None
                if self.is_op(":"):
                    self.advance()
                    dtok = self.advance()
                    if dtok.kind is not Tok.NAME or dtok.text not in ("IN", "OUT"):
                        raise self.error(f"expected IN or OUT, found {dtok.describe()}", dtok)
                    direction = dtok.text
                params.append(Param(ptok.text, direction, self.pos(ptok)))
                if not self.is_op(","):
                    break
                self.advance()
        self.expect_op(")")
        self.expect_eol()
        body = self.block((end_word,), allow_decls=True)
        self.expect_word(end_word)
        self.expect_eol()
        return Routine(name, tuple(params), body, return_type, is_global, self.pos(start))

    def dat_module(self) -> DataList:
        headers = self.headers()
        start = self.expect_word("DEFDAT")
        name = self.expect_name("the data list's name").text
        public = False
        if self.is_word("PUBLIC"):
            self.advance()
            public = True
        self.expect_eol()
        decls = []
        self.skip_newlines()
        while not self.is_word("ENDDAT"):
            if self.tok.kind is Tok.EOF:
                raise self.error("expected ENDDAT before the end of the file")
            if not self.at_decl():
                raise self.error(f"expected a declaration or ENDDAT, found {self.tok.describe()}")
            decls.append(self.decl())
            self.expect_eol()
            self.skip_newlines()
        self.advance()
        self.skip_newlines()
        if self.tok.kind is not Tok.EOF:
            raise self.error(f"expected the end of the file after ENDDAT, found {self.tok.describe()}")
        return DataList(name, tuple(decls), public, headers, self.pos(start), self.file)

    # --- statements --------------------------------------------------------------------------------------------------
    def block(self, terminators: tuple[str, ...], allow_decls: bool = False) -> tuple[Stmt, ...]:
        """Statements up to (not including) one of ``terminators``."""
        self.depth += 1
        try:
            if self.depth > MAX_NESTING:
                raise self.error(f"blocks nested deeper than {MAX_NESTING} levels")
            return self._block(terminators, allow_decls)
        finally:
            self.depth -= 1

    def _block(self, terminators: tuple[str, ...], allow_decls: bool) -> tuple[Stmt, ...]:
        stmts: list[Stmt] = []
        decls_allowed = allow_decls
        self.skip_newlines()
        while not self.is_word(*terminators):
            if self.tok.kind is Tok.EOF:
                raise self.error(f"expected {' or '.join(terminators)} before the end of the file")
            if self.at_decl():
                if not decls_allowed:
                    raise self.error("declarations must come before the first statement of a routine")
                stmts.append(self.decl())
            else:
                decls_allowed = False
                stmts.append(self.statement())
            self.expect_eol()
            self.skip_newlines()
        return tuple(stmts)

    def at_decl(self) -> bool:
        if self.is_word("DECL"):
            return True
        return (
            self.tok.kind is Tok.NAME
            and self.tok.text in BUILTIN_TYPES
            and self.peek().kind is Tok.NAME
            and self.peek().text not in KEYWORDS
        )

    def decl(self) -> Decl:
        start = self.tok
        if self.is_word("DECL"):
            self.advance()
        is_global = is_const = False
        while self.is_word("GLOBAL", "CONST"):
            if self.advance().text == "GLOBAL":
                is_global = True
            else:
                is_const = True
        type_name = self.expect_name("a type name").text
        names: list[DeclName] = []
        while True:
            ntok = self.expect_name("a variable name")
            dims: list[int] = []
            if self.is_op("["):
                self.advance()
                while True:
                    dtok = self.advance()
                    if dtok.kind is not Tok.INT or not isinstance(dtok.value, int) or dtok.value < 1:
                        raise self.error(f"expected a positive array size, found {dtok.describe()}", dtok)
                    dims.append(dtok.value)
                    if not self.is_op(","):
                        break
                    self.advance()
                self.expect_op("]")
            names.append(DeclName(ntok.text, tuple(dims), self.pos(ntok)))
            if not self.is_op(","):
                break
            self.advance()
        init = None
        if self.is_op("="):
            if len(names) > 1:
                raise self.error("an initial value needs a declaration of a single name")
            self.advance()
            init = self.expression()
        return Decl(type_name, tuple(names), init, is_global, is_const, self.pos(start))

    def statement(self) -> Stmt:
        tok = self.tok
        p = self.pos(tok)
        if tok.kind is Tok.NAME:
            word = tok.text
            if word == "IF":
                return self.if_stmt()
            if word == "FOR":
                return self.for_stmt()
            if word == "WHILE":
                self.advance()
                cond = self.expression()
                self.expect_eol()
                body = self.block(("ENDWHILE",))
                self.advance()
                return While(cond, body, p)
            if word == "REPEAT":
                self.advance()
                self.expect_eol()
                body = self.block(("UNTIL",))
                self.advance()
                return Repeat(body, self.expression(), p)
            if word == "LOOP":
                self.advance()
                self.expect_eol()
                body = self.block(("ENDLOOP",))
                self.advance()
                return Loop(body, p)
            if word == "EXIT":
                self.advance()
                return Exit(p)
            if word == "HALT":
                self.advance()
                return Halt(p)
            if word == "BRAKE":
                self.advance()
                fast = self.is_word("F")
                if fast:
                    self.advance()
                return Brake(fast, p)
            if word == "INTERRUPT":
                return self.interrupt_stmt()
            if word == "RETURN":
                self.advance()
                if self.tok.kind in (Tok.NEWLINE, Tok.EOF):
                    return Return(None, p)
                return Return(self.expression(), p)
            if word == "WAIT":
                self.advance()
                if self.is_word("SEC"):
                    self.advance()
                    return WaitSec(self.expression(), p)
                if self.is_word("FOR"):
                    self.advance()
                    return WaitFor(self.expression(), p)
                raise self.error(f"expected SEC or FOR after WAIT, found {self.tok.describe()}")
            if word in MOTION_KINDS:
                self.advance()
                target = self.expression()
                approx = None
                if self.tok.kind is Tok.NAME and self.tok.text in APPROX_KINDS:
                    approx = self.advance().text
                return Motion(word, target, approx, p)
            if word in KEYWORDS:
                raise self.error(f"unexpected {word}")
        if tok.kind is not Tok.NAME:
            raise self.error(f"expected a statement, found {tok.describe()}")
        target = self.postfix()
        if self.is_op("="):
            if not _is_lvalue(target):
                raise self.error("cannot assign to this expression", tok)
            self.advance()
            return Assign(target, self.expression(), p)
        if isinstance(target, Call):
            return CallStmt(target.name, target.args, p)
        raise self.error(f"expected '=' or a call, found {self.tok.describe()}")

    def interrupt_stmt(self) -> InterruptDecl | InterruptCtl:
        p = self.pos(self.advance())
        if self.is_word("DECL"):
            self.advance()
            prio = self.expression()
            self.expect_word("WHEN")
            cond = self.expression()
            self.expect_word("DO")
            call = self.postfix()
            if not isinstance(call, Call):
                raise self.error("expected an interrupt routine call after DO")
            return InterruptDecl(prio, cond, call.name, call.args, p)
        if self.is_word("ON", "OFF", "ENABLE", "DISABLE"):
            action = self.advance().text
            if self.tok.kind in (Tok.NEWLINE, Tok.EOF):
                return InterruptCtl(action, None, p)
            return InterruptCtl(action, self.expression(), p)
        raise self.error(f"expected DECL, ON, OFF, ENABLE or DISABLE after INTERRUPT, found {self.tok.describe()}")

    def if_stmt(self) -> If:
        p = self.pos(self.advance())
        cond = self.expression()
        self.expect_word("THEN")
        self.expect_eol()
        then_body = self.block(("ELSE", "ENDIF"))
        else_body: tuple[Stmt, ...] = ()
        if self.is_word("ELSE"):
            self.advance()
            self.expect_eol()
            else_body = self.block(("ENDIF",))
        self.advance()
        return If(cond, then_body, else_body, p)

    def for_stmt(self) -> For:
        p = self.pos(self.advance())
        var = self.expect_name("the loop counter").text
        self.expect_op("=")
        start = self.expression()
        self.expect_word("TO")
        stop = self.expression()
        step = None
        if self.is_word("STEP"):
            self.advance()
            step = self.expression()
        self.expect_eol()
        body = self.block(("ENDFOR",))
        self.advance()
        return For(var, start, stop, step, body, p)

    # --- expressions -------------------------------------------------------------------------------------------------
    def expression(self) -> Expr:
        self.depth += 1
        try:
            if self.depth > MAX_NESTING:
                raise self.error(f"expression nested deeper than {MAX_NESTING} levels")
            return self._binary(0)
        finally:
            self.depth -= 1

    def _binary(self, level: int) -> Expr:
        if level == len(BINARY_LEVELS):
            return self.unary()
        left = self._binary(level + 1)
        ops = BINARY_LEVELS[level]
        while (self.tok.kind is Tok.OP or self.tok.kind is Tok.NAME) and self.tok.text in ops:
            op_tok = self.advance()
            right = self._binary(level + 1)
            left = Binary(op_tok.text, left, right, self.pos(op_tok))
        return left

    def unary(self) -> Expr:
        tok = self.tok
        if self.is_op("-", "+") or self.is_word("NOT", "B_NOT"):
            self.advance()
            nxt = self.tok
            if tok.text == "-" and nxt.kind in (Tok.INT, Tok.REAL) and isinstance(nxt.value, int | float):
                self.advance()  # a negative literal, so that {A2 -90} holds the number -90
                if nxt.kind is Tok.INT:
                    return IntLit(-int(nxt.value), self.pos(tok))
                return RealLit(-float(nxt.value), self.pos(tok), "-" + nxt.text)
            self.depth += 1
            try:
                if self.depth > MAX_NESTING:
                    raise self.error(f"expression nested deeper than {MAX_NESTING} levels")
                return Unary(tok.text, self.unary(), self.pos(tok))
            finally:
                self.depth -= 1
        return self.postfix()

    def postfix(self) -> Expr:
        expr = self.primary()
        while True:
            if self.is_op("["):
                open_tok = self.advance()
                indices: list[Expr] = []
                if not self.is_op("]"):
                    indices.append(self.expression())
                    while self.is_op(","):
                        self.advance()
                        indices.append(self.expression())
                self.expect_op("]")
                expr = Index(expr, tuple(indices), self.pos(open_tok))
            elif self.is_op("."):
                dot = self.advance()
                if self.tok.kind is not Tok.NAME:
                    raise self.error(f"expected a member name after '.', found {self.tok.describe()}")
                expr = Member(expr, self.advance().text, self.pos(dot))
            else:
                return expr

    def primary(self) -> Expr:
        tok = self.tok
        p = self.pos(tok)
        if tok.kind is Tok.INT and isinstance(tok.value, int):
            self.advance()
            return IntLit(tok.value, p)
        if tok.kind is Tok.REAL and isinstance(tok.value, float):
            self.advance()
            return RealLit(tok.value, p, tok.text)
        if tok.kind is Tok.STR:
            self.advance()
            return StrLit(tok.text, p)
        if tok.kind is Tok.ENUM:
            self.advance()
            return EnumLit(tok.text, p)
        if self.is_word("TRUE", "FALSE"):
            self.advance()
            return BoolLit(tok.text == "TRUE", p)
        if self.is_op("("):
            self.advance()
            inner = self.expression()
            self.expect_op(")")
            return inner
        if self.is_op("{"):
            return self.aggregate()
        if tok.kind is Tok.NAME and tok.text not in KEYWORDS:
            self.advance()
            if self.is_op("("):
                self.advance()
                args: list[Expr] = []
                if not self.is_op(")"):
                    args.append(self.expression())
                    while self.is_op(","):
                        self.advance()
                        args.append(self.expression())
                self.expect_op(")")
                return Call(tok.text, tuple(args), p)
            return Name(tok.text, p)
        raise self.error(f"expected an expression, found {tok.describe()}")

    def aggregate(self) -> Aggregate:
        p = self.pos(self.expect_op("{"))
        type_name = None
        if self.tok.kind is Tok.NAME and self.peek().kind is Tok.OP and self.peek().text == ":":
            type_name = self.advance().text
            self.advance()
        items: list[AggItem] = []
        seen: set[str] = set()
        while True:
            ftok = self.tok
            if ftok.kind is not Tok.NAME:
                raise self.error(f"expected a field name in the aggregate, found {ftok.describe()}")
            self.advance()
            if ftok.text in seen:
                raise self.error(f"field {ftok.text} given twice", ftok)
            seen.add(ftok.text)
            items.append(AggItem(ftok.text, self.expression(), self.pos(ftok)))
            if not self.is_op(","):
                break
            self.advance()
        self.expect_op("}")
        return Aggregate(type_name, tuple(items), p)


def _is_lvalue(expr: Expr) -> bool:
    while isinstance(expr, Index | Member):
        expr = expr.base
    return isinstance(expr, Name)


def parse_src(text: str, file: str = "<string>", deadline: float | None = None) -> Module:
    """Parse a ``.src`` module (headers, then one or more ``DEF``/``DEFFCT`` routines). ``deadline``
    (``time.monotonic()``): raise :class:`~rgse_daemon.krl.lexer.OutOfTime` once it has passed."""
    return _Parser(text, file, deadline).src_module()


def parse_dat(text: str, file: str = "<string>", deadline: float | None = None) -> DataList:
    """Parse a ``.dat`` data list (``DEFDAT name [PUBLIC]`` … declarations … ``ENDDAT``); ``deadline`` as in
    :func:`parse_src`."""
    return _Parser(text, file, deadline).dat_module()


def parse(text: str, file: str = "<string>") -> Module | DataList:
    """Parse a ``.src`` or ``.dat`` file, telling them apart by their first keyword."""
    parser = _Parser(text, file)
    parser.headers()
    is_dat = parser.is_word("DEFDAT")
    return parse_dat(text, file) if is_dat else parse_src(text, file)


def parse_expression(text: str, file: str = "<expression>") -> Expr:
    """Parse one expression that fills ``text`` (also reads KRL value strings: ``#T1``, ``{E6AXIS: A1 0.0}``)."""
    parser = _Parser(text, file)
    parser.skip_newlines()
    expr = parser.expression()
    parser.skip_newlines()
    if parser.tok.kind is not Tok.EOF:
        raise parser.error(f"unexpected {parser.tok.describe()} after the expression")
    return expr
