"""Issue 9 point 4: tracking on real anatomy (the imported Badin face).

The Badin mesh covers the face from the chin to about the eyes. AnimFace markers are aligned by the
markers both share by name (Mouth_Up, Mouth_Down, Mouth_Lend, Mouth_Rend, Mouth_DownL/R, Chin,
NoseHead) and kept when within 5 mm of the Badin skin. A synthetic performance on that marker
layout (Badin muscles, jaw opening) is recovered by ``track_sequence``; the first frames of the
real JawMoCap take are tracked. Thresholds are stated against the measured values in comments.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import data_path

pytestmark = pytest.mark.slow

SELECT_MM = 5.0  # largest distance of an aligned AnimFace marker from the Badin skin
PERFORMANCE_MUSCLES = tuple(f"{b}_{s}" for b in ("OOP", "MENT", "RIS", "LLS", "DAO") for s in "lr")


@pytest.fixture(scope="module")
def setup(badin_model):
    from wface.io.mocap import read_mocap
    from wface.speech.playback import select_capture_markers

    model = badin_model
    take = read_mocap(data_path("animface", "JawMoCap.c3d"))
    sel = select_capture_markers(model, take.positions_m, take.marker_names, max_distance_mm=SELECT_MM)
    return model, take, sel


def test_capture_markers_on_the_badin_skin(setup):
    model, take, sel = setup
    # all eight shared names anchor the alignment; they and the other lower-face markers are kept
    assert sorted(sel["landmarks"]) == sorted(n for n in model.marker_names if n in take.marker_names)
    assert len(sel["landmarks"]) == 8
    for name in ("Mouth_Up", "Mouth_Down", "Mouth_Lend", "Mouth_Rend", "Chin", "Chin_L1", "Chin_R1", "NoseHead_L"):
        assert name in sel["names"]
    assert all(sel["distance_mm"][i] <= SELECT_MM for i in sel["indices"])
    assert len(sel["names"]) < len(take.marker_names)  # some markers do not land on the Badin skin
    # the actor's face is larger than the Badin face: measured scale 0.76, landmark RMS 5.9 mm
    assert 0.6 < sel["scale"] < 0.95 and sel["landmark_rms_mm"] < 10.0


def test_synthetic_performance_is_recovered(setup):
    from wface.controls import jaw_to_intuitive
    from wface.speech.playback import performance_controls, simulate_controls
    from wface.tracking.capture import prepare_capture
    from wface.tracking.rig import FaceRig
    from wface.tracking.sequence import track_sequence

    model, take, sel = setup
    cap = prepare_capture(model, take.positions_m[:1, sel["indices"]], sel["names"])
    rig = FaceRig(model, tol=1e-6)
    # three consecutive frames from the middle of a 9-frame performance (reached from rest by continuation):
    # frame-to-frame changes like a sampled take, not a jump from rest to the peak
    C = performance_controls(model, 9, muscles=PERFORMANCE_MUSCLES, max_activation=0.5, max_jaw_deg=6.0, seed=1)[3:6]
    sim = simulate_controls(rig, cap.markers, C, substeps=3)
    assert sim["converged"].all()
    recs = track_sequence(model, sim["markers_m"], marker_names=sel["names"], markers=cap.markers)
    M = model.n_muscles
    A = np.array([r.controls[:M] for r in recs])
    err_mm = np.array([r.marker_error_m for r in recs]) * 1e3
    # measured: marker RMS 0.002-0.007 mm per frame (max 0.019 mm); activation RMS over all 22 muscles 0.006
    # (0.009 over the 10 driven ones, largest single error 0.03); jaw within 0.01 degrees
    assert np.sqrt(np.mean(err_mm**2)) < 0.05
    assert np.sqrt(np.mean((A - C[:, :M]) ** 2)) < 0.02 and np.abs(A - C[:, :M]).max() < 0.1
    jaw = [jaw_to_intuitive(model.jaw_joint, r.controls[M + 12 :])["opening_deg"] for r in recs]
    truth = [jaw_to_intuitive(model.jaw_joint, c[M + 12 :])["opening_deg"] for c in C]
    assert np.allclose(jaw, truth, atol=0.1)


def test_jaw_take_first_frames(setup):
    from wface.tracking.capture import prepare_capture
    from wface.tracking.sequence import track_sequence

    model, take, sel = setup
    pos = take.positions_m[0:3, sel["indices"]]
    cap = prepare_capture(model, pos, sel["names"])
    recs = track_sequence(model, cap.targets_m, marker_names=sel["names"], markers=cap.markers)
    err_mm = np.array([r.marker_error_m for r in recs]) * 1e3
    rms = np.sqrt(np.nanmean(err_mm**2, axis=1))
    # measured: 0.40, 0.43, 0.49 mm RMS per frame (max 1.5 mm) on 26 markers; an actor is not the Badin face
    assert np.all(rms < 1.0) and np.nanmax(err_mm) < 3.0
    for r in recs:
        a = r.controls[: model.n_muscles]
        assert a.min() >= 0.0 and a.max() <= 1.0 and r.stats["inverted_elements"] == 0
