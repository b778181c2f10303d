"""The language front end: ``.mech`` text -> :class:`~mechdsl.grammar.model.Model`.

The grammar (``mech.lark``) and its parser with the cache of its tables (:mod:`.parser`,
:mod:`.cache`), the model's dataclasses (:mod:`.model`), expressions and their exact
derivatives (:mod:`.expr`, :mod:`.derive`), the checks that need no plugin (:mod:`.checks`)
and tables written inline (:mod:`.tables`). Pure: it reads no file (a table or a mesh file is
named, and read by :mod:`mechdsl.compiled`) and imports nothing from the later stages.
"""

from .model import Model
from .parser import (normalise, parse, parse_expr, parse_expr_list, parse_reductions,
                     parse_traces)

__all__ = ["Model", "normalise", "parse", "parse_expr", "parse_expr_list", "parse_reductions",
           "parse_traces"]
