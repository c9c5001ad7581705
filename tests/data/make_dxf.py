"""Write tests/data/plate_holes.dxf, the drawing tests/test_shapes.py reads (deterministic bytes).

The test plate of tests/conftest.py (400 x 200 mm) drawn as an engineer would in CAD: the outline as
four LINE entities meeting end to end on layer OUTLINE, a 60 x 60 mm window (220..280, 70..130) as
a closed LWPOLYLINE on layer WINDOW, a 15 mm radius bolt hole as a CIRCLE at (120, 100) on layer
HOLES, millimetres in the header ($INSUNITS = 4), and a TEXT note on layer NOTES (which a case reads
past with ``layers``). Run: ``.venv/bin/python tests/data/make_dxf.py``.
"""

from __future__ import annotations

from pathlib import Path

import ezdxf
from ezdxf import units

OUT = Path(__file__).with_name("plate_holes.dxf")
CORNERS = [(0, 0), (400, 0), (400, 200), (0, 200)]
WINDOW = [(220, 70), (280, 70), (280, 130), (220, 130)]
HOLE = ((120, 100), 15)


def main() -> None:
    ezdxf.options.write_fixed_meta_data_for_testing = True  # no time stamps or random GUIDs
    doc = ezdxf.new("R2010", units=units.MM)
    msp = doc.modelspace()
    for a, b in zip(CORNERS, CORNERS[1:] + CORNERS[:1]):
        msp.add_line(a, b, dxfattribs={"layer": "OUTLINE"})
    msp.add_lwpolyline(WINDOW, close=True, dxfattribs={"layer": "WINDOW"})
    msp.add_circle(HOLE[0], HOLE[1], dxfattribs={"layer": "HOLES"})
    msp.add_text("test plate, mm", dxfattribs={"layer": "NOTES", "insert": (10, 210)})
    doc.saveas(OUT)


if __name__ == "__main__":
    main()
