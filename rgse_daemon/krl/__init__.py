"""KRL, the subset the daemon writes: tokens (:mod:`.lexer`), the syntax tree (:mod:`.ast`), parser and formatter,
a walker (:mod:`.walk`), typed values (:mod:`.values`) and expression evaluation (:mod:`.evaluate`) as the controller
has them, the abstract interpretation behind the static check (:mod:`.abstract`), and the rendering of the daemon's
templates (:mod:`.render`)."""

from rgse_daemon.krl.ast import DataList, Module, Pos, Routine
from rgse_daemon.krl.formatter import format_expr, format_module
from rgse_daemon.krl.parser import parse, parse_dat, parse_expression, parse_src
from rgse_daemon.krl.walk import Visit, walk

__all__ = [
    "DataList",
    "Module",
    "Pos",
    "Routine",
    "Visit",
    "format_expr",
    "format_module",
    "parse",
    "parse_dat",
    "parse_expression",
    "parse_src",
    "walk",
]
