"""Sphinx configuration of mechdsl's documentation site (``sphinx-build -W docs OUT``).

The pages are the Markdown files of this folder (MyST); the API reference comes from the
docstrings (autodoc); the gallery is made at build time from ``examples/`` and their
pictures in ``images/`` (``_ext/gallery.py``), so it always shows every example.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "_ext"))

project = "mechdsl"
author = "the mechdsl developers"
copyright = "2026, the mechdsl developers"

extensions = ["myst_parser", "sphinx.ext.autodoc", "gallery"]
source_suffix = {".md": "markdown"}
exclude_patterns = ["_build", "images/*.txt"]
myst_heading_anchors = 4  # the pages' own [text](#a-heading) links
myst_enable_extensions = ["colon_fence"]
autodoc_member_order = "bysource"
autodoc_typehints = "description"
html_theme = "furo"
html_title = "mechdsl"
# the pages link to the repository's files (examples, benchmarks) by relative paths that
# leave the site: those are links to the repository, not documents
myst_url_schemes = ["http", "https", "mailto"]
