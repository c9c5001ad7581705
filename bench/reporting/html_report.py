"""``report/index.html``: the report as one self-contained web page.

What ``fixbench report`` wrote into ``report.md`` (tables and figure captions), rendered by
markdown-it-py (CommonMark with GFM tables), every figure embedded as a PNG data URI, and the run's
provenance: the distinct records of its rows (fixbench, libraries, BLAS, CPU, threads, switches;
:mod:`fixbench.bench.running.provenance`) with the cells of each, and its ``matrix.toml``. No script and no
request outside the file: it opens offline, sent on its own. The same report folder gives the same
bytes.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

import pandas as pd
from markdown_it import MarkdownIt

from fixbench.bench.records.store import json_text

STYLE = """body{font-family:system-ui,sans-serif;max-width:72rem;margin:2rem auto;padding:0 1rem;line-height:1.45}
table{border-collapse:collapse;margin:1rem 0;font-size:.85rem}th,td{border:1px solid #ccc;padding:.2rem .5rem}
th{background:#f2f2f2}td{text-align:right}td:first-child{text-align:left}img{max-width:100%}
pre{background:#f6f6f6;padding:.6rem;overflow-x:auto;font-size:.8rem}"""


def write_html(report: Path, rows: pd.DataFrame, matrices: list[Path]) -> Path:
    """Write ``report/index.html`` from ``report/report.md`` and its figures, ``rows`` (their
    ``provenance`` column) and the run's ``matrices`` (those that exist); returns its path."""
    md = MarkdownIt("commonmark").enable("table")
    tokens = md.parse((report / "report.md").read_text(encoding="utf-8"))
    for tok in tokens:
        for child in tok.children or ():
            src = child.attrGet("src") if child.type == "image" else None
            if src and src.endswith(".png") and (report / src).is_file():
                child.attrSet("src", "data:image/png;base64," + base64.b64encode((report / src).read_bytes()).decode())
    title = next((tokens[i + 1].content for i, t in enumerate(tokens) if t.tag == "h1"), "fixbench report")
    body = md.renderer.render(tokens, md.options, {})
    page = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>", body,
            "<h2>Provenance</h2>", provenance_html(rows)]
    for path in (p for p in matrices if p.is_file()):
        page += [f"<h3>{html.escape(path.parent.name)}/{html.escape(path.name)}</h3>",
                 f"<pre>{html.escape(path.read_text(encoding='utf-8'))}</pre>"]
    out = report / "index.html"
    out.write_text("\n".join(page + ["</body></html>", ""]), encoding="utf-8")
    return out


def provenance_html(rows: pd.DataFrame) -> str:
    """The distinct provenance records of ``rows`` side by side (one column a record, with its cells),
    or why there are none."""
    recs = [v for v in rows.get("provenance", pd.Series(dtype=object)) if isinstance(v, dict)]
    missing = len(rows) - len(recs)
    note = (f"<p>Not recorded for {missing} cells (made before rows carried their provenance).</p>"
            if missing else "")
    if not recs:
        return note
    texts = [json_text(r) for r in recs]  # a record's canonical text: what records are grouped on
    first = dict(zip(reversed(texts), reversed(recs)))  # each record as its first row holds it
    counts = pd.Series(texts).value_counts(sort=False)
    table = pd.DataFrame({f"record {i + 1} ({n} cells)": _flat(first[t]) for i, (t, n) in
                          enumerate(counts.items())})
    return table.fillna("-").to_html(escape=True, border=0) + note


def _flat(record: dict, prefix: str = "") -> dict[str, str]:
    """A provenance record as {dotted key: text} (its libraries and environment switches flattened)."""
    out = {}
    for k, v in record.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = str(v)
    return out
