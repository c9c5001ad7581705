"""What every generated part family shares: its parameter ranges, one draw, and the case file a draw
becomes (docs/families.md).

A family is a :class:`Family` subclass in a module of its own: its ``ranges`` (name -> :class:`Span`
or :class:`Choice`; a length names its unit, ``width_mm``), :meth:`Family.misfit` (why one draw cannot
hold: a cut-out that does not fit its panel) and :meth:`Family.tables` (the case file's tables). A
draw is a function of a seeded generator only, and its numbers are rounded to what a person would
write (0.1 mm, 1 N, 0.1 degree), so a family and a seed give the same bytes on any machine.

``overrides`` narrow a family's ranges (``fixbench generate FAMILY --set width_mm=400:600``); a range
that no draw could satisfy (a cut-out wider than every panel) is refused when the family is made,
naming the parameter, before any part is drawn.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from fixbench.cases.errors import FixbenchError

#: how many decimals a drawn real number keeps
DECIMALS = 1


class FamilyError(FixbenchError):
    """A family name, parameter or range that cannot be used: one line naming it."""

    def __init__(self, key: str, problem: str):
        self.key, self.problem = key, problem
        super().__init__(f"generate {key}: {problem}")


@dataclass(frozen=True)
class Span:
    """A number drawn uniformly in [low, high] (an integer where ``integer``)."""

    low: float
    high: float
    integer: bool = False

    def draw(self, rng: np.random.Generator) -> float | int:
        if self.integer:
            return int(rng.integers(int(self.low), int(self.high) + 1))
        return round(float(rng.uniform(self.low, self.high)), DECIMALS)

    def narrowed(self, key: str, text: str) -> Span:
        """The span ``text`` gives (``a`` or ``a:b``), which must lie inside this one."""
        try:
            parts = [float(v) for v in text.split(":")]
        except ValueError:
            raise FamilyError(key, f"'{text}' is not a number or a range a:b") from None
        if len(parts) not in (1, 2) or not all(math.isfinite(v) for v in parts):
            raise FamilyError(key, f"'{text}' is not a number or a range a:b")
        low, high = parts[0], parts[-1]
        if self.integer and not (low.is_integer() and high.is_integer()):
            raise FamilyError(key, f"'{text}': this parameter is a whole number")
        if low > high:
            raise FamilyError(key, f"'{text}': the range's low end is above its high end")
        if low < self.low or high > self.high:
            raise FamilyError(key, f"'{text}' leaves the family's range {self.text()}")
        return replace(self, low=low, high=high)

    def text(self) -> str:
        return f"{self.low:g}:{self.high:g}"


@dataclass(frozen=True)
class Choice:
    """One of ``options``, each as likely."""

    options: tuple[str, ...]

    def draw(self, rng: np.random.Generator) -> str:
        return self.options[int(rng.integers(len(self.options)))]

    def narrowed(self, key: str, text: str) -> Choice:
        """The options ``text`` lists (comma-separated), each one of this choice's."""
        chosen = tuple(dict.fromkeys(v.strip() for v in text.split(",")))
        unknown = [v for v in chosen if v not in self.options]
        if unknown or not chosen:
            raise FamilyError(key, f"'{text}': choose from {', '.join(self.options)}")
        return Choice(chosen)

    def text(self) -> str:
        return ",".join(self.options)


class Family:
    """A family of generated parts. Subclasses set ``name``, ``summary`` and ``ranges`` and write
    :meth:`misfit` and :meth:`tables`; :meth:`check_ranges` refuses narrowed ranges no draw can hold."""

    name: ClassVar[str]
    summary: ClassVar[str]
    ranges: ClassVar[dict[str, Span | Choice]]

    def __init__(self, overrides: dict[str, str] | None = None):
        self.params = dict(self.ranges)
        for key, text in (overrides or {}).items():
            if key not in self.ranges:
                raise FamilyError(f"--set {key}", f"family '{self.name}' has no such parameter; its parameters: "
                                  f"{', '.join(self.ranges)}")
            self.params[key] = self.ranges[key].narrowed(f"--set {key}", text)
        self.check_ranges()

    def draw(self, rng: np.random.Generator) -> dict:
        """One draw of every parameter, in the order of ``ranges``."""
        return {k: r.draw(rng) for k, r in self.params.items()}

    def check_ranges(self) -> None:
        """Raise :class:`FamilyError` where the (narrowed) ranges leave no draw that can hold."""

    def misfit(self, p: dict) -> str | None:
        """Why the draw ``p`` cannot make a part (it is then redrawn, the reason recorded), or None."""
        return None

    def tables(self, p: dict, name: str) -> dict:
        """The case file of the draw ``p`` as TOML tables (docs/cases.md), named ``name``."""
        raise NotImplementedError

    def low(self, key: str) -> float:
        return self.params[key].low

    def high(self, key: str) -> float:
        return self.params[key].high


