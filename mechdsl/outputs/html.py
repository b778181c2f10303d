"""One self-contained HTML page of a run (``mechdsl run FILE --html out.html``): the page of
``mechdsl view`` (:mod:`mechdsl.view`) with the run inside it, for a report, a course page or
a colleague. It opens from the disk in any browser, offline, with no server: the animation,
the outputs' plots, and every variant of a sweep overlaid with its legend (the sweep's values
were computed beforehand; nothing is solved in the browser).

The run travels as the view's binary message (:mod:`mechdsl.outputs.payload`), base64 in a
``<script type="application/octet-stream">`` element: data, never run as script. Its JSON
header is parsed by the page, and every name and message in it is shown as text. The page's
script and style are the view's own files, inlined (a file opened from the disk cannot load
them from beside it in every browser).
"""

from __future__ import annotations

import base64
import html
import os
from pathlib import Path

PAGE = Path(__file__).resolve().parents[1] / "view" / "page"


def memory(system, path: str, settings: dict) -> dict[str, int]:
    """What the page adds to the run (:attr:`mechdsl.outputs.Format.memory`): the drawing's
    world coordinates, as a snapshot's (:func:`mechdsl.outputs.draw.snapshot_memory`)."""
    from .draw import snapshot_memory

    return snapshot_memory(system, path, settings)


def summary(results, path: str, settings: dict) -> str:
    """The line ``mechdsl run`` prints of the page written to ``path``."""
    n = int(results.n_solved.max(initial=0))
    variants = f", {results.n_variants} variants" if results.sweep else ""
    return f"{path}: page of {n} instant{'s' if n != 1 else ''}{variants}"


def write_page(results, system, path: str | os.PathLike) -> None:
    """Write the page of ``results`` (of ``system``, with poses) to ``path``, atomically."""
    from . import payload
    from ..writing import write_text

    message = payload.run_message(system, results, (), file=os.path.basename(
        results.source_name or "mechanism"))
    data = base64.b64encode(message).decode("ascii")
    page = (PAGE / "index.html").read_text(encoding="utf-8")
    style = (PAGE / "view.css").read_text(encoding="utf-8")
    script = (PAGE / "view.js").read_text(encoding="utf-8")
    # the inlined script must not end its element early
    script = script.replace("</script", "<\\/script")
    page = page.replace('<link rel="stylesheet" href="view.css">',
                        f"<style>\n{style}</style>")
    page = page.replace('<script src="view.js" defer></script>',
                        '<script id="mechdsl-run" type="application/octet-stream">'
                        f"{data}</script>")
    page = page.replace("<title>mechdsl view</title>",
                        f"<title>{html.escape(os.path.basename(os.fspath(path)))}</title>")
    page = page.replace("</body>", f"<script>\n{script}</script>\n</body>")
    write_text(path, lambda f: f.write(page))
