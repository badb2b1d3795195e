"""A hub torque written as a formula: a cogging torque, a cable's pull, a spring, stated in a rig
file and identified with the physics.

The formula is text (``"a*sin(8*theta) + b*theta"``) over the hub angle ``theta`` (rad), the hub
velocity ``omega`` (rad/s), the drive's input ``u`` (the record's input column, in the drive's
unit) and the time ``t`` (s from the record's first sample), and over parameters declared with a
reference value and bounds. It is read by SymPy from a vetted list of tokens (numbers,
operators, the variables, the declared parameters and the functions of :data:`FUNCTIONS`; no
``eval`` of anything else) and compiled to JAX with :mod:`sympy2jax`, so the simulator
differentiates and vmaps through it. The effect keeps only the text and the parameters' specs
(static, hashable); the compiled form is built once per formula and cached.

The simulator holds the input constant over each step and steps the state-dependent forces
explicitly, so the formula is split into its additive terms: those in ``theta`` and ``omega``
act as a position-dependent load on the hub (:meth:`AbstractEffect.loads`, as gravity does);
those in ``u``, ``t`` and the parameters alone join the drive's torque on the integrator's grid
(:meth:`AbstractEffect.signal_torque`). A term that mixes the state with ``u`` or ``t`` is
refused.
"""

from __future__ import annotations

import functools
import io
import keyword
import math
import tokenize
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import sympy
import sympy2jax
from jaxtyping import Array, Float
from sympy.parsing.sympy_parser import parse_expr, standard_transformations

from jaxflex.effects._base import AbstractEffect, Structure
from jaxflex.parameters import BASE_PARAMETERS, ParameterSpec, Params

STATE: tuple[str, ...] = ("theta", "omega")
"""The state variables a formula may use: hub angle (rad) and hub velocity (rad/s)."""
SIGNAL: tuple[str, ...] = ("u", "t")
"""The input variables: the drive's input (its own unit) and time (s)."""
VARIABLES: tuple[str, ...] = STATE + SIGNAL
_WHERE = sympy.Function("where")
FUNCTIONS: dict[str, Any] = {
    "sin": sympy.sin, "cos": sympy.cos, "tan": sympy.tan, "asin": sympy.asin,
    "acos": sympy.acos, "atan": sympy.atan, "atan2": sympy.atan2, "sinh": sympy.sinh,
    "cosh": sympy.cosh, "tanh": sympy.tanh, "asinh": sympy.asinh, "atanh": sympy.atanh,
    "exp": sympy.exp, "log": sympy.log, "sqrt": sympy.sqrt, "abs": sympy.Abs, "Abs": sympy.Abs,
    "sign": sympy.sign, "Max": sympy.Max, "Min": sympy.Min, "max": sympy.Max, "min": sympy.Min,
    "floor": sympy.floor, "ceiling": sympy.ceiling, "erf": sympy.erf,
    "Piecewise": sympy.Piecewise, "pi": sympy.pi, "True": sympy.true, "False": sympy.false,
}
"""The names a formula may call (SymPy's functions that :mod:`sympy2jax` compiles, and
``Piecewise((value, condition), ..., (value, True))``) and the constants ``pi``, True, False."""
_OPERATORS = frozenset("+ - * / ** ( ) , < > <= >= & | ~".split())
_NUMBERS = {"Integer": sympy.Integer, "Float": sympy.Float, "Rational": sympy.Rational}
RESERVED: frozenset[str] = frozenset(VARIABLES) | {p.name for p in BASE_PARAMETERS} | set(
    FUNCTIONS) | set(_NUMBERS)
"""Names a formula's parameter may not take: its variables, the base parameters, functions."""


class FormulaError(ValueError):
    """A formula or its parameters are wrong; the one-line message names the key at fault
    (``expression``, or the parameter)."""


Bounds = tuple[str, float, float, float, str, bool]
"""One declared parameter: name, reference, lower, upper, unit, log scale."""


class _Parameters:
    """``parameters``: the declared parameters' specs (none on the class: it declares none)."""

    def __get__(self, instance: FormulaTorque | None, owner: type) -> tuple[ParameterSpec, ...]:
        return () if instance is None else instance.specs()


