"""The session language: tokenizer, expression parser (no eval), command parser and help."""

from .commands import *  # noqa: F401,F403  (the command dataclasses)
from .commands import COMMAND_NAMES, Relation, parse_command
from .expressions import FUNCTIONS, DictScope, NameKind, Scope, parse_condition, parse_expression
from .help import COMMAND_HELP, help_text
from .tokens import strip_comment, tokenize

__all__ = ["COMMAND_NAMES", "COMMAND_HELP", "FUNCTIONS", "DictScope", "NameKind", "Relation", "Scope",
           "help_text", "parse_command", "parse_condition", "parse_expression", "strip_comment", "tokenize"]
