"""An SVG of a corpus document (:func:`edge.evaluation.corpus.corpus_document`), written by hand (no plotting
library): one panel per metric, per variant (and "all") the pooled value as a point with its 95 % interval as a
bar; the ``dev`` part in blue circles, ``holdout`` in orange squares beside it. A value without an interval (one
run) is drawn as a hollow point. A surveillance document adds, per part and variant, its summed confusion matrix
(``confusion_by_variant``): counts in cells shaded by their share of the true class's row."""

from __future__ import annotations

import math
from pathlib import Path
from xml.sax.saxutils import escape

COLOURS = {"dev": "#1f77b4", "holdout": "#d95f02"}
PANEL_W_MIN, SLOT_W, PANEL_H, MARGIN_L, MARGIN_T, MARGIN_B = 260, 56, 170, 62, 28, 58
COLUMNS = 2
#: confusion-matrix panels: row-label width, cell width and height, header height (rotated column labels), gap
CM_LABEL_W, CM_CELL_W, CM_CELL_H, CM_HEAD_H, CM_GAP = 78, 34, 18, 62, 24


def _nice_ticks(lo: float, hi: float, n: int = 4) -> list[float]:
    if hi <= lo:
        hi = lo + (abs(lo) or 1.0) * 0.1
        lo = lo - (abs(lo) or 1.0) * 0.1
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = min((s * mag for s in (1, 2, 2.5, 5, 10) if s * mag >= raw), default=10 * mag)
    start = math.floor(lo / step) * step
    ticks = [start]
    while ticks[-1] < hi - 1e-12 * max(1.0, abs(hi)) and len(ticks) < 24:
        ticks.append(round(start + len(ticks) * step, 12))
    return ticks


def _label(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.2e}"


