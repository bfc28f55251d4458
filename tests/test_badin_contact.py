"""Contact on the imported ArtiSynth Badin face: the teeth overlap the flesh in the source data."""

from __future__ import annotations

import numpy as np
import pytest

from wface.physics.contact import Contact


def _winding_number(p: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Generalised winding number of points p (k, 3) w.r.t. a triangle mesh (Jacobson et al. 2013)."""
    a, b, c = (v[t[:, j]][None] - p[:, None] for j in range(3))
    la, lb, lc = (np.linalg.norm(q, axis=2) for q in (a, b, c))
    det = np.einsum("pti,pti->pt", a, np.cross(b, c))
    dot = lambda u, w: np.einsum("pti,pti->pt", u, w)  # noqa: E731
    den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
    return (2 * np.arctan2(det, den)).sum(axis=1) / (4 * np.pi)


def test_teeth_overlap_the_flesh_in_the_data_and_are_ignored_at_rest(badin_model):
    m = badin_model
    raw = Contact(m, regions="teeth", inside_at_rest="push")
    pen = raw.penetration(m.rest_positions_m)
    assert pen["max_penetration_m"] > 5e-3  # measured 8.7 mm (lower teeth), 7.2 mm (upper)
    # Not a sign or frame error: the deepest nodes are inside the (nearly closed) teeth meshes by
    # their winding number, and they lie on the face's inner (gum-side) surface.
    pairs = raw.evaluate(m.rest_positions_m)
    deep = np.unique(pairs.node[pairs.penetration_m > 2e-3])
    assert deep.size > 50
    p = m.rest_positions_m[deep[:40]]
    w = sum(
        _winding_number(p, m.bone_meshes[b].vertices_m, m.bone_meshes[b].triangles)
        for b in ("lower_teeth", "upper_teeth")
    )
    assert np.all(np.abs(w - 1.0) < 0.02)  # inside exactly one tooth row (measured 0.99-1.00)
    assert np.isin(deep, np.unique(m.surface_groups["inner"])).mean() > 0.9
    # Default: nodes inside at rest are left out, so the rest shape carries no teeth contact.
    teeth = Contact(m, regions="teeth,lips")
    assert teeth.penetration(m.rest_positions_m)["max_penetration_m"] == 0.0
    assert teeth.ignored_at_rest["lower_teeth"] > 100 and teeth.ignored_at_rest["upper_teeth"] > 100
    # ... while the lips (collision surfaces) stay able to touch the teeth
    lips = np.unique(np.concatenate([m.surface_groups["upper_lip"].ravel(), m.surface_groups["lower_lip"].ravel()]))
    kept = teeth.rigid_nodes[[n for n, _ in teeth.rigid].index("upper_teeth")]
    assert np.isin(lips, kept).mean() > 0.9


@pytest.mark.parametrize("region", ["bones"])
def test_bone_meshes_carry_no_contact_at_rest(badin_model, region):
    c = Contact(badin_model, regions=region)
    assert c.penetration(badin_model.rest_positions_m)["max_penetration_m"] == 0.0
