"""Spar webs: a long web plate with a row of round lightening holes along its middle, clamped at its
root end (and at its tip end, where a rib meets it), drilled along its top edge, where a flange joins
it, while 3-5 robots, one a stretch of the spar, hold it."""

from __future__ import annotations

from fixbench.cases.families.base import Choice, Family, FamilyError, Span, columns_rows, mm, strip_grid, strips, thrust

#: the candidate grid's and the drilling line's inset (mm) from the web's edges
INSET_MM = 15
#: web left (mm) between two lightening holes, and between a hole and an end, at least
LAND_MM = 30


class SparWeb(Family):
    name = "spar_web"
    summary = "long web with 2-5 lightening holes, clamped root (and tip), drilled along its top edge"
    ranges = {
        "material": Choice(("aluminium", "titanium", "steel")),
        "thickness_mm": Span(2.0, 8.0),
        "length_mm": Span(600, 1400),
        "height_mm": Span(120, 300),
        "holes": Span(2, 5, integer=True),
        "hole_diameter_ratio": Span(0.3, 0.6),  # of the web's height
        "ends": Choice(("root", "root and tip")),
        "positions": Span(6, 12, integer=True),
        "force_N": Span(100, 300),
        "tilt_deg": Span(0, 20),
        "agents": Span(3, 5, integer=True),
        "candidates_per_agent": Span(10, 30, integer=True),
    }

    def check_ranges(self) -> None:
        pitch = self.high("length_mm") / self.low("holes")
        diameter = self.low("hole_diameter_ratio") * self.low("height_mm")
        if diameter + LAND_MM > pitch:
            raise FamilyError("--set holes", f"{self.low('holes'):g} holes of at least {diameter:g} mm with "
                              f"{LAND_MM} mm lands never fit a web at most {self.high('length_mm'):g} mm long")
        if self.high("hole_diameter_ratio") * self.high("height_mm") > self.high("height_mm") - 2 * (INSET_MM + 10):
            raise FamilyError("--set hole_diameter_ratio", "holes this large leave no web above them to drill")

    def misfit(self, p: dict) -> str | None:
        pitch = p["length_mm"] / p["holes"]
        d = p["hole_diameter_ratio"] * p["height_mm"]
        if d + LAND_MM > pitch:
            return f"{p['holes']} holes of {d:.1f} mm with their lands do not fit a {p['length_mm']:g} mm web"
        return None

    def tables(self, p: dict, name: str) -> dict:
        L, H, n = p["length_mm"], p["height_mm"], p["agents"]
        pitch, r = L / p["holes"], p["hole_diameter_ratio"] * H / 2
        holes = [{"op": "difference", "circle_mm": [mm(pitch * (i + 0.5)), mm(H / 2), mm(r)]}
                 for i in range(p["holes"])]
        supports = [{"name": "root", "segment_mm": [[0, 0], [0, H]], "kind": "clamped"}]
        if p["ends"] == "root and tip":
            supports.append({"name": "tip rib", "segment_mm": [[L, 0], [L, H]], "kind": "clamped"})
        per_agent = min(p["candidates_per_agent"], int((2e5) ** (1 / n)))
        cols, rows = columns_rows(n, per_agent, (L - 2 * INSET_MM) / n / (H - 2 * INSET_MM))
        y = mm(H - INSET_MM)
        return {
            "case": {"description": f"Generated spar web ({self.name} family), {p['holes']} lightening holes, "
                                    f"{p['positions']} holes drilled", "part": name},
            "material": {"name": p["material"]},
            "geometry": {"thickness_mm": p["thickness_mm"], "shapes": [{"rectangle_mm": [0, 0, L, H]}, *holes]},
            "mesh": {"size_mm": mm(min(max(H / 6, 15), 40)),
                     "refine": [{"near": "tasks", "size_mm": 5, "width_mm": 6}]},
            "supports": supports,
            "fixtures": {"radius_mm": 8, "holds": ["ux", "uy", "w"],
                         "grid": strip_grid(INSET_MM, L - INSET_MM, INSET_MM, H - INSET_MM, n, cols, rows)},
            "agents": {"count": n, "regions": strips(INSET_MM, L - INSET_MM, 0, H, n, "stretch")},
            "tasks": [{"kind": "drilling", "name": "flange hole",
                       "line_mm": [[mm(2 * INSET_MM), y], [mm(L - 2 * INSET_MM), y]],
                       "count": p["positions"], "force_N": thrust(p["force_N"], p["tilt_deg"], 90.0), "radius_mm": 3}],
        }
