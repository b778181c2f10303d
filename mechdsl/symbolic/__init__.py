"""Equations as expression graphs: traced from plain arithmetic, differentiated exactly, and
compiled into one straight-line function (:mod:`.graph`, :mod:`.codegen`)."""

from .codegen import Kernel, kernel
from .graph import Graph, GraphError, Node

__all__ = ["Graph", "GraphError", "Node", "Kernel", "kernel"]
