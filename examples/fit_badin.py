"""Template fitting from the imported Badin face (issue 14, point 1): onto a known warp of its own skin,
and onto the JawMoCap neutral marker frame.

    python examples/fit_badin.py --out out/fit_badin            # both fits, ~1 min on 2 cores
    python examples/fit_badin.py --out /tmp/fb --no-markers      # the warp alone

The ArtiSynth face comes from ``$WFACE_DATA/artisynth-face`` (``WFACE_DATA`` defaulting to
``../shared/data``; ``wface.faces.import_artisynth``), the capture from
``$WFACE_DATA/animface/JawMoCap.c3d``. The warp is smooth and known: 8 % / 5 % / 3 % scale about the
skin's centroid along x / y / z and a 3 mm bump over ~4 cm, with the Badin face's own markers
carried by the same warp as landmarks. Printed and written to ``fit_badin.json``: the surface
distance to the target (mean / max mm), the landmark and marker residuals, the skin's recovery
error against the warp (mean / max mm: the fit is told only the surface and the landmarks), the
minimum dihedral angle and volume ratio of the template, of the interior relaxation and of the
result (after the interior smoothing), and the inverted tets.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from wface.faces import import_artisynth
from wface.faces.fit import fit_template
from wface.io.mocap import read_mocap
from wface.mesh.closest import SurfaceQuery
from wface.mesh.meshfile import SurfaceMesh

_DATA = Path(os.environ.get("WFACE_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


def smooth_warp(x: np.ndarray, centre: np.ndarray, bump_at: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3) metres: anisotropic scale about ``centre`` and a 3 mm bump at ``bump_at``."""
    y = centre + (x - centre) * np.array([1.08, 1.05, 1.03])
    bump = np.exp(-np.sum((x - bump_at) ** 2, axis=1) / 0.04**2)
    n = (bump_at - centre) / np.linalg.norm(bump_at - centre)
    return y + 0.003 * bump[:, None] * n


def fit_to_warp(face) -> dict:
    skin_tri = face.skin_triangles
    skin = np.unique(skin_tri)
    centre = face.rest_positions_m[skin].mean(axis=0)
    far = skin[np.argmax(np.linalg.norm(face.rest_positions_m[skin] - centre, axis=1))]
    bump_at = centre + 0.6 * (face.rest_positions_m[far] - centre)  # part way out on the skin
    bump_at = face.rest_positions_m[skin][np.argmin(np.linalg.norm(face.rest_positions_m[skin] - bump_at, axis=1))]
    warp = lambda p: smooth_warp(p, centre, bump_at)  # noqa: E731
    mesh = SurfaceMesh(
        points=warp(face.rest_positions_m),
        face_vertex_counts=np.full(len(skin_tri), 3, np.int32),
        face_vertex_indices=skin_tri.ravel(),
        meters_per_unit=1.0,
        source="badin_warp",
    )
    marks = {n: warp(p[None])[0] for n, p in zip(face.marker_names, face.marker_positions_m, strict=True)}
    t = time.perf_counter()
    res = fit_template(face, surface=mesh, landmarks=marks, progress=print)
    inv = np.linalg.inv(res.target_to_model)
    got = res.model.rest_positions_m @ inv[:3, :3].T + inv[:3, 3]
    truth = warp(face.rest_positions_m)
    rec_mm = SurfaceQuery(truth, skin_tri).closest(got[skin]).distance_m * 1e3
    out = res.report.as_dict()
    out["skin_to_warped_surface_mm"] = {"mean": float(rec_mm.mean()), "max": float(rec_mm.max())}
    out["seconds"] = time.perf_counter() - t
    return out


def fit_to_markers(face, c3d: Path) -> dict:
    take = read_mocap(c3d)
    t = time.perf_counter()
    res = fit_template(face, markers_m=take.positions_m[0], marker_names=list(take.marker_names), progress=print)
    out = res.report.as_dict()
    out["seconds"] = time.perf_counter() - t
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="output directory (fit_badin.json)")
    ap.add_argument("--no-markers", action="store_true", help="skip the JawMoCap neutral-frame fit")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    face = import_artisynth(_DATA / "artisynth-face")
    print(f"Badin face: {face.n_tets} tets, {face.n_nodes} nodes, {len(face.marker_names)} markers")
    result = {"tets": face.n_tets, "warp": fit_to_warp(face)}
    if not args.no_markers:
        result["jaw_neutral_frame"] = fit_to_markers(face, _DATA / "animface" / "JawMoCap.c3d")
    (out / "fit_badin.json").write_text(json.dumps(result, indent=1, default=float))
    print(json.dumps(result, indent=1, default=float))
    return result


if __name__ == "__main__":
    main()
