"""The one override syntax: ``dotted.path=value`` on a tree of frozen dataclasses, typed by its fields.

Used for the env and reward settings of training (``bar-train --env-overrides
reward.scales.action_rate=-0.1``, ``bar_policy.envs.load(name, overrides=[...])``) and for the training config
itself (``bar_policy.training.config.apply_overrides``, the benches' ``--set``). One grammar for all of them:

- ``path`` names a leaf field through nested dataclasses (``reward.scales.action_rate``); an unknown name is
  refused with the valid names at that level.
- ``value`` is read as the field's annotated type: numbers as Python numbers (``-0.1``, ``1e-3``; an
  integer field refuses ``2.5``), booleans as ``true``/``false`` (any case), ``None``/``null`` for an
  optional field, sequences as ``[0, 1]`` or ``(0, 1)`` (a single number for a variable-length tuple),
  ``Literal`` fields by one of their choices, and strings as typed (no quotes needed).

All overrides are applied together, one ``dataclasses.replace`` per dataclass, so related fields can change
at once; each dataclass's ``__post_init__`` then validates the result. numpy-free and jax-free.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any, Literal, Union, get_args, get_origin

__all__ = [
    "OverrideError",
    "apply_overrides",
    "changed_overrides",
    "did_you_mean",
    "field_paths",
    "merge_overrides",
    "override_text",
    "split_override",
]

_NONE_WORDS = ("None", "null")
"""Texts read as None for an optional field."""
_BOOL_WORDS = {"true": True, "false": False}
"""Texts (lower-cased) read as booleans."""


class OverrideError(ValueError):
    """An override that names no field, is malformed, or does not fit the field's type."""


def split_override(text: str) -> tuple[str, str]:
    """``"a.b=1"`` -> ``("a.b", "1")``; raises ``OverrideError`` without ``=`` or without a path."""
    path, eq, value = text.partition("=")
    if not eq or not path.strip():
        raise OverrideError(f"override {text!r} must look like 'dotted.path=value'")
    return path.strip(), value.strip()


def merge_overrides(base: Iterable[str], extra: Iterable[str]) -> tuple[str, ...]:
    """``extra`` on top of ``base``: ``base``'s items whose path ``extra`` does not set, then ``extra``.

    How a command line's ``--env-overrides`` applies on top of a preset's own (``training.cli``): the reach
    gpu preset's ``sim_dt=0.004`` stays when a run adds ``reward.scales.success=1``, and goes when it gives
    ``sim_dt=0.002``. ``merge_overrides(x, x) == tuple(x)``.
    """
    extra = tuple(extra)
    given = {split_override(o)[0] for o in extra}
    return tuple(o for o in base if split_override(o)[0] not in given) + extra


def apply_overrides(config: Any, overrides: Iterable[str] | Mapping[str, Any]) -> Any:
    """``config`` with the overrides applied (see the module docstring for the grammar).

    Args:
        config: a (nested) frozen dataclass.
        overrides: ``["reward.scales.action_rate=-0.02", "actuator.latency_steps=[0, 1]"]`` (texts, read
            by the field types), or a mapping ``{"reward.scales.action_rate": -0.02}`` (values used as
            given).

    Raises:
        OverrideError: an unknown path (the message lists the valid fields there), a malformed item, or a
            value that does not fit its field's type.
        ValueError: the resulting config fails its own validation.
    """
    if isinstance(overrides, Mapping):
        items = [(str(p).split("."), v, str(p), False) for p, v in overrides.items()]
    else:
        items = []
        for text in overrides:
            path, value = split_override(text)
            items.append((path.split("."), value, path, True))
    return _apply(config, items) if items else config


