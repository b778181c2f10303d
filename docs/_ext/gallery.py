"""The gallery of examples, made when the site is built: every ``examples/*.mech`` with the
comment that opens it, its pictures (``images/NAME.png`` and ``images/NAME_*.png``, as
``examples/plots.sh`` draws them) and the file itself. An example without a picture is a
build error (so with ``-W`` the site does not build without it).

Used as a directive in a page::

    ```{mech-gallery}
    ```
"""

from __future__ import annotations

import glob
import os

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective

DOCS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(os.path.dirname(DOCS), "examples")


def _intro(path: str) -> str:
    """The comment lines that open an example, as one paragraph."""
    lines = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            if not line.startswith("#"):
                break
            lines.append(line[1:].strip())
    return " ".join(lines)


def _owner(name: str, stems: list[str]) -> str | None:
    """The example a picture ``name`` (without .png) is of: the longest stem it is, or
    starts with followed by '_' (fourbar_coupler.png is fourbar_coupler.mech's, not
    fourbar.mech's)."""
    owners = [s for s in stems if name == s or name.startswith(s + "_")]
    return max(owners, key=len) if owners else None


def pictures(stem: str) -> list[str]:
    """The pictures of example ``stem`` under images/, by name relative to the docs."""
    stems = [os.path.splitext(os.path.basename(p))[0]
             for p in glob.glob(os.path.join(EXAMPLES, "*.mech"))]
    found = sorted(glob.glob(os.path.join(DOCS, "images", "*.png")),
                   key=lambda p: (os.path.basename(p) != f"{stem}.png", p))
    return [os.path.relpath(p, DOCS).replace(os.sep, "/") for p in found
            if _owner(os.path.splitext(os.path.basename(p))[0], stems) == stem]


class MechGallery(SphinxDirective):
    """Every example: its title, its opening comment, its pictures and its file."""

    def run(self) -> list[nodes.Node]:
        out: list[nodes.Node] = []
        for path in sorted(glob.glob(os.path.join(EXAMPLES, "*.mech"))):
            stem = os.path.splitext(os.path.basename(path))[0]
            self.env.note_dependency(path)
            found = pictures(stem)
            if not found:
                raise self.error(f"examples/{stem}.mech has no picture in docs/images "
                                 "(examples/plots.sh draws them)")
            section = nodes.section(ids=[nodes.make_id(f"example-{stem}")])
            section += nodes.title(text=f"{stem}.mech")
            text = [_intro(path), ""]
            for picture in found:
                text += [f"![{stem}](/{picture})", ""]
            rel = os.path.relpath(path, DOCS).replace(os.sep, "/")
            text += [f"```{{literalinclude}} {rel}", ":language: text", "```", ""]
            self.state.nested_parse(StringList(text, path), 0, section)
            out.append(section)
        return out


def setup(app):
    app.add_directive("mech-gallery", MechGallery)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