class FormulaTorque(AbstractEffect):
    """A torque (N m) at the hub given by ``expression``, in the sign of the drive's torque.

    ``FormulaTorque("a*sin(6*theta)", parameters={"a": (0.0, -0.05, 0.05)}, name="cogging")``:
    each parameter is ``(reference, lower, upper)`` or a table of ``reference``, ``lower``,
    ``upper`` and optionally ``unit`` (default ``"N m"``) and ``log_scale`` (default false).
    Every free name of the expression is a variable (:data:`VARIABLES`) or a declared parameter,
    and every declared parameter is used. Where the formula vanishes with all its parameters at
    zero, zero is each parameter's null (a score test can judge the effect); otherwise it has
    none. ``name`` is the effect's name in models, fits and reports (default ``"torque"``).
    """

    expression: str = eqx.field(static=True, default="")
    bounds: tuple[Bounds, ...] = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="torque")  # type: ignore[assignment]

    needs_declaration: ClassVar[bool] = True
    description: ClassVar[str] = (
        "A torque at the hub written as a formula of the hub angle, its velocity, the drive's "
        "input and time, with declared parameters identified with the physics: a motor's "
        "cogging, a cable's pull, a spring returning the hub, a torque the library lacks."
    )
    signature: ClassVar[str] = "whatever the formula describes"

    parameters = _Parameters()  # type: ignore[assignment]

    def __init__(
        self,
        expression: str,
        parameters: Mapping[str, Any] = MappingProxyType({}),
        name: str = "torque",
        *,
        bounds: tuple[Bounds, ...] | None = None,
    ) -> None:
        if not isinstance(parameters, Mapping):
            raise FormulaError(f"parameters: expected a mapping of name to (reference, lower, "
                               f"upper), got {type(parameters).__name__}")
        self.expression = expression
        self.name = name
        self.bounds = _bounds(dict(parameters)) if bounds is None else tuple(bounds)

    def __check_init__(self) -> None:
        if not (isinstance(self.name, str) and self.name.isidentifier()):
            raise FormulaError(f"name: {self.name!r} must be an identifier (the effect's name "
                               "in fits and reports)")
        from jaxflex.effects import EFFECTS  # (the registry imports this module)

        if self.name != type(self).name and self.name.partition(":")[0] in EFFECTS:
            raise FormulaError(f"name: {self.name!r} is a library effect's name; name the "
                               "formula otherwise")
        if not isinstance(self.expression, str) or not self.expression.strip():
            raise FormulaError(f"expression: expected a formula (text), got "
                               f"{self.expression!r}")
        for name, reference, lower, upper, _, _ in self.bounds:
            _check_bounds(name, reference, lower, upper)
        _compiled(self.expression, self.names)

    def specs(self) -> tuple[ParameterSpec, ...]:
        """The declared parameters as specs: null 0 where the formula vanishes with every
        parameter at zero (and the parameter is not log-scaled), else none."""
        null = 0.0 if _compiled(self.expression, self.names).vanishes else None
        return tuple(
            ParameterSpec(name, unit, lower, upper, reference,
                          f"parameter of {self.name}: {self.expression}", log_scale=log,
                          null=None if log else null)
            for name, reference, lower, upper, unit, log in self.bounds
        )

    @property
    def names(self) -> tuple[str, ...]:
        """The declared parameters' names, in declaration order."""
        return tuple(b[0] for b in self.bounds)

    def settings(self) -> dict[str, Any]:
        """The rig-file table (without ``type``): ``name``, ``expression`` and each parameter's
        ``{reference, lower, upper}`` (with ``unit`` and ``log_scale`` where not default)."""
        table: dict[str, Any] = {"name": self.name, "expression": self.expression}
        for name, reference, lower, upper, unit, log in self.bounds:
            table[name] = ({"reference": reference, "lower": lower, "upper": upper}
                           | ({"unit": unit} if unit != "N m" else {})
                           | ({"log_scale": True} if log else {}))
        return table

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> FormulaTorque:
        """The effect a rig file's ``[[effects]]`` table declares (``type`` removed)."""
        settings = dict(settings)
        name = settings.pop("name", "torque")
        if "expression" not in settings:
            raise FormulaError("expression: missing (a formula torque is declared with its "
                               "formula and parameters, e.g. in a rig file's [[effects]] table: "
                               "type = \"torque\", expression = \"a*sin(8*theta)\", a = { "
                               "reference = 0.0, lower = -0.05, upper = 0.05 })")
        expression = settings.pop("expression")
        return cls(expression, settings, name=name)

    def torque(self, params: Params, theta: Array, omega: Array, u: Array, t: Array) -> Array:
        """The formula's value: the whole torque at one state, input and time."""
        compiled = _compiled(self.expression, self.names)
        own = {n: params[n] for n in self.names}
        total = jnp.zeros(jnp.broadcast_shapes(*(jnp.shape(x) for x in (theta, omega, u, t))))
        for part in (compiled.state, compiled.signal):
            if part is not None:
                total = total + part(theta=theta, omega=omega, u=u, t=t, **own)
        return total

    def loads(self, structure: Structure, params: Params) -> Float[Array, "k n"]:
        if _compiled(self.expression, self.names).state is None:
            return jnp.zeros((0, structure.mass.shape[0]))
        return jnp.zeros((1, structure.mass.shape[0])).at[0, 0].set(1.0)  # on the hub alone

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Array:
        state = _compiled(self.expression, self.names).state
        if state is None:
            return super().load_amplitudes(params, angle, velocity)
        own = {n: params[n] for n in self.names}
        value = state(theta=angle, omega=velocity, **own)
        return jnp.broadcast_to(value, jnp.shape(angle))[None]

    def signal_torque(self, params: Params, signal: Float[Array, " m"], h: float) -> Array | None:
        signal_part = _compiled(self.expression, self.names).signal
        if signal_part is None:
            return None
        own = {n: params[n] for n in self.names}
        time = jnp.arange(signal.shape[-1]) * h
        return jnp.broadcast_to(signal_part(u=signal, t=time, **own), jnp.shape(signal))


