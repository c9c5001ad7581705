"""Skin panels: a rectangular metal skin with one or two cut-outs (rounded rectangles, ellipses or
slots) at drawn places, fixed along one or two edges (a spar flange, a frame) or an edge and a jig post,
drilled on a rivet ring around its first cut-out or on a rivet line along its free top edge while 3-5
robots, one a strip of the panel, hold it. The access panel of docs/new-part.md is one of them."""

from __future__ import annotations

from fixbench.cases.families.base import (
    Choice,
    Family,
    FamilyError,
    Span,
    columns_rows,
    mm,
    rounded_box,
    strip_grid,
    strips,
    thrust,
)

#: room (mm) kept between a cut-out's rivet ring and the panel's edge or the next cut-out's cell
MARGIN_MM = 30
#: inset (mm) of the candidate grid and of a rivet line from the panel's edges
INSET_MM = 20


class SkinPanel(Family):
    name = "skin_panel"
    summary = "rectangular skin, 1-2 cut-outs, clamped edge(s) or edge + post, rivet ring or edge line"
    ranges = {
        "material": Choice(("aluminium", "titanium", "steel")),
        "thickness_mm": Span(2.0, 6.0),
        "width_mm": Span(400, 900),
        "height_mm": Span(250, 600),
        "cutouts": Span(1, 2, integer=True),
        "cutout_shape": Choice(("rounded", "ellipse", "slot")),
        "cutout_width_mm": Span(60, 200),
        "cutout_height_mm": Span(40, 150),
        "cutout_shift": Span(-0.5, 0.5),  # where in its free room a cut-out sits (0: centred)
        "support": Choice(("left edge", "left and right edges", "left edge and a post")),
        "drilling": Choice(("ring", "top edge")),
        "ring_offset_mm": Span(15, 25),
        "positions": Span(6, 10, integer=True),
        "force_N": Span(100, 300),
        "tilt_deg": Span(0, 20),
        "agents": Span(3, 5, integer=True),
        "candidates_per_agent": Span(10, 30, integer=True),
    }

    def room(self, p: dict) -> tuple[float, float]:
        """Width and height a cut-out and its rivet ring need, with the margin."""
        ring = 2 * (p["ring_offset_mm"] + MARGIN_MM)
        return p["cutout_width_mm"] + ring, p["cutout_height_mm"] + ring

    def check_ranges(self) -> None:
        smallest = {k: self.low(k) for k in ("cutout_width_mm", "cutout_height_mm", "ring_offset_mm")}
        need_w, need_h = self.room(smallest)
        if need_w > self.high("width_mm") / self.low("cutouts"):
            raise FamilyError("--set cutout_width_mm", f"a cut-out at least {self.low('cutout_width_mm'):g} mm wide "
                              f"with its rivet ring and margin ({need_w:g} mm) never fits a panel at most "
                              f"{self.high('width_mm'):g} mm wide with {self.low('cutouts'):g} cut-out(s)")
        if need_h > self.high("height_mm"):
            raise FamilyError("--set cutout_height_mm", f"a cut-out at least {self.low('cutout_height_mm'):g} mm "
                              f"high with its rivet ring and margin ({need_h:g} mm) never fits a panel at most "
                              f"{self.high('height_mm'):g} mm high")

    def misfit(self, p: dict) -> str | None:
        need_w, need_h = self.room(p)
        cell = p["width_mm"] / p["cutouts"]
        if need_w > cell or need_h > p["height_mm"]:
            return (f"cut-out {p['cutout_width_mm']:g} x {p['cutout_height_mm']:g} mm needs {need_w:.1f} x "
                    f"{need_h:.1f} mm with its rivet ring and margins, its cell of the panel is {cell:.1f} x "
                    f"{p['height_mm']:g} mm")
        return None

    def cutouts(self, p: dict) -> list[dict]:
        """The cut-outs' shape tables, one centred in each equal cell across the panel, moved by the
        drawn shift within the room the cell leaves."""
        w, h, W, H = p["cutout_width_mm"], p["cutout_height_mm"], p["width_mm"], p["height_mm"]
        need_w, need_h = self.room(p)
        cell = W / p["cutouts"]
        out = []
        for i in range(p["cutouts"]):
            cx = cell * (i + 0.5) + p["cutout_shift"] * (cell - need_w)
            cy = H / 2 + p["cutout_shift"] * (H - need_h)
            if p["cutout_shape"] == "rounded":
                shape = {"rectangle_mm": rounded_box(cx, cy, w, h), "corner_radius_mm": mm(min(w, h) / 4)}
            elif p["cutout_shape"] == "ellipse":
                shape = {"ellipse_mm": [mm(cx), mm(cy), mm(w / 2), mm(h / 2)]}
            else:  # a stadium along its longer side
                half = (max(w, h) - min(w, h)) / 2
                dx, dy = (half, 0) if w >= h else (0, half)
                shape = {"slot_mm": [mm(cx - dx), mm(cy - dy), mm(cx + dx), mm(cy + dy), mm(min(w, h))]}
            out.append({"op": "difference", **shape})
        return out

    def tables(self, p: dict, name: str) -> dict:
        W, H, n = p["width_mm"], p["height_mm"], p["agents"]
        supports = [{"name": "spar flange", "segment_mm": [[0, 0], [0, H]], "kind": "clamped"}]
        if p["support"] == "left and right edges":
            supports.append({"name": "frame", "segment_mm": [[W, 0], [W, H]], "kind": "clamped"})
        elif p["support"] == "left edge and a post":
            supports.append({"name": "jig post", "point_mm": [mm(W - INSET_MM), mm(H / 2)], "radius_mm": 10,
                             "kind": "simple"})
        per_agent = min(p["candidates_per_agent"], int((2e5) ** (1 / n)))
        cols, rows = columns_rows(n, per_agent, (W - 2 * INSET_MM) / n / (H - 2 * INSET_MM))
        task = {"kind": "drilling", "name": "rivet", "count": p["positions"],
                "force_N": thrust(p["force_N"], p["tilt_deg"]), "radius_mm": 3}
        if p["drilling"] == "ring":
            task |= {"along": "hole 0", "offset_mm": p["ring_offset_mm"]}
        else:
            y = mm(H - INSET_MM)
            task["line_mm"] = [[MARGIN_MM + INSET_MM, y], [mm(W - MARGIN_MM - INSET_MM), y]]
        size = mm(min(max(min(W, H) / 10, 20), 40))
        return {
            "case": {"description": f"Generated skin panel ({self.name} family), {p['cutouts']} cut-out(s), "
                                    f"{p['positions']} rivets", "part": name},
            "material": {"name": p["material"]},
            "geometry": {"thickness_mm": p["thickness_mm"],
                         "shapes": [{"rectangle_mm": [0, 0, W, H]}, *self.cutouts(p)]},
            "mesh": {"size_mm": size, "refine": [{"near": "tasks", "size_mm": 6, "width_mm": 6}]},
            "supports": supports,
            "fixtures": {"radius_mm": 8, "holds": ["ux", "uy", "w"],
                         "grid": strip_grid(INSET_MM, W - INSET_MM, INSET_MM, H - INSET_MM, n, cols, rows)},
            "agents": {"count": n, "regions": strips(INSET_MM, W - INSET_MM, 0, H, n)},
            "tasks": [task],
        }
