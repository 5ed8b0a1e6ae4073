"""Safe, vectorized scalar expressions of space and time used in scene files.

A scene value may be a number or a string such as ``"0.005*min(4*t/T, 1)"``. Strings are
parsed once with :mod:`ast`; only arithmetic, comparisons, the names ``x``, ``y``, ``z``, ``t``,
named scene parameters and a fixed set of NumPy functions are allowed. Nothing is passed to
``eval`` and no attribute access or call of an unknown name is possible.
"""

from __future__ import annotations

import ast
import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["Expression", "ExpressionError", "compile_expression", "function_signatures",
           "reserved_names"]

#: Variables every expression may use: coordinates (m) and time (s); ``z`` is 0 in 2D scenes.
VARIABLES = ("x", "y", "z", "t")
#: The coordinates among :data:`VARIABLES`, in the order of the columns of evaluation points.
COORDINATES = ("x", "y", "z")

def _analytic_functions() -> dict[str, Callable]:
    """Exact fields of ``poromech.analytic`` usable in expressions.

    The plane-strain displacements around Sneddon's and the inclined crack, and Mandel's pressure
    and vertical displacement (``k`` is the mobility k/η, m²/(Pa s); ``t`` a time).
    """
    from poromech import analytic

    def sneddon(k):
        return lambda x, y, a, p, E, nu: analytic.sneddon_displacement(x, y, a, p, E, nu)[k]

    def inclined(k):
        return lambda x, y, b, psi, s, F, E, nu: analytic.inclined_crack_displacement(
            x, y, b, psi, s, F, E, nu)[k]

    def mandel(field):
        def evaluate(s, t, a, F, E, nu, biot, M, k):
            c = analytic.mandel_parameters(E, nu, biot, M, k, a, F)
            s, t = np.broadcast_arrays(np.asarray(s, dtype=np.float64),
                                       np.asarray(t, dtype=np.float64))
            out = np.empty(s.shape)
            for time in np.unique(t):  # one time in a scene's expressions
                at = t == time
                out[at] = field(s[at], float(time), c)
            return out
        return evaluate

    return {
        "sneddon_ux": sneddon(0),
        "sneddon_uy": sneddon(1),
        "inclined_crack_ux": inclined(0),
        "inclined_crack_uy": inclined(1),
        "mandel_p": mandel(analytic.mandel_pressure),
        "mandel_uz": mandel(analytic.mandel_displacement_z),
    }


_FUNCTIONS: dict[str, Callable] = {
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "arcsin": np.arcsin,
    "arccos": np.arccos,
    "arctan": np.arctan,
    "arctan2": np.arctan2,
    "sinh": np.sinh,
    "cosh": np.cosh,
    "tanh": np.tanh,
    "exp": np.exp,
    "log": np.log,
    "log10": np.log10,
    "sqrt": np.sqrt,
    "abs": np.abs,
    "min": np.minimum,
    "max": np.maximum,
    "where": np.where,
    "clip": np.clip,
    "hypot": np.hypot,
    "radians": np.radians,
    "degrees": np.degrees,
}
_FUNCTIONS.update(_analytic_functions())
_CONSTANTS = {"pi": math.pi, "e": math.e}

#: Arguments each function takes (the NumPy ufuncs' and the analytic fields' signatures).
_ARITY = {name: 1 for name in _FUNCTIONS}
_ARITY.update(arctan2=2, min=2, max=2, hypot=2, where=3, clip=3, sneddon_ux=6, sneddon_uy=6,
              inclined_crack_ux=8, inclined_crack_uy=8, mandel_p=9, mandel_uz=9)
_SIGNATURES = {
    "arctan2": "arctan2(y, x)", "min": "min(a, b)", "max": "max(a, b)", "hypot": "hypot(a, b)",
    "where": "where(condition, a, b)", "clip": "clip(a, lo, hi)",
    "sneddon_ux": "sneddon_ux(x, y, a, p, E, nu)", "sneddon_uy": "sneddon_uy(x, y, a, p, E, nu)",
    "inclined_crack_ux": "inclined_crack_ux(x, y, b, psi, sigma, F, E, nu)",
    "inclined_crack_uy": "inclined_crack_uy(x, y, b, psi, sigma, F, E, nu)",
    "mandel_p": "mandel_p(x, t, a, F, E, nu, b, M, k)",
    "mandel_uz": "mandel_uz(z, t, a, F, E, nu, b, M, k)",
}


def reserved_names() -> frozenset[str]:
    """Names a scene parameter may not take: the variables, constants and functions."""
    return frozenset(VARIABLES) | frozenset(_CONSTANTS) | frozenset(_FUNCTIONS)


def function_signatures() -> list[str]:
    """The functions an expression may call, as ``name(arguments)`` (for documentation)."""
    return [_SIGNATURES.get(name, f"{name}(a)") for name in _FUNCTIONS]


