"""The compiled model: a mechanism resolved to index maps, one generated evaluation of all its
constraints and the plan of its factorisation; it imports nothing from the solver.

:mod:`.compile` resolves a model against the plugins (the files it names read by
:mod:`.files`, every number evaluated for every sweep variant by :mod:`.variants`) into a
:class:`~.system.System`, whose equations :mod:`.equations` evaluates; :mod:`.shapes` gives
the bodies' shapes and mass properties."""
