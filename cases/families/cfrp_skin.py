"""CFRP skins: the skin panel's outline, supports and robots (:mod:`.skin_panel`) in a carbon-fibre
laminate, a symmetric quasi-isotropic [45/-45/0/90]ns or cross-ply [0/90]ns layup of a ply material
from docs/materials.md, padded up around the first cut-out where its rivet ring is drilled: a
laminate's stiffness differs from a metal's in kind (anisotropic, varying by region), not only in size,
which makes it the natural family to keep out of training (docs/families.md)."""

from __future__ import annotations

from fixbench.cases.families.base import Choice, Span, mm, rounded_box
from fixbench.cases.families.skin_panel import SkinPanel

#: ply angles of one repeat of each layup (the lower half of a symmetric stack)
LAYUPS = {"quasi-isotropic": [45, -45, 0, 90], "cross-ply": [0, 90]}
#: cured ply thickness (mm), the catalog's CFRP parts' (docs/materials.md#ply-materials)
PLY_MM = 0.125
#: how far (mm) a pad-up reaches past the rivet ring
PAD_MARGIN_MM = 15


class CfrpSkin(SkinPanel):
    name = "cfrp_skin"
    summary = "the skin panel in a symmetric CFRP layup, padded up around the rivet ring of its first cut-out"
    ranges = {
        **{k: v for k, v in SkinPanel.ranges.items() if k not in ("material", "thickness_mm", "drilling")},
        "ply": Choice(("T300/5208", "AS4/3501-6")),
        "layup": Choice(tuple(LAYUPS)),
        "repeat": Span(2, 5, integer=True),
        "pad_repeat": Span(1, 3, integer=True),
        "drilling": Choice(("ring",)),
    }

    def room(self, p: dict) -> tuple[float, float]:
        w, h = super().room(p)
        return w + 2 * PAD_MARGIN_MM, h + 2 * PAD_MARGIN_MM

    def tables(self, p: dict, name: str) -> dict:
        angles = LAYUPS[p["layup"]]
        plies = 2 * len(angles) * p["repeat"]
        t = super().tables({**p, "material": "layup", "thickness_mm": mm(plies * PLY_MM)}, name)
        t["case"]["description"] = (f"Generated CFRP skin ({self.name} family), {p['layup']} {p['ply']}, "
                                    f"{p['cutouts']} cut-out(s), {p['positions']} rivets")
        t["material"] = {"name": "layup", "symmetric": True,
                         "plies": [{"ply": p["ply"], "angles_deg": angles, "repeat": p["repeat"],
                                    "thickness_mm": PLY_MM}]}
        hole = t["geometry"]["shapes"][1]
        x0, y0, x1, y1 = _bounds(hole)
        reach = p["ring_offset_mm"] + PAD_MARGIN_MM
        t["regions"] = [{"name": "pad-up around the rivet ring",
                         "rectangle_mm": rounded_box((x0 + x1) / 2, (y0 + y1) / 2, x1 - x0 + 2 * reach,
                                                     y1 - y0 + 2 * reach),
                         "corner_radius_mm": mm(reach), "symmetric": True,
                         "plies": [{"ply": p["ply"], "angles_deg": angles, "repeat": p["repeat"] + p["pad_repeat"],
                                    "thickness_mm": PLY_MM}]}]
        return t


def _bounds(shape: dict) -> tuple[float, float, float, float]:
    """The bounding box (mm) of a cut-out table of :meth:`SkinPanel.cutouts`."""
    if "rectangle_mm" in shape:
        return tuple(shape["rectangle_mm"])
    if "ellipse_mm" in shape:
        cx, cy, a, b = shape["ellipse_mm"]
        return cx - a, cy - b, cx + a, cy + b
    x0, y0, x1, y1, width = shape["slot_mm"]
    r = width / 2
    return min(x0, x1) - r, min(y0, y1) - r, max(x0, x1) + r, max(y0, y1) + r