#: Longest expression text, and deepest nesting of its syntax tree (``a+a+...`` of n terms is
#: n deep): the tree is checked and evaluated recursively.
MAX_LENGTH = 10_000
MAX_DEPTH = 500

_BINOPS = {
    ast.Add: np.add,
    ast.Sub: np.subtract,
    ast.Mult: np.multiply,
    ast.Div: np.divide,
    ast.Pow: np.power,
    ast.Mod: np.mod,
}
_CMPOPS = {
    ast.Lt: np.less,
    ast.LtE: np.less_equal,
    ast.Gt: np.greater,
    ast.GtE: np.greater_equal,
    ast.Eq: np.equal,
    ast.NotEq: np.not_equal,
}


@functools.lru_cache(maxsize=256)
def _parse(source: str) -> ast.Expression:
    """Parse an expression once; the tree is cached by its text."""
    return ast.parse(source, mode="eval")


class ExpressionError(ValueError):
    """An expression string that cannot be parsed or uses a forbidden construct."""


def _short(text: str) -> str:
    """The expression text for a message, shortened."""
    return repr(text) if len(text) <= 60 else repr(text[:57] + "...")


def _depth(tree: ast.AST) -> int:
    """Depth of a syntax tree (iterative: the tree may be deeper than Python's recursion)."""
    deepest, stack = 0, [(tree, 1)]
    while stack:
        node, d = stack.pop()
        deepest = max(deepest, d)
        stack.extend((child, d + 1) for child in ast.iter_child_nodes(node))
    return deepest


def _check(node: ast.AST, names: set[str]) -> None:
    """Reject every syntax element outside the allowed subset."""
    if isinstance(node, ast.Expression):
        _check(node.body, names)
    elif isinstance(node, ast.Constant):
        if not isinstance(node.value, int | float) or isinstance(node.value, bool):
            raise ExpressionError(f"constant {node.value!r} is not a number")
    elif isinstance(node, ast.Name):
        if node.id not in names and node.id not in _CONSTANTS:
            allowed = ", ".join(sorted(names | set(_CONSTANTS)))
            raise ExpressionError(f"unknown name '{node.id}' (allowed: {allowed})")
    elif isinstance(node, ast.BinOp):
        if type(node.op) not in _BINOPS:
            raise ExpressionError(f"operator {type(node.op).__name__} is not allowed")
        _check(node.left, names)
        _check(node.right, names)
    elif isinstance(node, ast.UnaryOp):
        if not isinstance(node.op, ast.UAdd | ast.USub):
            raise ExpressionError(f"operator {type(node.op).__name__} is not allowed")
        _check(node.operand, names)
    elif isinstance(node, ast.Compare):
        if any(type(op) not in _CMPOPS for op in node.ops):
            raise ExpressionError("only <, <=, >, >=, ==, != comparisons are allowed")
        _check(node.left, names)
        for c in node.comparators:
            _check(c, names)
    elif isinstance(node, ast.BoolOp):
        for v in node.values:
            _check(v, names)
    elif isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCTIONS:
            fname = ast.unparse(node.func)
            raise ExpressionError(
                f"function '{fname}' is not allowed (allowed: {', '.join(sorted(_FUNCTIONS))})"
            )
        if node.keywords:
            raise ExpressionError("keyword arguments are not allowed")
        name, nargs = node.func.id, len(node.args)
        if nargs != _ARITY[name] or any(isinstance(a, ast.Starred) for a in node.args):
            usage = _SIGNATURES.get(name, f"{name}(a)")
            raise ExpressionError(f"function '{name}' takes {_ARITY[name]} argument"
                                  f"{'s' if _ARITY[name] > 1 else ''}, not {nargs}: {usage}")
        for a in node.args:
            _check(a, names)
    else:
        raise ExpressionError(f"'{type(node).__name__}' is not allowed in an expression")


def _evaluate(node: ast.AST, env: Mapping[str, object]):
    """Evaluate a checked syntax tree with NumPy semantics."""
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, env)
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        return env[node.id] if node.id in env else _CONSTANTS[node.id]
    if isinstance(node, ast.BinOp):
        return _BINOPS[type(node.op)](_evaluate(node.left, env), _evaluate(node.right, env))
    if isinstance(node, ast.UnaryOp):
        v = _evaluate(node.operand, env)
        return np.negative(v) if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.Compare):
        left = _evaluate(node.left, env)
        result = True
        for op, comp in zip(node.ops, node.comparators, strict=True):
            right = _evaluate(comp, env)
            result = np.logical_and(result, _CMPOPS[type(op)](left, right))
            left = right
        return result
    if isinstance(node, ast.BoolOp):
        combine = np.logical_and if isinstance(node.op, ast.And) else np.logical_or
        values = [_evaluate(v, env) for v in node.values]
        out = values[0]
        for v in values[1:]:
            out = combine(out, v)
        return out
    if isinstance(node, ast.Call):
        return _FUNCTIONS[node.func.id](*[_evaluate(a, env) for a in node.args])
    raise AssertionError("unchecked node")  # pragma: no cover


