"""Safe arithmetic for a campaign's ``[derived]`` section — parsed with :mod:`ast`, never ``eval``.

An expression such as ``"0.5 * controller.k_p"`` or ``"pi / (2 * 0.035) * controller.gamma / b"``
(the bound of thesis (2.41)) may use numbers, ``+ - * / // % **``, unary signs, parentheses, the
functions in :data:`FUNCTIONS`, the constants ``pi`` and ``e``, the rig's nominal constants
(e.g. ``a``, ``b`` of the DC motor) and dotted keys of the campaign (grid keys, earlier derived
keys, base values). Every node type outside the allow-list is refused when the campaign is
loaded, so a malformed expression fails before anything runs. Numbers are evaluated as floats:
``10 ** 10 ** 10`` overflows at once instead of computing a huge integer.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from labrunner.errors import InvalidParameter

MAX_LENGTH = 400  # characters of one expression
MAX_NODES = 200  # AST nodes of one expression

_BINARY: dict[type, Callable[[float, float], float]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: operator.mod,
    ast.Pow: operator.pow,
}
_UNARY: dict[type, Callable[[float], float]] = {ast.UAdd: operator.pos, ast.USub: operator.neg}

FUNCTIONS: dict[str, Callable[..., float]] = {
    "sqrt": math.sqrt,
    "exp": math.exp,
    "log": math.log,
    "log10": math.log10,
    "sin": math.sin,
    "cos": math.cos,
    "tan": math.tan,
    "atan": math.atan,
    "abs": abs,
    "min": min,
    "max": max,
    "round": round,
}
CONSTANTS: dict[str, float] = {"pi": math.pi, "e": math.e}


def _dotted(node: ast.expr) -> str | None:
    """``a.b.c`` for a Name/Attribute chain, else None."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return ".".join(reversed(parts))
    return None


@dataclass(frozen=True)
class Expression:
    """A validated expression: its source text and the names it reads."""

    field: str
    source: str
    tree: ast.Expression
    names: frozenset[str]

    def evaluate(self, names: Mapping[str, object]) -> float:
        """Value of the expression with ``names`` (dotted key or constant → number); finite float."""
        try:
            value = _eval(self.tree.body, names)
        except (ArithmeticError, ValueError, TypeError) as exc:  # TypeError: complex powers
            raise InvalidParameter(self.field, f"{self.source!r} cannot be evaluated: {exc}") from None
        if not math.isfinite(value):
            raise InvalidParameter(self.field, f"{self.source!r} evaluates to {value!r}, must be finite")
        return value


def parse(field: str, source: object, known: Mapping[str, object] | frozenset[str] | set[str]) -> Expression:
    """Parse and check ``source``: only allow-listed syntax, and every name in ``known`` or a constant.

    ``field`` is the key path used in error messages (``"derived.controller.k_d"``).
    """
    if not isinstance(source, str):
        raise InvalidParameter(field, f"must be an expression string, got {type(source).__name__}")
    if not source.strip():
        raise InvalidParameter(field, "must be a non-empty expression")
    if len(source) > MAX_LENGTH:
        raise InvalidParameter(field, f"expression longer than {MAX_LENGTH} characters")
    try:
        tree = ast.parse(source.strip(), mode="eval")
    except SyntaxError as exc:
        raise InvalidParameter(field, f"{source!r} is not a valid expression ({exc.msg})") from None
    nodes = list(ast.walk(tree))
    if len(nodes) > MAX_NODES:
        raise InvalidParameter(field, f"expression has more than {MAX_NODES} terms")
    names: set[str] = set()
    _check(field, source, tree.body, names, known)
    return Expression(field, source, tree, frozenset(names))


def _check(field: str, source: str, node: ast.expr, names: set[str], known) -> None:
    bad = None
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            bad = f"constant {node.value!r}"
    elif isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        _check(field, source, node.left, names, known)
        _check(field, source, node.right, names, known)
    elif isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        _check(field, source, node.operand, names, known)
    elif isinstance(node, ast.Call):
        fname = node.func.id if isinstance(node.func, ast.Name) else None
        if fname not in FUNCTIONS or node.keywords or not node.args:
            bad = f"call of {ast.unparse(node.func)!r} (allowed functions: {', '.join(sorted(FUNCTIONS))})"
        else:
            for arg in node.args:
                _check(field, source, arg, names, known)
    elif (name := _dotted(node)) is not None:
        if name not in CONSTANTS and name not in known:
            names_known = sorted(set(known) | set(CONSTANTS))
            options = ", ".join(names_known[:20]) + (", …" if len(names_known) > 20 else "")
            raise InvalidParameter(field, f"unknown name {name!r} in {source!r} (known: {options})")
        names.add(name)
    else:
        bad = f"{type(node).__name__} syntax"
    if bad:
        raise InvalidParameter(field, f"{bad} is not allowed in {source!r}; use numbers, + - * / ** and names")


def _eval(node: ast.expr, names: Mapping[str, object]) -> float:
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.BinOp):
        return float(_BINARY[type(node.op)](_eval(node.left, names), _eval(node.right, names)))
    if isinstance(node, ast.UnaryOp):
        return float(_UNARY[type(node.op)](_eval(node.operand, names)))
    if isinstance(node, ast.Call):
        return float(FUNCTIONS[node.func.id](*(_eval(a, names) for a in node.args)))  # type: ignore[attr-defined]
    name = _dotted(node)
    value = CONSTANTS[name] if name in CONSTANTS else names[name]  # type: ignore[index]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} is {value!r}, not a number")
    return float(value)
