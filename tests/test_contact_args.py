"""The contact flags mean the same in every command; each keeps its measured defaults."""

from __future__ import annotations

import pytest

from wface.cli import build_parser
from wface.physics.penalty import TRACKING_SMOOTHING_M

FLAGS = (
    "--contact",
    "--contact-stiffness",
    "--contact-smoothing-mm",
    "--freeze-below",
    "--contact-inside-at-rest",
    "--lip-surface",
)


def _options(command: str) -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return {s for a in sub.choices[command]._actions for s in a.option_strings}


@pytest.mark.parametrize("command", ["simulate", "resim", "speech", "track", "demo"])
def test_every_command_has_the_contact_flags(command):
    assert set(FLAGS) <= _options(command)


def test_defaults_and_the_contact_they_build():
    from wface.cli.contact_args import contact_from_args
    from wface.faces.builtin import build_face

    parser = build_parser()
    model = build_face(1000)
    sim = parser.parse_args(["simulate", "--model", "m.npz", "--out", "o", "--contact", "lips"])
    speech = parser.parse_args(
        ["speech", "--model", "m.npz", "--gesture", "closure", "--out", "o", "--contact", "lips"]
    )
    track = parser.parse_args(["track", "--mocap", "t.c3d", "--out", "o", "--contact", "lips"])
    c_sim, c_speech, c_track = (contact_from_args(a, model) for a in (sim, speech, track))
    assert c_sim.smoothing_m == 0.0 and c_sim.freeze_below is None  # the plain penalty
    assert c_sim.surface == "smooth" and c_speech.surface == "smooth"  # lips pressed: Newton converges
    assert c_track.surface == "faceted"  # tracked lips touch lightly; faceted is faster at the same fit
    # speech: smooth lip surfaces by default (wface.physics.smooth_contact), which need no freezing
    assert c_speech.smoothing_m == pytest.approx(1e-4) and c_speech.freeze_below is None
    # track / demo: the tracking ramp (0.5 mm, wface.physics.penalty.TRACKING_SMOOTHING_M)
    assert c_track.smoothing_m == pytest.approx(TRACKING_SMOOTHING_M) == 5e-4 and c_track.freeze_below is None
    demo = parser.parse_args(["demo", "--out", "o", "--contact", "lips"])
    assert contact_from_args(demo, model).smoothing_m == pytest.approx(TRACKING_SMOOTHING_M)
    assert contact_from_args(parser.parse_args(["simulate", "--model", "m", "--out", "o"]), model) is None
    with pytest.raises(SystemExit):  # a usage error while parsing (exit 2), before any face is built
        parser.parse_args(["simulate", "--model", "m", "--out", "o", "--contact", "gums"])


def test_inside_at_rest_is_ignored_unless_asked_to_push_or_hold():
    from wface.cli.contact_args import contact_from_args
    from wface.faces.builtin import build_face

    parser = build_parser()
    model = build_face(1000)
    base = ["speech", "--model", "m.npz", "--gesture", "closure", "--out", "o", "--contact", "lips,teeth"]
    assert parser.parse_args(base).contact_inside_at_rest == "ignore"
    for surface in ("faceted", "smooth"):
        ignore = parser.parse_args([*base, "--lip-surface", surface])
        push = parser.parse_args([*base, "--lip-surface", surface, "--contact-inside-at-rest", "push"])
        ignoring = contact_from_args(ignore, model)
        assert ignoring.surface == surface
        assert ignoring.ignored_at_rest and all("teeth" in name for name in ignoring.ignored_at_rest)
        kept = ignoring.rigid_nodes
        pushed = contact_from_args(push, model)
        assert pushed.ignored_at_rest == {}  # nothing left out: every contact node may touch every mesh
        assert all(len(k) <= len(p) for k, p in zip(kept, pushed.rigid_nodes, strict=True))
        hold = parser.parse_args([*base, "--lip-surface", surface, "--contact-inside-at-rest", "hold"])
        held = contact_from_args(hold, model)  # every node may touch, those inside at rest from their depth
        assert held.inside_at_rest == "hold" and held.held_at_rest == ignoring.ignored_at_rest
        assert [len(n) for n in held.rigid_nodes] == [len(n) for n in pushed.rigid_nodes]


def test_freezing_asks_for_the_faceted_lips():
    """--freeze-below freezes faceted features: with smooth lips the error names both flags."""
    from wface.cli.contact_args import contact_from_args
    from wface.faces.builtin import build_face

    parser = build_parser()
    model = build_face(1000)
    base = ["simulate", "--model", "m.npz", "--out", "o", "--contact", "lips", "--freeze-below", "0.01"]
    with pytest.raises(ValueError, match="--freeze-below.*--lip-surface faceted"):
        contact_from_args(parser.parse_args(base), model)
    frozen = contact_from_args(parser.parse_args([*base, "--lip-surface", "faceted"]), model)
    assert frozen.surface == "faceted" and frozen.freeze_below == pytest.approx(0.01)
    teeth = [a if a != "lips" else "teeth" for a in base]  # no lip contact: nothing for the surface to do
    assert contact_from_args(parser.parse_args(teeth), model).freeze_below == pytest.approx(0.01)
