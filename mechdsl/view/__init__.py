"""``mechdsl view``: the mechanism drawn live in a browser page beside the editor.

:mod:`.session` holds the file and the sliders' values (the only mutable state),
:mod:`mechdsl.outputs.payload` turns a run into the binary message the page reads (as the
``--html`` page does: an output format), :mod:`.server` serves the
page (``page/``) on the loopback interface behind a random token. The server's libraries
(starlette, uvicorn, websockets, watchfiles: the ``view`` extra) are imported only here.
"""
