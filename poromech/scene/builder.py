"""Raw scene mappings → frozen dataclasses, following type hints and field metadata.

Every value is converted to the type its field declares (numbers, integers, booleans, strings,
literals, tuples, mappings, nested dataclasses, :class:`~poromech.scene.expressions.Expression`)
and checked against the ranges of its metadata (``gt``, ``min``, ``choices``, ...); unknown and
missing keys are refused. Every failure is a one-line :class:`~poromech.errors.ConfigError`.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import re
import types
import typing
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np

from poromech.errors import ConfigError
from poromech.scene.expressions import Expression, ExpressionError, compile_expression

__all__ = ["Builder", "RANGE_RULES", "check_number", "deep_copy", "field_meta", "format_value",
           "list_of", "list_type"]


def format_value(value: Any) -> str:
    """A value as it appears in an error message (at most 60 characters)."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, datetime.date):  # YAML reads 2026-01-01 as a date
        return f"{value.isoformat()} (a date to YAML: quote it for text)"
    if isinstance(value, bool):  # YAML 1.1 reads yes/no/on/off as booleans too
        return f"{str(value).lower()} (a YAML boolean, as are yes/no/on/off: quote text)"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def deep_copy(x):
    """A copy of a raw scene mapping (nested dicts and lists)."""
    if isinstance(x, dict):
        return {k: deep_copy(v) for k, v in x.items()}
    if isinstance(x, list):
        return [deep_copy(v) for v in x]
    return x


class Builder:
    """Turns a raw mapping into dataclasses, following type hints and field metadata."""

    def __init__(self, parameters: Mapping[str, float]):
        self.parameters = dict(parameters)

    def build(self, value: Any, tp: Any, path: str, meta: Mapping | None = None) -> Any:
        """``value`` converted to type ``tp`` and checked against the field metadata ``meta``."""
        if (meta and list_type(tp) is not None and value is not None
                and not isinstance(value, list | tuple)):
            if list_of(tp) is Expression and isinstance(value, int | float | str) \
                    and not isinstance(value, bool):
                value = [value]  # one expression where a list of them is asked: [value]
            else:
                raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a list: "
                                  f"{meta['doc']}")
        out = self._convert(value, tp, path)
        if meta:
            self._check_range(out, path, meta)
        return out

    def _convert(self, value: Any, tp: Any, path: str) -> Any:
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):
            if value is None and type(None) in args:
                return None
            inner = [a for a in args if a is not type(None)]
            for a in inner:  # a value already of one of the member types is kept as it is
                if a in (str, float, int, bool) and type(value) is a:
                    return value
            return self._convert(value, inner[0], path)
        if value is None:
            raise ConfigError(f"scene key '{path}' is null but a value is required")
        if tp is Expression:
            try:
                return compile_expression(value, self.parameters)
            except ExpressionError as err:
                raise ConfigError(f"scene key '{path}' = {format_value(value)}: {err}") from None
        if tp is float:
            return self._number(value, path)
        if tp is int:
            if isinstance(value, bool) or not (
                isinstance(value, int) or isinstance(value, float) and value.is_integer()
            ):
                raise ConfigError(f"scene key '{path}' = {format_value(value)} must be an integer")
            return int(value)
        if tp is bool:
            if not isinstance(value, bool):
                raise ConfigError(f"scene key '{path}' = {format_value(value)} must be true or "
                                  "false")
            return value
        if tp is str:
            if not isinstance(value, str):
                raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a string")
            return value
        if origin is Literal:
            if value not in args:
                allowed = ", ".join(str(a) for a in args)
                raise ConfigError(f"scene key '{path}' = {format_value(value)} is not one of: "
                                  f"{allowed}")
            return value
        if origin is tuple:
            return self._tuple(value, args, path)
        if origin is dict:
            if not isinstance(value, dict):
                raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a mapping")
            return {str(k): self._convert(v, args[1], f"{path}.{k}") for k, v in value.items()}
        if dataclasses.is_dataclass(tp):
            return self.dataclass(value, tp, path)
        if tp is type(None):
            raise ConfigError(f"scene key '{path}' must be null")
        raise TypeError(f"unsupported schema type {tp} at {path}")  # pragma: no cover

    def _number(self, value: Any, path: str) -> float:
        if isinstance(value, bool):
            raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a number")
        if isinstance(value, int | float):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
            if value in self.parameters:
                return float(self.parameters[value])
            return self._constant_expression(value, path)
        raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a number")

    def _constant_expression(self, value: str, path: str) -> float:
        """A number given as an expression of the parameters (``radius: a/2``)."""
        what = f"scene key '{path}' = {format_value(value)} must be a number"
        try:
            expr = compile_expression(value, self.parameters)
        except ExpressionError as err:  # a number takes no x, y, z, t: not listed as allowed
            text = re.sub(r" \(allowed: [^)]*\)", "", str(err))
            names = ", ".join(sorted([*self.parameters, "e", "pi"]))
            above = "; a parameter may use those above it" if path.startswith("parameters.") else ""
            raise ConfigError(f"{what} or an expression of the parameters: {text} (allowed: "
                              f"{names}){above}") from None
        if not expr.is_constant:
            raise ConfigError(f"{what}: it may use the parameters, not x, y, z or t")
        number = expr.value()
        if not np.isfinite(number):
            raise ConfigError(f"{what}: it evaluates to {number}")
        return number

    def _tuple(self, value: Any, args: tuple, path: str) -> tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(self._convert(v, args[0], f"{path}.{i}") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(
                f"scene key '{path}' = {format_value(value)} must have {len(args)} entries, "
                f"not {len(value)}"
            )
        return tuple(self._convert(v, a, f"{path}.{i}")
                     for i, (v, a) in enumerate(zip(value, args, strict=True)))

    def dataclass(self, value: Any, cls: type, path: str) -> Any:
        """An instance of dataclass ``cls`` from the mapping ``value`` (unknown keys refused)."""
        prefix = f"{path}." if path else ""
        if not isinstance(value, dict):
            raise ConfigError(f"scene key '{path}' = {format_value(value)} must be a mapping")
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls)}
        for key in value:
            if key not in fields:
                allowed = ", ".join(fields)
                raise ConfigError(f"scene key '{prefix}{key}' is unknown (allowed: {allowed})")
        kwargs = {}
        for name, f in fields.items():
            if name in value:
                kwargs[name] = self.build(value[name], hints[name], prefix + name, f.metadata)
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"scene key '{prefix}{name}' is required ({f.metadata['doc']})")
        return cls(**kwargs)

    def _check_range(self, value: Any, path: str, meta: Mapping) -> None:
        if value is None:
            return
        if isinstance(value, tuple):
            for i, v in enumerate(value):
                self._check_range(v, f"{path}.{i}", meta)
            return
        if isinstance(value, Expression):
            if not value.is_constant:
                return  # checked on a sample grid once the domain is known
            value = value.value()
        if not isinstance(value, int | float) or isinstance(value, bool):
            return
        check_number(value, path, meta)