def _bounds(parameters: dict[str, Any]) -> tuple[Bounds, ...]:
    """The stored form of declared parameters (tuples or rig-file tables)."""
    out = []
    for name, value in parameters.items():
        if not isinstance(name, str) or not name.isidentifier() or keyword.iskeyword(name):
            raise FormulaError(f"{name!r}: a parameter's name must be an identifier")
        if name in RESERVED:
            raise FormulaError(f"{name}: a reserved name (a variable {', '.join(VARIABLES)}, a "
                               "base parameter or a function); name the parameter otherwise")
        if isinstance(value, Mapping):
            extra = sorted(set(value) - {"reference", "lower", "upper", "unit", "log_scale"})
            if extra:
                raise FormulaError(f"{name}: unknown key(s) {extra}; a parameter is "
                                   "{ reference, lower, upper } (optional unit, log_scale)")
            missing = [k for k in ("reference", "lower", "upper") if k not in value]
            if missing:
                raise FormulaError(f"{name}: missing {', '.join(missing)}; a parameter is "
                                   "{ reference = 0.0, lower = -0.1, upper = 0.1 }")
            unit, log = value.get("unit", "N m"), value.get("log_scale", False)
            if not isinstance(unit, str) or not isinstance(log, bool):
                raise FormulaError(f"{name}: unit must be text and log_scale true or false")
            triple = (value["reference"], value["lower"], value["upper"])
        elif isinstance(value, (tuple, list)) and len(value) == 3:
            triple, unit, log = tuple(value), "N m", False
        else:
            raise FormulaError(f"{name}: expected (reference, lower, upper) or a table "
                               f"{{ reference, lower, upper }}, got {value!r}")
        _check_bounds(name, *triple)
        if log and triple[1] <= 0:
            raise FormulaError(f"{name}: log_scale needs a positive lower bound")
        reference, lower, upper = (float(x) for x in triple)
        out.append((name, reference, lower, upper, unit, log))
    return tuple(out)


def _check_bounds(name: str, reference: Any, lower: Any, upper: Any) -> None:
    for label, value in (("reference", reference), ("lower", lower), ("upper", upper)):
        if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value)):
            raise FormulaError(f"{name}.{label}: expected a finite number, got {value!r}")
    if not lower < upper or not lower <= reference <= upper:
        raise FormulaError(f"{name}: bounds [{lower!r}, {upper!r}] must be increasing and "
                           f"hold the reference {reference!r}")


class _Compiled:
    """A formula parsed and compiled: its state and signal parts (None where empty) and
    whether it vanishes with every parameter at zero."""

    def __init__(self, state: Callable | None, signal: Callable | None, vanishes: bool):
        self.state, self.signal, self.vanishes = state, signal, vanishes


