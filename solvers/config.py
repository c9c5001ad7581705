"""``--set key=value`` overrides, typed by the planner's config dataclass."""

from __future__ import annotations

import typing
from dataclasses import fields

from fixbench.solvers.base import PlannerConfig, PlannerError


def parse_value(text: str, kind: type):
    if kind is bool:
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"'{text}' is not a boolean")
    if kind in (int, float, str):
        return kind(text)
    origin = typing.get_origin(kind)
    if origin is tuple:
        inner = typing.get_args(kind)[0]
        return tuple(parse_value(t, inner) for t in text.split(",") if t)
    raise ValueError(f"cannot set a field of type {kind}")


def apply_sets(config_cls: type[PlannerConfig], sets: list[str] | tuple[str, ...],
               planner: str) -> dict:
    """Overrides from ``key=value`` strings; one-line errors for unknown keys or bad values."""
    types = typing.get_type_hints(config_cls)
    names = {f.name for f in fields(config_cls)}
    out = {}
    for item in sets:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise PlannerError(f"--set {item}: expected key=value")
        if key not in names:
            raise PlannerError(f"--set {item}: planner '{planner}' has no setting '{key}' "
                               f"(settings: {', '.join(sorted(names)) or 'none'})")
        kind = types[key]
        if typing.get_origin(kind) is typing.Union:  # Optional[X]
            kind = next(a for a in typing.get_args(kind) if a is not type(None))
        try:
            out[key] = parse_value(value, kind)
        except ValueError as exc:
            raise PlannerError(f"--set {item}: {exc}") from None
    return out