def corpus_svg(doc: dict) -> str:
    """The SVG text for ``doc`` (module doc)."""
    parts = [p for p in ("dev", "holdout") if p in doc["parts"]]
    groups: list[str] = []
    for p in parts:
        for g in doc["parts"][p]["pooled"]["by_variant"]:
            if g not in groups:
                groups.append(g)
    groups.append("all")
    metrics = list(doc["metrics"])
    pw = max(PANEL_W_MIN, MARGIN_L + 20 + SLOT_W * len(groups))
    ph = MARGIN_T + PANEL_H + MARGIN_B
    rows = math.ceil(len(metrics) / COLUMNS)
    width = COLUMNS * pw + 20
    cms = [(p, v, cm) for p in parts for v, cm in (doc["parts"][p].get("confusion_by_variant") or {}).items()]
    cm_rows = _confusion_layout(cms, width)
    height = rows * ph + 50 + sum(h for _, h in cm_rows)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
           f'<rect width="{width}" height="{height}" fill="white"/>',
           f'<text x="10" y="18" font-size="14" font-weight="bold">{escape(doc["corpus"])} ({escape(doc["profile"])}):'
           f' pooled over runs, 95 % cluster-bootstrap intervals</text>']
    lx = 10
    for p in parts:
        n = len(doc["parts"][p]["runs"])
        out.append(f'<circle cx="{lx + 5}" cy="34" r="4" fill="{COLOURS[p]}"/>' if p == "dev" else
                   f'<rect x="{lx + 1}" y="30" width="8" height="8" fill="{COLOURS[p]}"/>')
        out.append(f'<text x="{lx + 14}" y="38">{p} ({n} runs)</text>')
        lx += 120
    for k, m in enumerate(metrics):
        ox, oy = (k % COLUMNS) * pw + 10, (k // COLUMNS) * ph + 50
        unit = doc["metrics"][m].get("unit", "")
        out.append(f'<text x="{ox + MARGIN_L}" y="{oy + 16}" font-weight="bold">{escape(m)}'
                   f'{" (" + escape(unit) + ")" if unit else ""}</text>')
        pts = []  # (group index, part, value, lo, hi)
        for p in parts:
            pooled = doc["parts"][p]["pooled"]
            for gi, g in enumerate(groups):
                rec = (pooled["all"] if g == "all" else pooled["by_variant"].get(g, {})).get(m)
                if not rec or rec.get("value") is None:
                    continue
                lo, hi = rec["ci95"] if rec.get("ci95") else (None, None)
                pts.append((gi, p, rec["value"], lo, hi))
        x0, y0, w, h = ox + MARGIN_L, oy + MARGIN_T, pw - MARGIN_L - 20, PANEL_H
        out.append(f'<rect x="{x0}" y="{y0}" width="{w}" height="{h}" fill="none" stroke="#999"/>')
        if not pts:
            out.append(f'<text x="{x0 + 10}" y="{y0 + h / 2}" fill="#666">no data</text>')
        else:
            vals = [v for _, _, v, lo, hi in pts for v in (v, lo, hi) if v is not None]
            ticks = _nice_ticks(min(vals), max(vals))
            lo_ax, hi_ax = ticks[0], ticks[-1]

            def ypix(v: float) -> float:
                return y0 + h - (v - lo_ax) / (hi_ax - lo_ax) * h

            for t in ticks:
                yy = ypix(t)
                out.append(f'<line x1="{x0}" x2="{x0 + w}" y1="{yy:.1f}" y2="{yy:.1f}" stroke="#eee"/>')
                out.append(f'<text x="{x0 - 4}" y="{yy + 4:.1f}" text-anchor="end">{_label(t)}</text>')
            slot = w / len(groups)
            for gi, p, v, lo, hi in pts:
                off = (-0.15 if p == "dev" else 0.15) * slot if len(parts) > 1 else 0.0
                xx = x0 + (gi + 0.5) * slot + off
                c = COLOURS[p]
                if lo is not None:
                    out.append(f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{ypix(lo):.1f}" y2="{ypix(hi):.1f}" '
                               f'stroke="{c}" stroke-width="1.5"/>')
                    for yy in (ypix(lo), ypix(hi)):
                        out.append(f'<line x1="{xx - 4:.1f}" x2="{xx + 4:.1f}" y1="{yy:.1f}" y2="{yy:.1f}" stroke="{c}"/>')
                fill = c if lo is not None else "white"
                title = f"<title>{escape(p)} {escape(groups[gi])}: {v:.6g}" + (
                    f" [{lo:.6g}, {hi:.6g}]" if lo is not None else " (one run: no interval)") + "</title>"
                if p == "dev":
                    out.append(f'<circle cx="{xx:.1f}" cy="{ypix(v):.1f}" r="3.5" fill="{fill}" stroke="{c}">'
                               f'{title}</circle>')
                else:
                    out.append(f'<rect x="{xx - 3.5:.1f}" y="{ypix(v) - 3.5:.1f}" width="7" height="7" fill="{fill}" '
                               f'stroke="{c}">{title}</rect>')
        for gi, g in enumerate(groups):
            xx = x0 + (gi + 0.5) * (w / len(groups))
            out.append(f'<text x="{xx:.1f}" y="{y0 + h + 12}" text-anchor="end" '
                       f'transform="rotate(-35 {xx:.1f} {y0 + h + 12})">{escape(g)}</text>')
    y = rows * ph + 50
    for row, h in cm_rows:
        x = 10
        for p, v, cm in row:
            out += _confusion_svg(p, v, cm, x, y)
            x += _confusion_width(cm) + CM_GAP
        y += h
    out.append("</svg>")
    return "\n".join(out) + "\n"


def _confusion_width(cm: dict) -> int:
    return CM_LABEL_W + CM_CELL_W * len(cm["columns"])


def _confusion_layout(cms: list, width: int) -> list[tuple[list, int]]:
    """The confusion panels in rows that fit ``width``: ``[(panels, row height), ...]``."""
    rows: list[tuple[list, int]] = []
    cur: list = []
    used = 10
    for item in cms:
        w = _confusion_width(item[2]) + CM_GAP
        if cur and used + w > width:
            rows.append((cur, _row_height(cur)))
            cur, used = [], 10
        cur.append(item)
        used += w
    if cur:
        rows.append((cur, _row_height(cur)))
    return rows


def _row_height(row: list) -> int:
    return 20 + CM_HEAD_H + CM_CELL_H * max(len(cm["labels"]) for _, _, cm in row) + CM_GAP


def _confusion_svg(part: str, variant: str, cm: dict, x: float, y: float) -> list[str]:
    """One variant's summed confusion matrix at (x, y): rows true class, columns predicted class and missed."""
    out = [f'<text x="{x}" y="{y + 14}" font-weight="bold">confusion, {escape(variant)} '
           f'<tspan fill="{COLOURS.get(part, "#000")}">({escape(part)})</tspan></text>']
    gx, gy = x + CM_LABEL_W, y + 20 + CM_HEAD_H
    for j, c in enumerate(cm["columns"]):
        cx = gx + (j + 0.5) * CM_CELL_W
        out.append(f'<text x="{cx:.1f}" y="{gy - 4}" transform="rotate(-50 {cx:.1f} {gy - 4})">{escape(str(c))}</text>')
    for i, (lab, row) in enumerate(zip(cm["labels"], cm["all"])):
        yy = gy + i * CM_CELL_H
        out.append(f'<text x="{gx - 4}" y="{yy + 13}" text-anchor="end">{escape(str(lab))}</text>')
        total = sum(row)
        for j, n in enumerate(row):
            share = n / total if total else 0.0
            hit = j < len(cm["labels"]) and cm["columns"][j] == lab
            rgb = (31, 119, 180) if hit else (214, 39, 40)  # right: blue; wrong or missed: red
            fill = "#%02x%02x%02x" % tuple(round(255 - share * (255 - c)) for c in rgb)
            out.append(f'<rect x="{gx + j * CM_CELL_W}" y="{yy}" width="{CM_CELL_W}" height="{CM_CELL_H}" '
                       f'fill="{fill}" stroke="#ccc"><title>{escape(str(lab))} -> {escape(str(cm["columns"][j]))}: '
                       f'{n} of {total}</title></rect>')
            ink = ' fill="white"' if share > 0.6 else ""
            out.append(f'<text x="{gx + (j + 0.5) * CM_CELL_W:.1f}" y="{yy + 13}" text-anchor="middle"{ink}>{n}</text>')
    return out


def write_corpus_svg(doc: dict, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(corpus_svg(doc), encoding="utf-8")
    return p
