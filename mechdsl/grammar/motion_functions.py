"""The functions of points and bodies that output expressions may call, written out as
expressions of the output quantities (``rod.x``, ``lever.O.vy``, ...) so that the compiler
evaluates them and derives their rates like any named output.

With r, v, a, phi', phi'' a body's frame origin, its velocity and acceleration and its
angular velocity and acceleration, d = P - r_B, perp(x, y) = (-y, x), all in world axes:

* ``distance(P, Q)`` = |P - Q|.
* ``ic_x(A, B)``, ``ic_y(A, B)``: the instant centre of body A relative to body B (B may be
  ``ground``), the point where A's and B's velocity fields agree:
  (phi'_A - phi'_B) perp(I) = c, c = v_B - v_A + phi'_A perp(r_A) - phi'_B perp(r_B), so
  I = (c_y, -c_x) / (phi'_A - phi'_B); relative to the ground, I = r_A + perp^-1(-v_A) / phi'_A
  = (x_A - vy_A / phi'_A, y_A + vx_A / phi'_A). Infinite where A translates relative to B.
  Its path over the run is the fixed (B = ground) or the moving centrode.
* ``transmission(P, Q, R)``: the angle at Q between Q -> P and Q -> R, in [0, pi]:
  atan2(|u x w|, u . w), u = P - Q, w = R - Q; for a four-bar, ``transmission(coupler.A,
  coupler.B, rocker.O)`` is the transmission angle mu between the coupler and the rocker.
* ``rel_vx(P, B)``, ``rel_vy(P, B)``: the velocity of point P relative to body B, v_P minus
  the velocity of the point of B where P is: v_rel = v_P - (v_B + phi'_B perp(d)).
* ``rel_ax(P, B)``, ``rel_ay(P, B)``: its acceleration relative to B (Coriolis' theorem):
  a_rel = a_P - (a_B + phi''_B perp(d) - phi'_B^2 d) - 2 phi'_B perp(v_rel).

The mechanical advantage needs no function: a velocity ratio is a quotient of rates
(``rocker.omega / crank.omega``), a force ratio one of loads (``load.fy / motor.torque``).
"""

from __future__ import annotations

from typing import Callable

from ..errors import MechError
from . import expr as E
from .model import GROUND

#: name -> (argument kinds, the text of a call for a message)
SIGNATURES: dict[str, tuple[tuple[str, ...], str]] = {
    "distance": (("point", "point"), "distance(lever.O, block.origin)"),
    "ic_x": (("body", "body"), "ic_x(rod, ground)"),
    "ic_y": (("body", "body"), "ic_y(rod, ground)"),
    "transmission": (("point", "point", "point"),
                     "transmission(coupler.A, coupler.B, rocker.O)"),
    "rel_vx": (("point", "body"), "rel_vx(slider.origin, crank)"),
    "rel_vy": (("point", "body"), "rel_vy(slider.origin, crank)"),
    "rel_ax": (("point", "body"), "rel_ax(slider.origin, crank)"),
    "rel_ay": (("point", "body"), "rel_ay(slider.origin, crank)"),
}


def _arg(a: E.Expr, kind: str) -> E.Name | None:
    """A point (``body.P``) or a body (``rod``, ``ground``) written as an argument."""
    if not isinstance(a, E.Name):
        return None
    dots = a.id.count(".")
    return a if (kind == "point" and dots == 1) or (kind == "body" and dots == 0) else None


def _q(ref: E.Name, quantity: str) -> E.Expr:
    """A quantity of a point or body; the ground's frame is fixed at the origin (its own
    quantities are 0; a ground point's position is its coordinates)."""
    if ref.id == GROUND:
        return E.Num(0.0)
    if ref.id.startswith(GROUND + ".") and quantity not in ("x", "y"):
        return E.Num(0.0)
    return E.Name(f"{ref.id}.{quantity}", ref.span)


