"""The compiled model: a mechanism resolved to index maps, one generated evaluation of all its
constraints and the plan of its factorisation; it imports nothing from the solver."""
