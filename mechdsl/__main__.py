"""``python -m mechdsl``: the command line (:mod:`mechdsl.cli`)."""

import os
import sys

# `python -m` puts the current folder first on sys.path, so that a module there named like a
# plugin (or like anything imported later) would be imported instead of the installed one:
# drop it, as `python -P` does. Python has imported the package and its own dependencies
# (numpy, lark, pluggy) by now: in an untrusted folder, `python -P -m mechdsl` or the
# `mechdsl` command is safe from the first import.
if not getattr(sys.flags, "safe_path", False) and sys.path and sys.path[0] in ("", os.getcwd()):
    del sys.path[0]

from mechdsl.cli import entry  # noqa: E402 - after the sys.path fix

entry()