# shared pieces of the case files
# ---------------------------------------------------------------------------------------------------


def mm(v: float) -> float:
    """A length in mm as a case file writes it (0.1 mm)."""
    return round(float(v), DECIMALS)


def strips(x0: float, x1: float, y0: float, y1: float, n: int, prefix: str = "zone") -> list[dict]:
    """``n`` agent regions: equal strips across the candidate grid's x interval ``x0``..``x1`` (mm),
    the outer ones reaching 1 mm past it and each 1 mm past ``y0``..``y1``, so every candidate of a
    :func:`strip_grid` over the same box has one owner and none lies on a strip's edge."""
    cuts = np.linspace(x0, x1, n + 1)
    cuts[0], cuts[-1] = x0 - 1, x1 + 1
    out = []
    for i in range(n):
        a, b = mm(cuts[i]), mm(cuts[i + 1])
        out.append({"name": f"{prefix} {i}",
                    "polygon_mm": [[a, mm(y0 - 1)], [b, mm(y0 - 1)], [b, mm(y1 + 1)], [a, mm(y1 + 1)]]})
    return out


def strip_grid(x0: float, x1: float, y0: float, y1: float, agents: int, columns: int, rows: int) -> dict:
    """A candidate grid of ``columns`` columns a strip (:func:`strips`) and ``rows`` rows, each
    point at the centre of its cell, so no point lies on a strip's edge."""
    nx = agents * columns
    dx, dy = (x1 - x0) / nx, (y1 - y0) / rows
    return {"x_start_mm": mm(x0 + dx / 2), "x_step_mm": round(dx, 3), "x_count": nx,
            "y_start_mm": mm(y0 + dy / 2), "y_step_mm": round(dy, 3), "y_count": rows}


def columns_rows(agents: int, per_agent: int, aspect: float) -> tuple[int, int]:
    """Columns and rows of a strip's grid holding about ``per_agent`` points, cells about square in a
    strip of width / height ``aspect``."""
    columns = max(1, round(math.sqrt(per_agent * aspect)))
    return columns, max(2, round(per_agent / columns))


def thrust(force: float, tilt_deg: float, heading_deg: float = 0.0) -> list[float]:
    """A drill thrust of ``force`` N into the plate (-z), tilted ``tilt_deg`` from the normal towards
    ``heading_deg`` in the plane: its in-plane part loads the membrane field (docs/cases.md#case-files)."""
    t, h = math.radians(tilt_deg), math.radians(heading_deg)
    return [round(force * math.sin(t) * math.cos(h), 1), round(force * math.sin(t) * math.sin(h), 1),
            round(-force * math.cos(t), 1)]


def rounded_box(cx: float, cy: float, w: float, h: float) -> list[float]:
    """``rectangle_mm`` of a box of size w x h centred at (cx, cy)."""
    return [mm(cx - w / 2), mm(cy - h / 2), mm(cx + w / 2), mm(cy + h / 2)]


# the case file's text
# ---------------------------------------------------------------------------------------------------


def case_text(tables: dict, header: list[str]) -> str:
    """``tables`` as TOML, after ``header`` as comment lines, read back to check it says the same.

    Written by hand rather than with a TOML writer because the one kept for Python, tomli-w, puts every
    element of an array on a line of its own: a point ``[x, y]`` would take four lines and a polygon a
    screenful, where a person reading or editing a case file wants one point a line at most. Only what
    a case file holds is written: strings, numbers, booleans, (nested) arrays of them, tables and
    arrays of tables."""
    lines = [f"# {h}".rstrip() for h in header]
    _table(lines, (), tables)
    text = "\n".join(lines).strip("\n") + "\n"
    if tomllib.loads(text) != tables:  # a value this writer cannot spell: never a silently wrong file
        raise ValueError("case_text: the TOML written does not read back as the tables given")
    return text


def _table(lines: list[str], path: tuple[str, ...], table: dict) -> None:
    def nested(v):  # a table, or a non-empty array of tables
        return isinstance(v, dict) or (isinstance(v, list) and v and all(isinstance(x, dict) for x in v))

    lines += [f"{k} = {_value(v)}" for k, v in table.items() if not nested(v)]
    for k, v in table.items():
        if isinstance(v, dict):
            lines += ["", f"[{'.'.join((*path, k))}]"]
            _table(lines, (*path, k), v)
        elif nested(v):
            for item in v:
                lines += ["", f"[[{'.'.join((*path, k))}]]"]
                _table(lines, (*path, k), item)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        if not math.isfinite(v):
            raise ValueError(f"case_text: {v!r} has no TOML spelling here")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string with ASCII escapes is a TOML basic string
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise ValueError(f"case_text: cannot write {type(v).__name__} {v!r}")