@dataclass(frozen=True)
class Expression:
    """A scalar field ``f(x, y, z, t)`` given by a number or a checked expression string.

    Evaluated at points ``(n, d)`` (``d`` = 1, 2 or 3 columns ``x, y, z``; a missing coordinate
    is 0) and a time.

    Attributes:
        source: The text as written in the scene (or the number).
        parameters: Named constants the expression may use.
    """

    source: str | float
    parameters: tuple[tuple[str, float], ...] = ()

    @property
    def is_constant(self) -> bool:
        """True when the value does not depend on x, y, z or t."""
        if not isinstance(self.source, str):
            return True
        tree = _parse(self.source)
        return not any(isinstance(n, ast.Name) and n.id in VARIABLES for n in ast.walk(tree))

    @property
    def is_uniform(self) -> bool:
        """True when the value does not depend on x, y or z (it may depend on t)."""
        if not isinstance(self.source, str):
            return True
        tree = _parse(self.source)
        return not any(isinstance(n, ast.Name) and n.id in COORDINATES for n in ast.walk(tree))

    @property
    def depends_on_time(self) -> bool:
        """True when the expression uses ``t``."""
        if not isinstance(self.source, str):
            return False
        tree = _parse(self.source)
        return any(isinstance(n, ast.Name) and n.id == "t" for n in ast.walk(tree))

    def __call__(self, points: npt.ArrayLike, t: float = 0.0) -> npt.NDArray[np.float64]:
        """Values at points ``(n, d)`` and time ``t``: an array of ``n`` values.

        A DOLFINx interpolation passes ``x`` of shape ``(3, n)``: give ``x.T``.
        """
        points = np.asarray(points, dtype=np.float64)
        n = points.shape[0]
        if not isinstance(self.source, str):
            return np.full(n, float(self.source))
        env = dict(self.parameters)
        for k, name in enumerate(COORDINATES):
            env[name] = points[:, k] if k < points.shape[1] else np.zeros(n)
        env["t"] = float(t)
        try:
            with np.errstate(all="ignore"):
                value = _evaluate(_parse(self.source), env)
        except ExpressionError:
            raise
        except (ValueError, ArithmeticError, TypeError) as err:  # an exact field's own checks
            why = " ".join(str(err).split()) or type(err).__name__
            raise ExpressionError(f"cannot be evaluated ({type(err).__name__}: {why[:120]}; "
                                  "the parameters of an exact field must be constants, in "
                                  "its range)") from None
        return np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()

    def value(self, t: float = 0.0) -> float:
        """The value of a space-independent expression at time ``t``."""
        return float(self(np.zeros((1, 2)), t)[0])


def compile_expression(
    source: str | float | int, parameters: Mapping[str, float] | None = None
) -> Expression:
    """Check an expression and return it as an :class:`Expression`.

    Args:
        source: A number or an expression string in ``x``, ``y``, ``z``, ``t`` and parameters.
        parameters: Named constants (scene ``parameters:``) the expression may use.

    Raises:
        ExpressionError: The string is not a valid expression.
    """
    params = tuple(sorted((parameters or {}).items()))
    if isinstance(source, bool):
        raise ExpressionError("a boolean is not a number")
    if isinstance(source, int | float):
        return Expression(float(source), params)
    if not isinstance(source, str):
        raise ExpressionError(f"expected a number or an expression string, got "
                              f"{type(source).__name__}")
    text = source.strip()
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"the expression has {len(text)} characters (at most "
                              f"{MAX_LENGTH}): use parameters or a simpler formula")
    try:
        tree = _parse(text)
    except SyntaxError as err:
        raise ExpressionError(f"cannot parse {_short(text)}: {err.msg}") from None
    except (RecursionError, MemoryError):
        raise ExpressionError(f"{_short(text)} is nested too deeply to parse") from None
    if _depth(tree) > MAX_DEPTH:
        raise ExpressionError(f"{_short(text)} is nested more than {MAX_DEPTH} levels deep "
                              "(e.g. a sum of that many terms): use parameters or a simpler "
                              "formula")
    _check(tree, set(VARIABLES) | {k for k, _ in params})
    expr = Expression(source.strip(), params)
    sample = expr(np.array([[0.3, 0.7, 0.2]]), 0.5)
    if sample.shape != (1,):
        raise ExpressionError(f"{source!r} does not evaluate to a scalar field")
    return expr
