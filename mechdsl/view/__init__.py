"""``mechdsl view``: the mechanism drawn live in a browser page beside the editor.

:mod:`.session` holds the file and the sliders' values (the only mutable state),
:mod:`.payload` turns a run into the binary message the page reads, :mod:`.server` serves the
page (``page/``) on the loopback interface behind a random token. The server's libraries
(starlette, uvicorn, websockets, watchfiles: the ``view`` extra) are imported only here.
"""
