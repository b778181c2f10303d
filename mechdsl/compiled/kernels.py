"""The code generated for a compiled model, held apart from its data.

A :class:`~mechdsl.compiled.system.System` is plain, read-only data: index maps, the
sparsity pattern, per-variant values, the output columns and the drawing's geometry. What
runs on it is here: the traced expression graphs of Phi, Phi_q, gamma and of the masses and
loads with the kernels generated from them (:mod:`.fused`, :mod:`.dynamics`), the drives'
f(t), f'(t), f''(t), the output expressions, and the plans made from them on first use (the
generated sparse LU, the code on Python floats, the numba module). MuJoCo keeps its model
(``mjModel``) apart from what changes in a run (``mjData``); here, too, the model's data is
apart from the code made for it, and the solvers keep their state in run objects of their
own. A :class:`Kernels` knows its System (``kernels.system``); a System knows no code.

The solvers take a Kernels: they read the data through ``kernels.system`` and call the code.
Drawings, exports and stores take the System alone.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable, Mapping

import numpy as np

from ..grammar import expr as E
from .lu import MAX_N, LUPlan, plan
from .system import System

if TYPE_CHECKING:  # (imported by compile.py, which builds them)
    from .dynamics import Dynamics
    from .fused import Fused


@dataclass(frozen=True)
class DriveFunction:
    """f(t), f'(t), f''(t) of one drive, compiled, with the trees they came from."""

    f: Callable
    fd: Callable
    fdd: Callable
    exprs: tuple[E.Expr, E.Expr, E.Expr]


@dataclass(frozen=True)
class Kernels:
    """The code that evaluates ``system``'s equations (see the module documentation)."""

    system: System
    #: the compiled evaluation of Phi, Phi_q, gamma (:mod:`mechdsl.compiled.fused`)
    fused: Fused | None = None
    #: masses and loads (:mod:`mechdsl.compiled.dynamics`), where the model has any
    dynamics: Dynamics | None = None
    #: per drive row (``system.drive_rows``), f, f', f''
    drive_functions: tuple[DriveFunction, ...] = ()
    #: per expression output (:class:`~mechdsl.compiled.system.ExprOutput`), by label: its
    #: function of the params, ``t`` and its inputs
    expressions: Mapping[str, Callable] = field(default_factory=dict)
    #: per reduction (:class:`~mechdsl.compiled.system.ReductionOutput`), by label
    reductions: Mapping[str, Callable] = field(default_factory=dict)
    #: the code of ``system.start.system`` (the model with its ``initial`` statements)
    start: "Kernels | None" = None
    #: the kernels whose traced code this one runs with other values (compile_model's
    #: ``reuse``): its plans (the LU, the code on floats) serve this one too
    template: "Kernels | None" = field(default=None, repr=False, compare=False)

    def with_system(self, system: System) -> "Kernels":
        """The same code for ``system`` (the same model with other values, e.g. one
        variant)."""
        return replace(self, system=system)

    def variant(self, v: int) -> "Kernels":
        """The kernels of sweep variant ``v`` alone, on the System of that variant."""
        f, d = self.fused, self.dynamics
        return replace(self, system=self.system.variant(v),
                       fused=None if f is None else f.variant(v),
                       dynamics=None if d is None else d.variant(v))

    @functools.cached_property
    def lu(self) -> LUPlan | None:
        """The generated sparse LU of Phi_q (square systems), its pivot order chosen on the
        Jacobian at the first variant's guess (:mod:`mechdsl.compiled.lu`); None where that
        Jacobian is singular in its pattern. Kernels with a ``template`` take the
        template's (the same pattern and code: a pivot that becomes small for these values
        falls back to partial pivoting, as one does over a run)."""
        if self.template is not None:
            return self.template.lu
        s, f = self.system, self.fused
        if f is None or s.m != s.n or not 0 < s.n <= MAX_N:
            return None
        sample = f.evaluate_jac(s.guess[:, None, :])[0, 0]
        # the member layout's entries are one node each: those that are constants fold
        constants = ({k: float(d.value) for k, d in enumerate(f.jac_nodes)
                      if d.op == "const" and np.isfinite(float(d.value))}
                     if f.layout == "member" else None)
        return plan(f.rows, f.cols, s.n, sample, constants)

    @functools.cached_property
    def native(self):
        """The compiled module of this model (:mod:`mechdsl.compiled.native`: numba
        imported, the march compiled or loaded from the disk cache), or None where the
        backend does not apply or numba is missing. Loaded on first use only."""
        from . import native

        return native.load(self)

    @functools.cached_property
    def one_state(self):
        """A single mechanism's model as code on Python floats, for the steps of a solve that
        see one state at a time (:mod:`mechdsl.compiled.scalar`); None for a sweep, or where
        it does not apply."""
        if self.system.n_variants != 1:
            return None
        from .scalar import with_values

        if self.template is not None:
            one = self.template.state_code
            return None if one is None else with_values(one, self.fused)
        return self.state_code

    @functools.cached_property
    def state_code(self):
        """:attr:`one_state` of the first variant whatever the number of variants: the code
        kernels made as a template (compile_model's ``reuse``) lend to those that run it
        with other values."""
        from .scalar import one_state

        return one_state(self, 0)

    @functools.cached_property
    def curvature(self):
        """The constraints' second derivatives as code on floats
        (:func:`mechdsl.compiled.curvature.curvature`; None where they are linear),
        generated on first use, once per model."""
        from .curvature import curvature

        return curvature(self)

    @functools.cached_property
    def scalar_kernels(self):
        """The forward dynamics' one-state kernels on floats
        (:func:`mechdsl.symbolic.codegen.scalar_kernel`): ``(phi_jac, motion, fixed)``.
        ``phi_jac`` gives Phi and Phi_q's entries. ``motion`` gives the entries of the
        augmented matrix [M Phi_q^T; Phi_q 0] in the order they are stored (Phi_q's entries,
        Phi_q^T's, M's) except the constant ones, then its right-hand side [Q; gamma];
        ``fixed`` holds, over that order, the value of each constant entry and NaN where
        ``motion`` gives it (a constant is stored once, not at every evaluation). None
        where the model is traced type by type (the group layout) or has no masses."""
        from ..symbolic.codegen import joint_scalar_kernel, scalar_kernel

        f, d = self.fused, self.dynamics
        t = self.template
        if t is not None and d is not None and t.dynamics is not None \
                and d.graph is t.dynamics.graph:
            return t.scalar_kernels
        if f is None or d is None or f.layout != "member" or d.graph is None:
            return None
        nodes = [*f.jac_nodes, *f.gamma_nodes, *d.mass_nodes, *d.load_nodes]
        nnz, m, n_mass = len(f.jac_nodes), len(f.gamma_nodes), len(d.mass_nodes)
        jac, mass = range(nnz), range(nnz + m, nnz + m + n_mass)
        matrix = [*jac, *jac, *mass]
        fixed = np.array([float(nodes[k].value) if nodes[k].op == "const" else np.nan
                          for k in matrix], dtype=float)
        rhs = [*range(nnz + m + n_mass, len(nodes)), *range(nnz, nnz + m)]
        order = [k for k, c in zip(matrix, fixed) if np.isnan(c)] + rhs
        return (scalar_kernel(f.graph, [*f.phi_nodes, *f.jac_nodes], "phi_jac"),
                joint_scalar_kernel([(f.graph, [*f.jac_nodes, *f.gamma_nodes]),
                                     (d.graph, [*d.mass_nodes, *d.load_nodes])], "motion",
                                    order=order), fixed)
