"""Blades: a tapered, swept blade plate clamped at its root, loaded by pressure over one spanwise band
at a time (one task a band: the load of a stage of the blade's operation), while 3-5 robots, one a
stretch of the span, hold it."""

from __future__ import annotations

from fixbench.cases.families.base import Choice, Family, Span, columns_rows, mm, strip_grid, strips

#: the candidate grid's inset (mm) from the blade's root and tip, and from its widest extent
INSET_MM = 10


class Blade(Family):
    name = "blade"
    summary = "tapered, swept blade clamped at its root, pressure over one spanwise band a task"
    ranges = {
        "material": Choice(("aluminium", "titanium", "steel")),
        "thickness_mm": Span(3.0, 8.0),
        "length_mm": Span(250, 600),
        "root_width_mm": Span(80, 160),
        "taper": Span(0.5, 1.0),  # tip width over root width
        "sweep_mm": Span(-60, 60),  # the tip's centre, across the span from the root's
        "bands": Span(4, 8, integer=True),
        "pressure_kPa": Span(2, 10),
        "agents": Span(3, 5, integer=True),
        "candidates_per_agent": Span(10, 30, integer=True),
    }

    def tables(self, p: dict, name: str) -> dict:
        L, r, n = p["length_mm"], p["root_width_mm"], p["agents"]
        tip, s = r * p["taper"], p["sweep_mm"]
        outline = [[0, mm(-r / 2)], [L, mm(s - tip / 2)], [L, mm(s + tip / 2)], [0, mm(r / 2)]]
        lo, hi = min(-r / 2, s - tip / 2), max(r / 2, s + tip / 2)
        per_agent = min(p["candidates_per_agent"], int((2e5) ** (1 / n)))
        cols, rows = columns_rows(n, per_agent, (L - 2 * INSET_MM) / n / (hi - lo))
        bands, tasks = p["bands"], []
        for i in range(bands):
            a, b = mm(L * i / bands), mm(L * (i + 1) / bands)
            band = [[a, mm(lo - 1)], [b, mm(lo - 1)], [b, mm(hi + 1)], [a, mm(hi + 1)]]
            tasks.append({"kind": "loads", "name": f"band {i}", "features": [round((i + 0.5) / bands, 4)],
                          "loads": [{"kind": "pressure", "pressure_kPa": p["pressure_kPa"], "region_mm": band}]})
        return {
            "case": {"description": f"Generated blade ({self.name} family), pressure over {bands} bands", "part": name},
            "material": {"name": p["material"]},
            "geometry": {"thickness_mm": p["thickness_mm"], "shapes": [{"polygon_mm": outline}]},
            "mesh": {"size_mm": mm(min(max(tip / 6, 8), 20))},
            "supports": [{"name": "root", "segment_mm": [outline[0], outline[3]], "kind": "clamped"}],
            "fixtures": {"radius_mm": 8, "holds": ["w"],
                         "grid": strip_grid(INSET_MM, L - INSET_MM, lo, hi, n, cols, rows)},
            "agents": {"count": n, "regions": strips(INSET_MM, L - INSET_MM, lo, hi, n, "stretch")},
            "tasks": tasks,
        }
