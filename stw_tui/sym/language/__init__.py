"""The session language: tokenizer, line classifier, expression parser (no eval), command parser
and help.

The tokenizer and :func:`classify_line` load nothing heavy, so the TUI can tell what a line is
before the solver stack is imported; the parsers and help (which load sympy) are imported on
first use of any of their names.
"""

import importlib

from stw_tui.sym.language.tokens import QUERIES, WRITERS, CommandLine, classify_line, strip_comment, tokenize

__all__ = ["COMMAND_NAMES", "COMMAND_HELP", "CommandLine", "QUERIES", "WRITERS", "classify_line",
           "FUNCTIONS", "DictScope", "NameKind", "Relation", "Scope",
           "help_text", "parse_command", "parse_condition", "parse_expression", "strip_comment", "tokenize"]

_PARSING_MODULES = ("commands", "expressions", "help")   # commands: the command dataclasses too


def __getattr__(name: str):
    """A name of the parsers or help, importing them (and sympy) the first time one is asked for."""
    for module_name in _PARSING_MODULES:
        module = importlib.import_module(f"{__name__}.{module_name}")
        if not name.startswith("_") and hasattr(module, name):
            value = getattr(module, name)
            globals()[name] = value
            return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
