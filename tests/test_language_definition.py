"""The language is defined by its grammar (mechdsl/grammar/mech.lark) and the tables of its
functions; the editor's helpers follow that definition. A keyword, a body item or a function
added to the grammar or the tables but not to the language server's completion, the symbol
table, the formatter or the TextMate grammar fails here, naming what is missing where."""

import json
import re

from conftest import ROOT

GRAMMAR = (ROOT / "mechdsl" / "grammar" / "mech.lark").read_text()
TEXTMATE = json.loads((ROOT / "editors" / "vscode" / "syntaxes" /
                       "mech.tmLanguage.json").read_text())


def _rule(name: str) -> str:
    m = re.search(rf"^\??{name}:(.*?)(?=^\S)", GRAMMAR + "\nEND", flags=re.M | re.S)
    assert m, name
    return m.group(1)


def _alternatives(name: str) -> list[str]:
    return [a.strip() for a in _rule(name).split("//")[0].split("|")]


def _first_word(rule: str) -> str:
    return re.search(r'"([a-z_][a-z0-9_]*)"', _rule(rule)).group(1)


#: the statements' keywords, from the grammar: the first word of each statement's rule
STATEMENTS = {_first_word(r) for r in _alternatives("_statement") if r != '";"'}
#: the body items' keywords
ITEMS = {_first_word(r) for r in _alternatives("_body_item") if r != '";"'}
#: every word the grammar spells (keywords of expressions and of statements' insides too)
WORDS = set(re.findall(r'"([a-z_][a-z0-9_]*)"', re.sub(r"//[^\n]*", "", GRAMMAR)))


def _functions() -> set[str]:
    from mechdsl.grammar import expr as E
    from mechdsl.grammar.model import REDUCTIONS, TRACE_FUNCTIONS
    from mechdsl.grammar.motion_functions import SIGNATURES

    return {*E.FUNCTIONS, "table", *SIGNATURES, *REDUCTIONS, *TRACE_FUNCTIONS}


def _textmate_words(scope_prefix: str = "") -> set[str]:
    """The words of the TextMate rules' alternations (\\b(a|b|c)), of the rules whose scope
    (or a capture's) starts with ``scope_prefix``."""
    out = set()
    for rule in TEXTMATE["repository"].values():
        scopes = [rule.get("name") or ""] + [c["name"] for c in rule.get("captures", {}).values()]
        if not any(s.startswith(scope_prefix) for s in scopes):
            continue
        for group in re.findall(r"\\b\(([a-z0-9_|]+)\)", rule["match"]):
            out.update(group.split("|"))
    return out


def test_the_grammar_is_read_as_expected():
    # (so that the checks below compare real sets)
    assert {"param", "body", "joint", "drive", "initial", "force", "simulate", "output",
            "trace", "units", "sweep", "plugin", "optimize", "minimize", "subject"} <= STATEMENTS
    assert {"point", "guess", "mass", "inertia", "v0"} <= ITEMS
    assert {"if", "then", "else", "and", "or", "not", "in", "to", "polygon"} <= WORDS


def test_the_language_servers_completion_knows_every_statement_item_and_function(registry):
    """What the language server offers (lsp.completions at a cursor, as an editor asks),
    against the grammar and the tables: every statement at a statement's start, every body
    item inside a body, every function in an expression of an output, and the trace
    functions in a trace statement."""
    from mechdsl import lsp

    def offered(text: str, kind: str) -> set[str]:
        lines = text.split("\n")
        found = lsp.completions(text, len(lines) - 1, len(lines[-1]), registry)
        return {label for label, k, _ in found if k == kind}

    statements = {w for s in offered("param a = 1\n", "keyword") for w in s.split()}
    assert STATEMENTS - statements == set(), "statements the completion never offers"
    assert ITEMS - offered("body b {\n  ", "keyword") == set(), \
        "body items the completion never offers"
    functions = offered("body b { }\noutput x = ", "function") | \
        offered("body b { }\ntrace ", "function")
    assert _functions() - functions == set(), "functions the completion never offers"


def test_the_symbol_table_knows_every_statement_and_function():
    from mechdsl.grammar import expr as E
    from mechdsl.grammar import symbols

    starts = symbols.RESERVED_STARTS | symbols.SOFT_STARTS
    assert STATEMENTS - starts == set(), "statements the symbol table does not start"
    known = set(E.FUNCTIONS) | {"table"} | set(symbols.OUTPUT_FUNCTIONS)
    from mechdsl.grammar.model import TRACE_FUNCTIONS

    assert _functions() - known - set(TRACE_FUNCTIONS) == set()
    # a trace function is a function where a trace statement calls it
    text = "body b { }\ntrace " + ", ".join(f"{f}(b, ground)" for f in TRACE_FUNCTIONS) + "\n"
    kinds = {s.name: s.kind for s in symbols.index(text).symbols}
    assert all(kinds[f] == "function" for f in TRACE_FUNCTIONS), kinds


def test_the_formatter_spaces_every_expression_keyword_as_an_operator():
    from mechdsl.grammar import format as F

    expression_words = {"if", "then", "else", "and", "or", "not", "step", "count"}
    assert expression_words <= WORDS
    assert expression_words - F._OPERATORS == set()
    assert set(F._BLOCKS) <= STATEMENTS


def test_the_textmate_grammar_colours_every_keyword_and_function():
    keywords = _textmate_words("keyword")
    missing = (STATEMENTS | ITEMS | WORDS) - keywords
    assert missing == set(), f"keywords without a TextMate keyword scope: {sorted(missing)}"
    functions = _textmate_words("support.function")
    # 'initial' and 'range' are both statements or functions by place; every function is
    # coloured as one where it is called
    assert _functions() - functions == set(), "functions the TextMate grammar does not colour"


def test_no_module_reaches_into_the_parser():
    """The parser's tables are its own: the tools lex and parse through its public
    functions (lex, parse_tree, parse), never its private parser object."""
    users = [p for p in (ROOT / "mechdsl").rglob("*.py")
             if p.name != "parser.py" and re.search(r"parser import[^\n]*\b_parser\b|"
                                                    r"parser\._parser\b", p.read_text())]
    assert users == []
