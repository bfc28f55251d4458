"""A self-contained HTML report: the numbers of report.json in tables, pictures and plots inline.

Images (PNG, JPEG, GIF, SVG) and movies (MP4, WebM) are embedded as base64 data URIs, so the one
``report.html`` file can be mailed or attached to a ticket. Per-frame lists are summarised
(count, mean, min, max) and drawn as a small inline sparkline; dicts of scalars (per muscle,
status blocks) become their own tables.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["HEADLINE", "write_html_report"]

_MIME = {
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".gif": "image/gif",
    ".svg": "image/svg+xml",
    ".mp4": "video/mp4",
    ".webm": "video/webm",
}

# report.json keys shown first, as large numbers (docs/design.md, "Takes"), when present and scalar.
HEADLINE = {
    "marker_rms_mm_mean": ("marker RMS", "mm"),
    "marker_max_mm": ("marker max", "mm"),
    "activation_rms_error": ("activation RMS error", ""),
    "jaw_angle_error_deg": ("jaw angle error", "deg"),
    "seconds_per_frame_median": ("time per frame", "s"),
    "inverted_elements": ("inverted elements", ""),
    "frames": ("frames", ""),
}

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1200px;
color:#222;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em} h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
.meta{color:#777;font-size:.9em}
table{border-collapse:collapse;margin:.5em 0;font-size:.92em}
td,th{border:1px solid #ddd;padding:.28em .6em;text-align:left;vertical-align:top}
th{background:#f4f4f4} td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{display:inline-block;margin:.6em;vertical-align:top} figcaption{font-size:.85em;color:#555;text-align:center}
img,video{max-width:100%;border:1px solid #eee}
.cards{display:flex;flex-wrap:wrap;gap:.8em;margin:.8em 0}
.card{border:1px solid #ddd;border-radius:6px;padding:.5em .9em;min-width:8em}
.card .v{font-size:1.5em;font-variant-numeric:tabular-nums} .card .k{color:#666;font-size:.85em}
"""


def _fmt(v) -> str:
    if isinstance(v, bool) or v is None:
        return html.escape(str(v))
    if isinstance(v, int):
        return f"{v:d}"
    if isinstance(v, float):
        if math.isnan(v) or math.isinf(v):
            return str(v)
        return f"{v:.4g}"
    return html.escape(str(v))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _sparkline(values: list[float], width: int = 160, height: int = 28) -> str:
    vals = [float(v) for v in values if _is_number(v) and math.isfinite(float(v))]
    if len(vals) < 2:
        return ""
    lo, hi = min(vals), max(vals)
    span = hi - lo or 1.0
    n = len(vals)
    pts = " ".join(
        f"{i * (width - 2) / (n - 1) + 1:.1f},{height - 1 - (v - lo) / span * (height - 2):.1f}"
        for i, v in enumerate(vals)
    )
    return (
        f'<svg width="{width}" height="{height}" viewBox="0 0 {width} {height}">'
        f'<polyline fill="none" stroke="#1f77b4" stroke-width="1.3" points="{pts}"/></svg>'
    )


def _value_cell(v) -> str:
    if isinstance(v, list) and v and all(_is_number(x) for x in v):
        finite = [float(x) for x in v if math.isfinite(float(x))]
        if not finite:
            return f"<td>{len(v)} values, none finite</td>"
        mean = sum(finite) / len(finite)
        return (
            f'<td class="num">n={len(v)}, mean {_fmt(mean)}, min {_fmt(min(finite))}, '
            f"max {_fmt(max(finite))}<br>{_sparkline(v)}</td>"
        )
    if _is_number(v):
        return f'<td class="num">{_fmt(v)}</td>'
    if isinstance(v, (list, dict)):
        text = json.dumps(v)
        return f"<td><code>{html.escape(text[:400] + ('...' if len(text) > 400 else ''))}</code></td>"
    return f"<td>{_fmt(v)}</td>"


def _embed(path: Path, caption: str) -> str:
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise ValueError(f"cannot embed {path.name}: unknown type (known: {', '.join(sorted(_MIME))})")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    cap = f"<figcaption>{html.escape(caption)}</figcaption>"
    if mime.startswith("video/"):
        return f'<figure><video controls loop muted playsinline src="data:{mime};base64,{data}"></video>{cap}</figure>'
    return f'<figure><img alt="{html.escape(caption)}" src="data:{mime};base64,{data}">{cap}</figure>'


def write_html_report(
    out_dir: str | Path,
    report: dict,
    images: dict[str, str | Path],
    *,
    title: str = "wface report",
    filename: str = "report.html",
) -> Path:
    """Write ``out_dir/report.html``: report.json's numbers in tables, images and movies embedded.

    Args:
        out_dir: directory (created if needed); usually the one holding report.json.
        report: the report.json dict (keys as in docs/design.md, "Takes"). Headline numbers
            (``HEADLINE``) are shown first as cards; scalars go into the main table; lists of
            numbers (per frame) are summarised with a sparkline; dicts of scalars (e.g.
            ``muscle_identifiability``, a status block) become tables of their own; anything
            deeper is shown as JSON.
        images: caption -> file (PNG/JPEG/GIF/SVG, MP4/WebM), embedded in the given order.
        title: page title.
        filename: name of the HTML file.

    Returns:
        The path of the HTML file.

    Raises:
        FileNotFoundError: an image file does not exist (named in the message).
        ValueError: an image has a type that cannot be embedded.
    """
    out_dir = Path(out_dir)
    if not isinstance(report, dict):
        raise TypeError(f"report must be a dict (report.json contents), got {type(report).__name__}")
    paths = {}
    for caption, p in images.items():
        p = Path(p)
        if not p.is_absolute() and not p.exists():
            p = Path(os.path.normpath(out_dir / p))  # relative to out_dir, like links in the page would be
        if not p.exists():
            raise FileNotFoundError(f"report image {caption!r} not found: {p}")
        paths[str(caption)] = p

    rows, sub_tables = [], []
    for key, v in report.items():
        if isinstance(v, dict) and v and all(isinstance(x, (int, float, str, bool)) or x is None for x in v.values()):
            body = "".join(f"<tr><td>{html.escape(str(k))}</td>{_value_cell(x)}</tr>" for k, x in v.items())
            sub_tables.append(
                f"<h2>{html.escape(str(key))}</h2><table><tr><th>name</th><th>value</th></tr>{body}</table>"
            )
        else:
            rows.append(f"<tr><th>{html.escape(str(key))}</th>{_value_cell(v)}</tr>")
    cards = "".join(
        f'<div class="card"><div class="v">{_fmt(report[key])} {unit}</div><div class="k">{label}</div></div>'
        for key, (label, unit) in HEADLINE.items()
        if key in report and _is_number(report[key])
    )
    figures = "".join(_embed(p, c) for c, p in paths.items())
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    doc = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
        f'<h1>{html.escape(title)}</h1><p class="meta">generated {stamp}</p>'
        + (f'<div class="cards">{cards}</div>' if cards else "")
        + (f"<h2>Pictures and plots</h2>{figures}" if figures else "")
        + f"<h2>Numbers</h2><table>{''.join(rows)}</table>"
        + "".join(sub_tables)
        + "</body></html>\n"
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / filename
    out.write_text(doc, encoding="utf-8")
    return out
