"""Units in case files, and a strict reader for TOML tables.

Inside fixbench every number is SI. In a file, a dimensional value names its unit in its key
(``thickness_mm``, ``force_N``, ``speed_rpm``); :class:`Reader` finds the key whatever unit of the
right dimension it carries, converts to SI, and raises a one-line :class:`CaseError` naming file
and key for a missing key, an unknown unit, a wrong type, a non-finite number or an unknown key.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from fixbench.cases.errors import CaseError

#: dimension -> {unit suffix: factor to SI}
UNITS: dict[str, dict[str, float]] = {
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6},
    "force": {"N": 1.0, "kN": 1e3},
    "pressure": {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "GPa": 1e9},
    "density": {"kg_m3": 1.0, "g_cm3": 1e3},
    "angular_speed": {"rad_s": 1.0, "rpm": 2.0 * math.pi / 60.0},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0},
}
_ALL_SUFFIXES = sorted({s for table in UNITS.values() for s in table}, key=len, reverse=True)


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


class Reader:
    """Read one TOML table strictly: every key must be consumed, or :meth:`finish` complains.

    ``source`` names the file; ``prefix`` is the dotted path of the table inside it.
    """

    def __init__(self, data: Any, source: str, prefix: str = ""):
        if not isinstance(data, dict):
            raise CaseError(source, prefix or "(top level)", "must be a table")
        self.data, self.source, self.prefix = data, source, prefix
        self.used: set[str] = set()

    # -- helpers -------------------------------------------------------------------------------
    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str, problem: str) -> CaseError:
        return CaseError(self.source, self.key(name), problem)

    def has(self, name: str) -> bool:
        return name in self.data or self._unit_key(name, None) is not None

    def _unit_key(self, name: str, dim: str | None) -> str | None:
        """Find ``name_<unit>`` among the keys; complain about a unit of the wrong kind."""
        hits = [k for k in self.data if k.startswith(name + "_") and k not in self.used]
        hits = [k for k in hits if "_" not in k[len(name) + 1:] or k[len(name) + 1:] in _ALL_SUFFIXES]
        if not hits:
            return None
        if len(hits) > 1:
            raise self.error(hits[1], f"given twice (also as {hits[0]})")
        k = hits[0]
        if dim is not None:
            unit = k[len(name) + 1:]
            if unit not in UNITS[dim]:
                known = ", ".join(UNITS[dim])
                raise self.error(k, f"unknown unit '{unit}' for a {dim.replace('_', ' ')} "
                                    f"(use one of: {known})")
        return k

    # -- scalar and array getters ---------------------------------------------------------------
    def raw(self, name: str, default: Any = ..., types: tuple = ()) -> Any:
        if name not in self.data:
            if default is ...:
                raise self.error(name, "missing")
            return default
        self.used.add(name)
        value = self.data[name]
        if types and not isinstance(value, types):
            raise self.error(name, f"must be {' or '.join(t.__name__ for t in types)}, "
                                   f"got {type(value).__name__}")
        return value

    def text(self, name: str, default: Any = ..., choices: tuple[str, ...] | None = None) -> str:
        value = self.raw(name, default, (str,))
        if choices is not None and value not in choices:
            raise self.error(name, f"must be one of {', '.join(choices)}; got '{value}'")
        return value

    def table(self, name: str, required: bool = False) -> Reader | None:
        if name not in self.data:
            if required:
                raise self.error(name, "missing")
            return None
        return Reader(self.raw(name), self.source, self.key(name))

    def tables(self, name: str) -> list[Reader]:
        """An array of tables (``[[name]]``), possibly empty."""
        value = self.raw(name, [], (list,))
        out = []
        for i, item in enumerate(value):
            out.append(Reader(item, self.source, f"{self.key(name)}[{i}]"))
        return out

    def number(self, name: str, dim: str | None = None, default: Any = ...,
               positive: bool = False, nonneg: bool = False) -> float:
        """A finite number, converted to SI when ``dim`` names a dimension."""
        value, key = self._quantity(name, dim, default)
        if value is None:
            return default
        if not _is_number(value):
            raise self.error(key, f"must be a number, got {type(value).__name__}")
        self._check_value(key, float(value), positive, nonneg)  # as written: the message quotes the file
        return float(value) * self._factor(key, name, dim)

    def integer(self, name: str, default: Any = ..., minimum: int | None = None) -> int:
        value = self.raw(name, default)
        if value is default and default is not ...:
            return default
        if not isinstance(value, int) or isinstance(value, bool):
            raise self.error(name, f"must be a whole number, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(name, f"must be at least {minimum}, got {value}")
        return value

    def array(self, name: str, dim: str | None = None, default: Any = ..., shape: tuple = (),
              positive: bool = False, nonneg: bool = False) -> np.ndarray:
        """A numeric array (nested lists), SI; ``shape`` entries of -1 match any length."""
        value, key = self._quantity(name, dim, default)
        if value is None:
            return default
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise self.error(key, "must be a (nested) list of numbers of even lengths") from None
        if arr.dtype == object:
            raise self.error(key, "must be a (nested) list of numbers of even lengths")
        if shape:
            if arr.ndim != len(shape) or any(s not in (-1, n) for s, n in zip(shape, arr.shape)):
                want = " x ".join("N" if s == -1 else str(s) for s in shape)
                raise self.error(key, f"must have shape {want}, got {' x '.join(map(str, arr.shape))}")
        self._check_value(key, arr, positive, nonneg)
        return arr * self._factor(key, name, dim)

    def _quantity(self, name: str, dim: str | None, default: Any) -> tuple[Any, str]:
        if dim is None:
            if name not in self.data and default is not ...:
                return None, name
            return self.raw(name), name
        if name in self.data:
            example = next(iter(UNITS[dim]))
            raise self.error(name, f"a {dim.replace('_', ' ')} needs its unit in the key, "
                                   f"e.g. {name}_{example}")
        key = self._unit_key(name, dim)
        if key is None:
            if default is not ...:
                return None, name
            raise self.error(f"{name}_<unit>", "missing")
        self.used.add(key)
        return self.data[key], key

    def _factor(self, key: str, name: str, dim: str | None) -> float:
        return 1.0 if dim is None else UNITS[dim][key[len(name) + 1:]]

    def _check_value(self, key: str, value: Any, positive: bool, nonneg: bool) -> None:
        arr = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise self.error(key, "must be finite (got NaN or infinity)")
        if positive and np.any(arr <= 0):
            raise self.error(key, f"must be positive, got {_show(value)}")
        if nonneg and np.any(arr < 0):
            raise self.error(key, f"must not be negative, got {_show(value)}")

    def finish(self) -> None:
        """Refuse keys that nobody read (typos, unsupported options)."""
        for k in self.data:
            if k not in self.used:
                raise self.error(k, "unknown key")


def _show(value: Any) -> str:
    arr = np.asarray(value, dtype=float)
    return f"{float(arr):g}" if arr.ndim == 0 else f"{arr.min():g} (smallest)"


def file_reader(path: Path, keys: tuple[str, ...], missing: str) -> Reader:
    """A TOML file's top table, read strictly: a missing file (``missing`` says what to give instead),
    TOML that does not parse, or a top-level key outside ``keys`` is a one-line :class:`CaseError`."""
    source = str(path)
    if not path.is_file():
        raise CaseError(source, "", missing)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(source, "", f"not valid TOML ({exc})") from None
    r = Reader(data, source)
    for key in data:
        if key not in keys:
            raise r.error(key, f"unknown key (known: {', '.join(keys)})")
    return r