def list_type(tp: Any) -> Any:
    """The ``tuple[...]`` type of a field, Optional unwrapped, or None."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        tp = inner[0] if len(inner) == 1 else None
    return tp if typing.get_origin(tp) is tuple else None


def list_of(tp: Any) -> Any:
    """The entry type of a variable-length ``tuple[X, ...]`` field, or None."""
    args = typing.get_args(list_type(tp))
    return args[0] if len(args) == 2 and args[1] is Ellipsis else None


RANGE_RULES = {
    "gt": (lambda v, b: v > b, "> {}"),
    "lt": (lambda v, b: v < b, "< {}"),
    "min": (lambda v, b: v >= b, ">= {}"),
    "max": (lambda v, b: v <= b, "<= {}"),
}


def check_number(value: float, path: str, meta: Mapping, where: str = "") -> None:
    """Refuse a number that is not finite or outside the range of its field metadata."""
    try:
        finite = math.isfinite(value)
    except OverflowError:  # an integer beyond any float (np.isfinite raised a TypeError)
        finite = False
    if not finite:
        raise ConfigError(f"scene key '{path}' = {format_value(value)}{where} must be finite")
    for rule, (ok, text) in RANGE_RULES.items():
        if rule in meta and not ok(value, meta[rule]):
            allowed = text.format(meta[rule])
            raise ConfigError(
                f"scene key '{path}' = {format_value(value)}{where} is not allowed: must be "
                f"{allowed}"
            )
    if "choices" in meta and value not in meta["choices"]:
        allowed = ", ".join(str(c) for c in meta["choices"])
        raise ConfigError(f"scene key '{path}' = {format_value(value)} is not one of: {allowed}")


def field_meta(cls, name) -> Mapping:
    """The metadata (doc, unit, range) of field ``name`` of dataclass ``cls``."""
    return {f.name: f for f in dataclasses.fields(cls)}[name].metadata
