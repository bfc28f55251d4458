"""The HTML report is self-contained: numbers in tables, every image embedded byte for byte."""

from __future__ import annotations

import base64
import re

import numpy as np
import pytest

from wface.viz.report import write_html_report


def _png(path, seed=0):
    mpl = pytest.importorskip("matplotlib")
    mpl.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot(np.random.default_rng(seed).random(10))
    fig.savefig(path)
    plt.close(fig)
    return path


def test_report_embeds_images_and_tabulates_numbers(tmp_path):
    a, b = _png(tmp_path / "a.png"), _png(tmp_path / "b.png", 1)
    report = {
        "frames": 40,
        "device": "cpu",
        "marker_rms_mm": [0.5, 0.7, float("nan"), 0.6],
        "marker_rms_mm_mean": 0.6,
        "muscle_identifiability": {"zygomatic<L>": 0.93, "frontalis": 0.12},
        "solver": {"name": "gn", "steps": 3},
        "nested": {"a": {"b": {"c": 1}}},
        "per_marker": {"Chin": {"seen": 3, "rms_mm": 0.25}, "Nose": {"seen": 2, "rms_mm": None}},
    }
    out = write_html_report(tmp_path / "out", report, {"activations": a, "marker error": "../b.png"})
    text = out.read_text()
    assert out.name == "report.html"
    uris = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert [base64.b64decode(u) for u in uris] == [a.read_bytes(), b.read_bytes()]
    assert not re.search(r'src="(?!data:)', text)  # nothing fetched from elsewhere
    for key in report:
        assert key in text
    assert "zygomatic&lt;L&gt;" in text and "0.93" in text  # names escaped, numbers shown
    assert "<h2>solver</h2>" in text and "<td>gn</td>" in text  # a dict of scalars: its own table
    assert "<code>{&quot;a&quot;: {&quot;b&quot;: {&quot;c&quot;: 1}}}</code>" in text  # deeper: JSON
    # records with the same keys: one table, a column per key
    assert "<h2>per_marker</h2><table><tr><th>name</th><th>seen</th><th>rms_mm</th></tr>" in text
    assert '<tr><td>Chin</td><td class="num">3</td><td class="num">0.25</td></tr>' in text
    assert "<tr><td>Nose</td>" in text and "&ndash;</td></tr>" in text and "None" not in text  # nothing to measure
    assert "n=4, mean 0.6" in text  # per-frame list summarised over finite values
    assert "<svg" in text
    assert re.search(r'class="card"><div class="v">0.6 mm</div><div class="k">marker RMS', text)
    _assert_balanced(text)


def test_per_marker_rms_is_shown_once_when_the_marker_stats_table_has_it(tmp_path):
    stats = {"Chin": {"seen": 3, "outliers": 1, "rms_mm": 0.25}}
    report = {"marker_rms_mm_per_marker": {"Chin": 0.31}, "marker_stats": stats}
    text = write_html_report(tmp_path, report, {}).read_text()
    assert "<h2>Per marker <code>marker_stats</code></h2>" in text and "marker_rms_mm_per_marker" not in text
    alone = write_html_report(tmp_path, {"marker_rms_mm_per_marker": {"Chin": 0.31}}, {}).read_text()
    assert "<h2>Per marker <code>marker_rms_mm_per_marker</code></h2>" in alone  # without the fuller table it stays


def test_tables_have_titles_and_units_and_values_are_not_cut(tmp_path):
    """Raw keys as headings, a "value" column without units and long values cut with "..." (the review)."""
    names = [f"muscle_{i:02d}" for i in range(35)]
    report = {
        "muscle_identifiability": {"zygomaticus_major_l": 1.2},
        "observable_muscles": names,
        "usage_prior": {"activation_sd": {n: 0.1 for n in names}, "noise_mm": 0.4},
    }
    text = write_html_report(tmp_path, report, {}).read_text()
    assert "<h2>Muscle identifiability <code>muscle_identifiability</code></h2>" in text
    assert "mm of marker motion per unit activation" in text
    assert f"35: {', '.join(names)}" in text  # every name, readable
    assert "<details>" in text and "&quot;muscle_34&quot;: 0.1" in text  # the long value folded, whole
    _assert_balanced(text)


def _assert_balanced(text):
    from html.parser import HTMLParser

    void = {"meta", "img", "br", "hr", "link", "input"}

    class Checker(HTMLParser):
        def __init__(self):
            super().__init__()
            self.stack = []

        def handle_starttag(self, tag, attrs):
            if tag not in void and tag != "polyline":
                self.stack.append(tag)

        def handle_endtag(self, tag):
            if tag == "polyline":
                return
            assert self.stack and self.stack[-1] == tag, f"</{tag}> closes <{self.stack[-1:]}>"
            self.stack.pop()

    c = Checker()
    c.feed(text)
    assert c.stack == [], f"unclosed tags: {c.stack}"


def test_report_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="'missing'"):
        write_html_report(tmp_path, {}, {"missing": tmp_path / "nope.png"})
    (tmp_path / "x.bmp").write_bytes(b"BM")
    with pytest.raises(ValueError, match="cannot embed x.bmp"):
        write_html_report(tmp_path, {}, {"bmp": tmp_path / "x.bmp"})
