"""A self-contained HTML report: the numbers of report.json in tables, pictures and plots inline.

Images (PNG, JPEG, GIF, SVG) and movies (MP4, WebM) are embedded as base64 data URIs, so the one
``report.html`` file can be mailed or attached to a ticket. Per-frame lists are summarised
(count, mean, min, max) and drawn as a small inline sparkline; dicts of scalars (per muscle,
status blocks) become their own tables, and so do dicts of records with the same keys (the
per-marker table; a key a fuller table already shows, ``_SUPERSEDED``, stays in report.json only).

The headline cards show the error a person should read first (``headline_cards``): on a synthetic
take the tracked markers against the clean truth (``truth_marker_rms_mm``); on a real take the
error over every fitted sample, outliers included (``marker_rms_mm_mean``), then the held-out
markers', then the inlier error with the share of fitted samples set aside as outliers beside it.
On a take the face cannot follow the inlier error mostly measures the cut-off, so it does not lead.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["HEADLINE", "headline_cards", "write_html_report"]

_MIME = {
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".gif": "image/gif",
    ".svg": "image/svg+xml",
    ".mp4": "video/mp4",
    ".webm": "video/webm",
}

# report.json keys shown first, as large numbers (docs/design.md, "Takes"), when present and scalar;
# the marker error card comes first (``headline_cards``).
HEADLINE = {
    "activation_rms_error": ("activation RMS error (observable muscles)", ""),
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
code{white-space:pre-wrap;word-break:break-word}
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


# report.json keys a fuller table shows in the page (both stay in report.json): key -> the fuller key
_SUPERSEDED = {"marker_rms_mm_per_marker": "marker_stats"}

# the page's titles of report.json's tables (key -> title, what the numbers are); the key stays beside
# the title, so a reader finds it in report.json
_SECTIONS = {
    "marker_stats": (
        "Per marker",
        "samples seen, missing, held out and outliers (over the cut-off: the fit sets them aside); errors in mm: "
        "rms_mm over every sample seen, inlier_rms_mm without the outliers, max_mm the largest",
    ),
    "muscle_identifiability": ("Muscle identifiability", "mm of marker motion per unit activation"),
    "seconds_breakdown_median": ("Time per frame by stage (median over frames)", "seconds"),
    "holdout_rms_mm_per_marker": ("Held-out markers", "RMS error over the frames, mm"),
    "marker_rms_mm_per_marker": ("Per marker", "RMS error over the frames, mm"),
    "capture_check": ("Capture check", "samples removed from the capture before tracking, by cause"),
    "face_model": ("Face model", "the face the take was tracked on"),
    "provenance": ("Provenance", "what made these files"),
}


def _heading(key: str) -> str:
    title, what = _SECTIONS.get(key, (key, ""))
    code = f" <code>{html.escape(key)}</code>" if title != key else ""
    note = f'<p class="meta">{html.escape(what)}</p>' if what else ""
    return f"<h2>{html.escape(title)}{code}</h2>{note}"


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
    if v is None:  # e.g. a marker with no inlier sample: nothing to measure
        return '<td class="num" title="no value: nothing to measure">&ndash;</td>'
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
    if isinstance(v, list) and v and all(isinstance(x, str) for x in v):  # names: all of them, readable
        return f"<td>{len(v)}: {html.escape(', '.join(v))}</td>"
    if isinstance(v, (list, dict)):
        text = json.dumps(v)
        if len(text) <= 400:
            return f"<td><code>{html.escape(text)}</code></td>"
        return (  # folded, not cut: the whole value is one click away
            f"<td><details><summary><code>{html.escape(text[:160])}...</code></summary>"
            f"<code>{html.escape(json.dumps(v, indent=1))}</code></details></td>"
        )
    return f"<td>{_fmt(v)}</td>"


def headline_cards(report: dict) -> list[tuple[str, str, str]]:
    """[(value, unit, label)] of the headline cards (module docstring), in display order."""
    cards = []
    truth = _is_number(report.get("truth_marker_rms_mm"))
    if truth:
        cards.append((_fmt(report["truth_marker_rms_mm"]), "mm", "marker RMS error vs the clean truth"))
    elif _is_number(report.get("marker_rms_mm_mean")):
        cards.append((_fmt(report["marker_rms_mm_mean"]), "mm", "marker RMS, every fitted sample (outliers included)"))
    if _is_number(report.get("holdout_rms_mm_mean")):  # the honest measure: markers the fit never saw
        cards.append((_fmt(report["holdout_rms_mm_mean"]), "mm", "held-out marker RMS (hidden from the fit)"))
    if not truth and _is_number(report.get("marker_rms_mm_inliers")):
        cards.append(_inlier_card(report))
    scale = report.get("capture_to_model_scale")
    if _is_number(scale) and abs(scale - 1.0) > 0.005:  # the face is not the actor's size: the actor's mm
        for key, label in (
            ("marker_rms_capture_mm_mean", "marker RMS"),
            ("holdout_rms_capture_mm_mean", "held-out RMS"),
        ):
            if _is_number(report.get(key)):
                cards.append((_fmt(report[key]), "mm", f"{label} in the capture's mm (face = {_fmt(scale)} x actor)"))
    if _is_number(report.get("marker_samples")):
        held = report.get("holdout_samples")
        cards.append(
            (
                f"{report.get('outlier_samples', 0)} / {report.get('missing_samples', 0)}"
                + (f" / {held}" if held else ""),
                "",
                ("outlier / missing / held-out" if held else "outlier / missing")
                + f" samples of {report['marker_samples']}",
            )
        )
    for key, (label, unit) in HEADLINE.items():
        if key in report and _is_number(report[key]):
            cards.append((_fmt(report[key]), unit, label))
    return cards


def _inlier_card(report: dict) -> tuple[str, str, str]:
    """The inlier error with the share of fitted samples (seen, not held out) over the cut-off."""
    thr = report.get("outlier_threshold_mm")
    fitted = report.get("marker_samples", 0) - report.get("missing_samples", 0) - report.get("holdout_samples", 0)
    share = (
        f"; {100.0 * report.get('outlier_samples', 0) / fitted:.0f} % of fitted samples over it" if fitted > 0 else ""
    )
    return _fmt(report["marker_rms_mm_inliers"]), "mm", f"inlier RMS (error <= {_fmt(thr)} mm{share})"


def _record_table(key: str, v: dict) -> str | None:
    """A dict of records with the same keys (e.g. per marker) as one table; None if it is not one."""
    rows = list(v.values())
    if not rows or not all(isinstance(r, dict) for r in rows):
        return None
    cols = list(rows[0])
    if not all(list(r) == cols for r in rows) or not all(
        isinstance(x, (int, float, str, bool)) or x is None for r in rows for x in r.values()
    ):
        return None
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in ["name", *cols])
    body = "".join(
        f"<tr><td>{html.escape(str(k))}</td>" + "".join(_value_cell(r[c]) for c in cols) + "</tr>" for k, r in v.items()
    )
    return f"{_heading(key)}<table><tr>{head}</tr>{body}</table>"


def _outputs_table(outputs: list[dict]) -> str:
    body = "".join(
        f"<tr><td><code>{html.escape(str(o.get('file', '')))}</code></td><td>{html.escape(str(o.get('what', '')))}"
        f"</td><td>{html.escape(str(o.get('opens_in', '')))}</td></tr>"
        for o in outputs
    )
    return f"<h2>Files</h2><table><tr><th>file</th><th>what</th><th>opens in</th></tr>{body}</table>"


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
    outputs: list[dict] | None = None,
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
        outputs: the files of the run, [{"file", "what", "opens_in"}], listed in a "Files" table.

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
        if _SUPERSEDED.get(key) in report:
            continue
        records = _record_table(str(key), v) if isinstance(v, dict) else None
        if records is not None:
            sub_tables.insert(0, records)
        elif isinstance(v, dict) and v and all(isinstance(x, (int, float, str, bool)) or x is None for x in v.values()):
            body = "".join(f"<tr><td>{html.escape(str(k))}</td>{_value_cell(x)}</tr>" for k, x in v.items())
            sub_tables.append(f"{_heading(str(key))}<table><tr><th>name</th><th>value</th></tr>{body}</table>")
        else:
            rows.append(f"<tr><th>{html.escape(str(key))}</th>{_value_cell(v)}</tr>")
    cards = "".join(
        f'<div class="card"><div class="v">{value} {unit}</div><div class="k">{html.escape(label)}</div></div>'
        for value, unit, label in headline_cards(report)
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
        + (_outputs_table(outputs) if outputs else "")
        + "</body></html>\n"
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / filename
    out.write_text(doc, encoding="utf-8")
    return out