def _ic(A: E.Name, B: E.Name, axis: str) -> E.Expr:
    dw = E.sub(_q(A, "omega"), _q(B, "omega"))
    # c = v_B - v_A + w_A perp(r_A) - w_B perp(r_B), perp(x, y) = (-y, x)
    cx = E.add(E.sub(_q(B, "vx"), _q(A, "vx")),
               E.sub(E.mul(_q(B, "omega"), _q(B, "y")), E.mul(_q(A, "omega"), _q(A, "y"))))
    cy = E.add(E.sub(_q(B, "vy"), _q(A, "vy")),
               E.sub(E.mul(_q(A, "omega"), _q(A, "x")), E.mul(_q(B, "omega"), _q(B, "x"))))
    return E.div(cy, dw) if axis == "x" else E.div(E.neg(cx), dw)


def _transmission(P: E.Name, Q: E.Name, R: E.Name) -> E.Expr:
    ux, uy = E.sub(_q(P, "x"), _q(Q, "x")), E.sub(_q(P, "y"), _q(Q, "y"))
    wx, wy = E.sub(_q(R, "x"), _q(Q, "x")), E.sub(_q(R, "y"), _q(Q, "y"))
    cross = E.sub(E.mul(ux, wy), E.mul(uy, wx))
    dot = E.add(E.mul(ux, wx), E.mul(uy, wy))
    return E.call("atan2", E.call("abs", cross), dot)


def _relative_velocity(P: E.Name, B: E.Name) -> tuple[E.Expr, E.Expr]:
    dx, dy = E.sub(_q(P, "x"), _q(B, "x")), E.sub(_q(P, "y"), _q(B, "y"))
    w = _q(B, "omega")
    return (E.sub(_q(P, "vx"), E.sub(_q(B, "vx"), E.mul(w, dy))),
            E.sub(_q(P, "vy"), E.add(_q(B, "vy"), E.mul(w, dx))))


def _relative_acceleration(P: E.Name, B: E.Name) -> tuple[E.Expr, E.Expr]:
    dx, dy = E.sub(_q(P, "x"), _q(B, "x")), E.sub(_q(P, "y"), _q(B, "y"))
    w, al = _q(B, "omega"), _q(B, "alpha")
    w2 = E.mul(w, w)
    vx, vy = _relative_velocity(P, B)
    two_w = E.mul(E.Num(2.0), w)
    # a_P - (a_B + al perp(d) - w^2 d) - 2 w perp(v_rel), perp(v) = (-vy, vx)
    ax = E.sub(E.sub(_q(P, "ax"), E.sub(E.sub(_q(B, "ax"), E.mul(al, dy)), E.mul(w2, dx))),
              E.mul(two_w, E.neg(vy)))
    ay = E.sub(E.sub(_q(P, "ay"), E.sub(E.add(_q(B, "ay"), E.mul(al, dx)), E.mul(w2, dy))),
              E.mul(two_w, vx))
    return ax, ay


_WRITERS: dict[str, Callable[..., E.Expr]] = {
    "distance": lambda P, Q: E.call("sqrt", E.add(
        E.power(E.sub(_q(P, "x"), _q(Q, "x")), E.Num(2.0)),
        E.power(E.sub(_q(P, "y"), _q(Q, "y")), E.Num(2.0)))),
    "ic_x": lambda A, B: _ic(A, B, "x"),
    "ic_y": lambda A, B: _ic(A, B, "y"),
    "transmission": _transmission,
    "rel_vx": lambda P, B: _relative_velocity(P, B)[0],
    "rel_vy": lambda P, B: _relative_velocity(P, B)[1],
    "rel_ax": lambda P, B: _relative_acceleration(P, B)[0],
    "rel_ay": lambda P, B: _relative_acceleration(P, B)[1],
}


def expand(e: E.Call) -> E.Expr:
    """The call ``e`` of one of :data:`SIGNATURES` written out (module docstring); a
    MechError located at the call where its arguments are not the points and bodies it
    takes."""
    kinds, example = SIGNATURES[e.func]
    args = [_arg(a, k) for a, k in zip(e.args, kinds)]
    if len(e.args) != len(kinds) or any(a is None for a in args):
        what = " and ".join(f"a {k}" for k in kinds) if len(set(kinds)) > 1 else \
            f"{('two', 'three')[len(kinds) - 2]} {'bodies' if kinds[0] == 'body' else 'points'}"
        raise MechError(f"{e.func}() takes {what}, such as {example}", e.span)
    return _WRITERS[e.func](*args)