def field_paths(config: Any, prefix: str = "") -> list[str]:
    """Every leaf path of a dataclass tree: ``["actuator.latency_steps", ..., "reward.scales.torque"]``."""
    out = []
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            out += field_paths(value, f"{prefix}{f.name}.")
        else:
            out.append(prefix + f.name)
    return out


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    """``"; did you mean 'x'?"``: the closest of ``choices`` to a mistyped ``name`` (difflib), else ``""``."""
    import difflib

    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def override_text(value: Any) -> str:
    """The override text of a leaf value that ``apply_overrides`` reads back to an equal value.

    Floats by ``repr`` (the shortest text that round-trips exactly), booleans ``true``/``false``, None as
    ``None``, tuples as ``(a, b)`` of their items, strings as they are.
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        items = ", ".join(override_text(v) for v in value)
        return f"({items},)" if len(value) == 1 else f"({items})"
    return str(value) if isinstance(value, str) else repr(value)


def changed_overrides(config: Any, base: Any, prefix: str = "") -> tuple[str, ...]:
    """The ``path=value`` items that turn ``base`` into ``config`` (two dataclass trees of one shape).

    Leaves in field order; ``apply_overrides(base, changed_overrides(config, base)) == config``. How the
    typed ``--env.*`` flags of ``bar-train`` become the run's ``env_overrides``, and what the run header
    prints as the settings that differ from the defaults.
    """
    out: list[str] = []
    for f in dataclasses.fields(config):
        value, old = getattr(config, f.name), getattr(base, f.name)
        if dataclasses.is_dataclass(value) and dataclasses.is_dataclass(old):
            out += changed_overrides(value, old, f"{prefix}{f.name}.")
        elif value != old or type(value) is not type(old):
            out.append(f"{prefix}{f.name}={override_text(value)}")
    return tuple(out)


def _apply(obj: Any, items: list[tuple[list[str], Any, str, bool]]) -> Any:
    """Apply ``(keys, value, path, is_text)`` items to one dataclass level with one ``replace``."""
    if not dataclasses.is_dataclass(obj):
        raise OverrideError(f"override {items[0][2]!r}: {type(obj).__name__} has no fields to set")
    names = [f.name for f in dataclasses.fields(obj)]
    hints = _hints(type(obj))
    leaf: dict[str, Any] = {}
    nested: dict[str, list[tuple[list[str], Any, str, bool]]] = {}
    for keys, value, path, is_text in items:
        head = keys[0]
        if head not in names:
            raise OverrideError(
                f"override {path!r}: no field {head!r} in {type(obj).__name__}; valid fields: {names}"
                + did_you_mean(head, names)
            )
        current = getattr(obj, head)
        if len(keys) > 1:
            nested.setdefault(head, []).append((keys[1:], value, path, is_text))
        elif dataclasses.is_dataclass(current):
            sub = [f.name for f in dataclasses.fields(current)]
            raise OverrideError(f"override {path!r}: {head!r} is a group; set one of its fields {sub}")
        elif is_text:
            leaf[head] = _read(value, hints.get(head, type(current)), path)
        else:
            leaf[head] = value
    changes = {name: _apply(getattr(obj, name), sub) for name, sub in nested.items()}
    return dataclasses.replace(obj, **changes, **leaf)


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """Resolved field annotations of a dataclass (empty when they cannot be resolved)."""
    try:
        return typing.get_type_hints(cls)
    except (NameError, TypeError):  # pragma: no cover - an unresolvable forward reference
        return {}


def _literal(text: str) -> Any:
    """The Python literal the text spells (numbers, tuples, lists), else the text itself."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return text


def _read(text: str, hint: Any, path: str) -> Any:
    """The override text as a value of type ``hint``; ``OverrideError`` naming the type otherwise."""
    ok, value = _convert(text, _literal(text), hint)
    if not ok:
        raise OverrideError(f"override {path}={text}: expected {_describe(hint)}, got {text!r}")
    return value


def _convert(text: str | None, parsed: Any, hint: Any) -> tuple[bool, Any]:
    """``(True, value)`` when ``parsed`` (from ``text``; None for a sequence item) fits ``hint``."""
    origin, args = get_origin(hint), get_args(hint)
    if origin in (Union, types.UnionType):
        if type(None) in args and (parsed is None or text in _NONE_WORDS):
            return True, None
        members = [a for a in args if a is not type(None)]
        # str accepts any text, so it is tried last.
        for member in sorted(members, key=lambda a: a is str):
            ok, value = _convert(text, parsed, member)
            if ok:
                return True, value
        return False, None
    if hint is type(None):
        return (parsed is None or text in _NONE_WORDS), None
    if origin is Literal:
        for choice in args:
            if parsed == choice or (text is not None and text == str(choice)):
                return True, choice
        return False, None
    if origin is tuple:
        return _convert_tuple(parsed, args)
    if hint is bool:
        if isinstance(parsed, bool):
            return True, parsed
        word = (text if text is not None else str(parsed)).lower()
        return (word in _BOOL_WORDS), _BOOL_WORDS.get(word)
    if hint is int:
        return (isinstance(parsed, int) and not isinstance(parsed, bool)), parsed
    if hint is float:
        ok = isinstance(parsed, int | float) and not isinstance(parsed, bool)
        return ok, float(parsed) if ok else None
    if hint is str:
        if text is not None:
            return True, text
        return isinstance(parsed, str), parsed
    if hint is Any or not isinstance(hint, type):
        return True, parsed
    return isinstance(parsed, hint), parsed


def _convert_tuple(parsed: Any, args: tuple[Any, ...]) -> tuple[bool, Any]:
    """A ``tuple[T, ...]`` or ``tuple[T1, T2]`` from a list/tuple (a scalar for the variable length)."""
    variable = len(args) == 2 and args[1] is Ellipsis
    if not isinstance(parsed, list | tuple):
        if not variable:
            return False, None
        parsed = (parsed,)
    kinds = [args[0]] * len(parsed) if variable else list(args)
    if len(kinds) != len(parsed):
        return False, None
    out = []
    for kind, item in zip(kinds, parsed, strict=True):
        ok, value = _convert(None, item, kind)
        if not ok:
            return False, None
        out.append(value)
    return True, tuple(out)


def _describe(hint: Any) -> str:
    """A type for an error message: ``a number``, ``one of ['swish', 'elu']``, ``a sequence of 2 ...``."""
    origin, args = get_origin(hint), get_args(hint)
    if origin in (Union, types.UnionType):
        parts = [_describe(a) for a in args if a is not type(None)]
        return " or ".join(parts) + (" or None" if type(None) in args else "")
    if origin is Literal:
        return f"one of {list(args)}"
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a sequence of {_describe(args[0])} like [1, 2]"
        return f"a sequence of {len(args)} values ({', '.join(_describe(a) for a in args)}) like [0, 1]"
    names = {bool: "a boolean (true or false)", int: "an integer", float: "a number", str: "a string"}
    return names.get(hint, getattr(hint, "__name__", str(hint)))