def parse_formula(expression: str, parameters: tuple[str, ...]) -> sympy.Expr:
    """``expression`` as a real SymPy expression of the variables and ``parameters``; a
    :class:`FormulaError` (naming ``expression``) for anything else."""
    symbols = {n: sympy.Symbol(n, real=True) for n in (*VARIABLES, *parameters)}
    _vet_tokens(expression, symbols)
    try:
        expr = parse_expr(expression, local_dict={**symbols, **FUNCTIONS},
                          global_dict={"__builtins__": {}, **_NUMBERS},
                          transformations=standard_transformations, evaluate=True)
    except Exception as exc:  # SymPy raises many kinds (TypeError, SympifyError, ...)
        raise FormulaError(f"expression: {expression!r} is not a formula ("
                           f"{' '.join(str(exc).split())[:120] or type(exc).__name__})") from None
    if not isinstance(expr, sympy.Expr) or expr.is_real is False or expr.has(
            sympy.I, sympy.zoo, sympy.nan, sympy.oo):
        raise FormulaError(f"expression: {expression!r} is not a real-valued torque (got "
                           f"{type(expr).__name__} {expr})")
    unused = [n for n in parameters if symbols[n] not in expr.free_symbols]
    if unused:
        raise FormulaError(f"expression: declared parameter(s) {', '.join(unused)} not used in "
                           f"{expression!r}")
    for sign in (1, -1):  # a value at a few points, both signs: e.g. sqrt(theta) is complex
        point = {s: sign * (0.3 + 0.1 * i) for i, s in enumerate(symbols.values())}
        probe = expr.subs(point).evalf()
        if probe.is_number and probe.is_finite is not False and probe.is_real is False:
            shown = ", ".join(f"{k}={v:g}" for k, v in point.items())
            raise FormulaError(f"expression: {expression!r} is not real-valued (at {shown} "
                               f"it is {probe})")
    return expr


def _vet_tokens(expression: str, symbols: Mapping[str, Any]) -> None:
    """Only numbers, operators, known names: what parse_expr then evaluates is harmless."""
    try:
        tokens = list(tokenize.generate_tokens(io.StringIO(expression).readline))
    except (tokenize.TokenError, IndentationError, SyntaxError) as exc:
        raise FormulaError(f"expression: {expression!r} is not a formula ({exc.args[0]})") from None
    for token in tokens:
        if token.type == tokenize.NAME and token.string not in symbols and (
                token.string not in FUNCTIONS):
            known = [n for n in symbols if n not in VARIABLES]
            raise FormulaError(
                f"expression: unknown symbol {token.string!r} (variables: "
                f"{', '.join(VARIABLES)}; parameters: {', '.join(known) or 'none declared'})")
        if token.type == tokenize.OP and token.string not in _OPERATORS:
            raise FormulaError(f"expression: {token.string!r} is not allowed in a formula "
                               f"(operators: {' '.join(sorted(_OPERATORS))})")
        if token.type in (tokenize.STRING, tokenize.ERRORTOKEN) or (
                token.type == tokenize.NUMBER and token.string[-1] in "jJ"):
            raise FormulaError(f"expression: {token.string!r} is not allowed in a formula")


@functools.lru_cache(maxsize=256)
def _compiled(expression: str, parameters: tuple[str, ...]) -> _Compiled:
    """The parsed formula's two parts compiled to JAX (once per formula)."""
    expr = parse_formula(expression, parameters)
    state_names = {sympy.Symbol(n, real=True) for n in STATE}
    signal_names = {sympy.Symbol(n, real=True) for n in SIGNAL}
    state_terms, signal_terms = [], []
    for term in sympy.Add.make_args(expr):
        on_state, on_signal = term.free_symbols & state_names, term.free_symbols & signal_names
        if on_state and on_signal:
            raise FormulaError(
                f"expression: the term {term} mixes the state ({', '.join(STATE)}) with the "
                f"input or time ({', '.join(SIGNAL)}); write the torque as a sum of terms in "
                "one or the other")
        (state_terms if on_state else signal_terms).append(term)
    vanishes = expr.subs({sympy.Symbol(n, real=True): 0 for n in parameters}) == 0
    return _Compiled(_jax(sympy.Add(*state_terms)), _jax(sympy.Add(*signal_terms)),
                     bool(vanishes))


def _jax(expr: sympy.Expr) -> Callable | None:
    """``expr`` as a JAX function of keyword arrays (extra keywords ignored); None for 0."""
    if expr == 0:
        return None
    module = sympy2jax.SymbolicModule(_without_piecewise(expr), make_array=False,
                                      extra_funcs={_WHERE: jnp.where})
    used = {str(s) for s in expr.free_symbols}

    def call(**values: Array) -> Array:
        return module(**{k: v for k, v in values.items() if k in used})

    return call


def _without_piecewise(expr: sympy.Expr) -> sympy.Expr:
    """Each ``Piecewise`` as nested ``where(condition, value, otherwise)`` (NaN where no
    condition holds), which :mod:`sympy2jax` compiles."""

    def nested(*pairs: Any) -> sympy.Expr:
        result: Any = sympy.nan
        for value, condition in reversed(pairs):
            result = value if condition is sympy.true else _WHERE(condition, value, result)
        return result

    return expr.replace(lambda e: isinstance(e, sympy.Piecewise), lambda e: nested(*e.args))


__all__ = ["FUNCTIONS", "RESERVED", "VARIABLES", "FormulaError", "FormulaTorque", "parse_formula"]
