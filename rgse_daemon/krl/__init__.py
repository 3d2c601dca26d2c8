"""KRL: the syntax tree, parser and formatter of the subset the daemon writes, and a walker for static checks."""

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
