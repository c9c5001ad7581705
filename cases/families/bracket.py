"""Flange and bracket plates: a rectangular plate with a row of load holes, its base clamped along its
edge or bolted at two or three points, drilled on a ring around its first hole or along its top
edge while 3-4 robots, one a strip of the plate, hold it."""

from __future__ import annotations

from fixbench.cases.families.base import Choice, Family, FamilyError, Span, columns_rows, mm, strip_grid, strips, thrust

#: the candidate grid's inset (mm) from the plate's edges, and the top rivet line's
INSET_MM = 12
#: a bolt's pad radius (mm)
BOLT_MM = 8
#: plate (mm) left between a hole's rivet ring and the next ring or an edge, at least
LAND_MM = 10


class Bracket(Family):
    name = "bracket"
    summary = "flange plate with 1-3 holes, base clamped or bolted, drilled around a hole or along its top"
    ranges = {
        "material": Choice(("aluminium", "titanium", "steel")),
        "thickness_mm": Span(3.0, 10.0),
        "width_mm": Span(150, 350),
        "height_mm": Span(120, 300),
        "holes": Span(1, 3, integer=True),
        "hole_diameter_mm": Span(10, 30),
        "hole_height_ratio": Span(0.5, 0.75),  # the holes' centre line, a share of the height
        "base": Choice(("clamped edge", "bolted")),
        "bolts": Span(2, 3, integer=True),
        "drilling": Choice(("ring", "top edge")),
        "ring_offset_mm": Span(8, 15),
        "positions": Span(6, 10, integer=True),
        "force_N": Span(100, 400),
        "tilt_deg": Span(0, 20),
        "agents": Span(3, 4, integer=True),
        "candidates_per_agent": Span(10, 30, integer=True),
    }

    @staticmethod
    def ring(p: dict) -> float:
        """Width (mm) a hole, its rivet ring and its land take."""
        return p["hole_diameter_mm"] + 2 * (p["ring_offset_mm"] + LAND_MM)

    def check_ranges(self) -> None:
        need = self.low("holes") * self.ring({k: self.low(k) for k in ("hole_diameter_mm", "ring_offset_mm")})
        if need > self.high("width_mm"):
            raise FamilyError("--set hole_diameter_mm", f"{self.low('holes'):g} hole(s) of at least "
                              f"{self.low('hole_diameter_mm'):g} mm with their rings ({need:g} mm) never fit a plate "
                              f"at most {self.high('width_mm'):g} mm wide")

    def misfit(self, p: dict) -> str | None:
        ring, W, H = self.ring(p), p["width_mm"], p["height_mm"]
        if p["holes"] * ring > W:
            return f"{p['holes']} hole(s) with their rings need {p['holes'] * ring:.1f} mm of a {W:g} mm plate"
        if p["hole_height_ratio"] * H + ring / 2 > H:
            return f"the holes' rings reach past the top of a {H:g} mm plate"
        return None

    def tables(self, p: dict, name: str) -> dict:
        W, H, n = p["width_mm"], p["height_mm"], p["agents"]
        pitch, y = W / p["holes"], p["hole_height_ratio"] * H
        holes = [{"op": "difference", "circle_mm": [mm(pitch * (i + 0.5)), mm(y), mm(p["hole_diameter_mm"] / 2)]}
                 for i in range(p["holes"])]
        if p["base"] == "clamped edge":
            supports = [{"name": "base", "segment_mm": [[0, 0], [W, 0]], "kind": "clamped"}]
        else:
            supports = [{"name": f"bolt {i}", "point_mm": [mm(W * (i + 0.5) / p["bolts"]), INSET_MM],
                         "radius_mm": BOLT_MM, "kind": "clamped"} for i in range(p["bolts"])]
        refine = [{"near": "tasks", "size_mm": 5, "width_mm": 6}]
        if p["base"] == "bolted":  # a bolt's pad holds the nodes within its radius: a few elements across it
            refine.append({"near": "points", "polyline_mm": [[0, INSET_MM], [W, INSET_MM]], "size_mm": 3,
                           "width_mm": BOLT_MM})
        per_agent = min(p["candidates_per_agent"], int((2e5) ** (1 / n)))
        y0 = 2 * INSET_MM  # pads stand clear of the base
        cols, rows = columns_rows(n, per_agent, (W - 2 * INSET_MM) / n / (H - INSET_MM - y0))
        task = {"kind": "drilling", "name": "rivet", "count": p["positions"],
                "force_N": thrust(p["force_N"], p["tilt_deg"], 90.0), "radius_mm": 3}
        if p["drilling"] == "ring":
            task |= {"along": "hole 0", "offset_mm": p["ring_offset_mm"]}
        else:
            task["line_mm"] = [[2 * INSET_MM, mm(H - INSET_MM)], [mm(W - 2 * INSET_MM), mm(H - INSET_MM)]]
        return {
            "case": {"description": f"Generated bracket plate ({self.name} family), {p['holes']} hole(s), "
                                    f"{p['base']} base, {p['positions']} rivets", "part": name},
            "material": {"name": p["material"]},
            "geometry": {"thickness_mm": p["thickness_mm"], "shapes": [{"rectangle_mm": [0, 0, W, H]}, *holes]},
            "mesh": {"size_mm": mm(min(max(min(W, H) / 8, 12), 30)), "refine": refine},
            "supports": supports,
            "fixtures": {"radius_mm": 8, "holds": ["ux", "uy", "w"],
                         "grid": strip_grid(INSET_MM, W - INSET_MM, y0, H - INSET_MM, n, cols, rows)},
            "agents": {"count": n, "regions": strips(INSET_MM, W - INSET_MM, y0, H - INSET_MM, n)},
            "tasks": [task],
        }
