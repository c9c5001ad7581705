"""Generated part families (docs/families.md): parametric thin parts of the kinds robotic fixtures
hold while they are drilled or loaded, each family a module; ``fixbench generate`` draws them into
case files (:mod:`fixbench.bench.generate`)."""

from __future__ import annotations

from fixbench.cases.families.base import Choice, Family, FamilyError, Span
from fixbench.cases.families.blade import Blade
from fixbench.cases.families.bracket import Bracket
from fixbench.cases.families.cfrp_skin import CfrpSkin
from fixbench.cases.families.skin_panel import SkinPanel
from fixbench.cases.families.spar_web import SparWeb

#: every family by name
FAMILIES: dict[str, type[Family]] = {f.name: f for f in (SkinPanel, Bracket, SparWeb, Blade, CfrpSkin)}


def family(name: str, overrides: dict[str, str] | None = None) -> Family:
    """The family ``name`` with its ranges narrowed by ``overrides`` (checked here)."""
    if name not in FAMILIES:
        raise FamilyError("FAMILY", f"unknown family '{name}'; the families: {', '.join(FAMILIES)}")
    return FAMILIES[name](overrides)


__all__ = ["FAMILIES", "Choice", "Family", "FamilyError", "Span", "family"]
