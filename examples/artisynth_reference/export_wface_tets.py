"""Write the tet mesh of a wface Badin import for ``RunLipOpening -Dlip.mesh=FILE``.

ArtiSynth then runs its own lip-opening demo on wface's tets instead of its hexes: the same nodes in the
node file's order (the sliver removal's moved interior nodes at their new rest positions), the nodes the
import added after them, and wface's tets. Everything else (material, muscles, bones, contact, stepping)
stays ArtiSynth's. See README.md, "ArtiSynth itself, run headless".

    python examples/artisynth_reference/export_wface_tets.py out/badin.npz out/wface_tets.txt
    python examples/artisynth_reference/export_wface_tets.py out/badin.npz out/wface_tets8.txt --refine

``--refine`` splits every tet into 8 at its edge midpoints (a mesh convergence check of the linear
tets, run in ArtiSynth, where a tet mesh this size costs minutes rather than wface's hours on a CPU).

Output: "NODES <count> <file nodes>", one "x y z" per node (metres, Badin frame; a midpoint node adds
its two end nodes, "x y z a b", so that it follows them onto a bone), "TETS <count>", one "a b c d"
per tet (0-based node indices, positive volume).
"""

import argparse
import sys

import numpy as np

from wface.faces.artisynth import BADIN_TO_WFACE
from wface.mesh.quality import signed_volumes
from wface.model import load_model

# the 8 children of tet (a, b, c, d) in its corners and edge midpoints: four corner tets, then the inner
# octahedron cut along ab-cd (its equator ac, ad, bd, bc)
_CHILDREN = (
    ("a", "ab", "ac", "ad"),
    ("ab", "b", "bc", "bd"),
    ("ac", "bc", "c", "cd"),
    ("ad", "bd", "cd", "d"),
    ("ab", "cd", "ac", "ad"),
    ("ab", "cd", "ad", "bd"),
    ("ab", "cd", "bd", "bc"),
    ("ab", "cd", "bc", "ac"),
)
_EDGES = (("a", "b"), ("a", "c"), ("a", "d"), ("b", "c"), ("b", "d"), ("c", "d"))


def refine_tets(x: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split every tet into 8 at its edge midpoints (shared by neighbours: the result is conforming).

    Returns the nodes (``x`` first, then one per edge), the tets (positively oriented where ``tets`` is)
    and the (edges, 2) end nodes of each midpoint.
    """
    corner = "abcd"
    pairs = np.array([[corner.index(u), corner.index(v)] for u, v in _EDGES])
    edges = np.sort(tets[:, pairs], axis=2).reshape(-1, 2)
    ends, inverse = np.unique(edges, axis=0, return_inverse=True)
    name = {c: tets[:, i] for i, c in enumerate(corner)}
    for k, (u, v) in enumerate(_EDGES):
        name[u + v] = len(x) + inverse.reshape(-1, 6)[:, k]
    x8 = np.vstack([x, 0.5 * (x[ends[:, 0]] + x[ends[:, 1]])])
    tets8 = np.stack([np.stack([name[c] for c in child], axis=1) for child in _CHILDREN], axis=1).reshape(-1, 4)
    flip = signed_volumes(x8, tets8) < 0
    tets8[flip] = tets8[flip][:, [0, 2, 1, 3]]
    return x8, tets8, ends


def write_tets(model, path, *, refine: bool = False) -> tuple[int, int, int]:
    """Write ``model``'s rest nodes (Badin frame) and tets; returns (nodes, file nodes, tets)."""
    added = model.metadata.get("added_nodes")
    if not isinstance(added, dict) or "first_id" not in added:
        raise SystemExit(
            "this model is not a wface Badin import (no metadata['added_nodes']); "
            "import it with `wface model import artisynth DIR --out FILE`"
        )
    n_file = int(added["first_id"])
    x = np.asarray(model.rest_positions_m, dtype=np.float64) @ BADIN_TO_WFACE  # wface -> Badin frame
    tets = np.asarray(model.tets, dtype=np.int64)
    ends = np.zeros((0, 2), dtype=np.int64)
    if refine:
        n_before = len(x)
        x, tets, ends = refine_tets(x, tets)
    with open(path, "w") as f:
        f.write(f"NODES {len(x)} {n_file}\n")
        if refine:
            np.savetxt(f, x[:n_before], fmt="%.12g")
            np.savetxt(f, np.hstack([x[n_before:], ends]), fmt=["%.12g"] * 3 + ["%d"] * 2)
        else:
            np.savetxt(f, x, fmt="%.12g")
        f.write(f"TETS {len(tets)}\n")
        np.savetxt(f, tets, fmt="%d")
    return len(x), n_file, len(tets)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="a wface Badin import (.npz from `wface model import artisynth`)")
    parser.add_argument("out", help="the text file for RunLipOpening -Dlip.mesh")
    parser.add_argument("--refine", action="store_true", help="split every tet into 8 at its edge midpoints")
    args = parser.parse_args(argv)
    n, n_file, m = write_tets(load_model(args.model), args.out, refine=args.refine)
    print(f"wrote {args.out}: {n} nodes ({n_file} from the node file), {m} tets")
    return 0


if __name__ == "__main__":
    sys.exit(main())
