"""Off-screen pictures and movies of a face with pyvista (VTK): stills, comparisons, takes.

Conventions (the figures of Sifakis et al. 2005): captured markers red, simulated / tracked markers green, named
by a legend at the panel's top left; muscles yellow when fully active, red when inactive, with a colour bar
(``ACTIVATION_LEGEND``) whenever activations are shown (``wface.viz.legend``). Bones (the teeth, the mouth's dark
backdrop) move by the affines given, else by the least-squares fit to their attached nodes. Two styles:

- ``"skin"``: the skin surface coloured by the muscles under it (``wface.viz.muscles``);
- ``"muscles"``: the muscle volumes (surfaces of their tets at the deformed positions) coloured
  by activation, the bones, and a translucent skin for context (like Sifakis et al. 2005, figure 3).

The camera looks at the face from the front with a slight three-quarter turn (``view``: a
direction from the face towards the camera in model coordinates; +y is up) and is fitted to the
points of everything drawn (over all frames of a movie): it comes as close as it can while every
point stays inside ``fill`` of the picture, so nothing is clipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from tqdm.auto import tqdm

from wface.controls import bone_affines_from_attached
from wface.viz.inside import INSIDE_RGB, inner_surface, throat_quad
from wface.viz.legend import CAPTURED_RGB, LEGEND_BAND, SIMULATED_RGB, add_activation_legend, add_marker_legend
from wface.viz.muscles import ACTIVE_RGB, INACTIVE_RGB, SKIN_RGB, activation_colors, skin_muscle_influence
from wface.viz.offscreen import offscreen_pyvista

__all__ = [
    "CAPTURED_RGB",
    "DEFAULT_VIEW",
    "SIMULATED_RGB",
    "Panel",
    "render_before_after",
    "render_expression",
    "render_panels",
    "render_take_movie",
]

BONE_RGB = (0.93, 0.91, 0.84)
DEFAULT_VIEW = (0.45, 0.12, 1.0)  # camera direction from the face: front (+z), a little right and above
_BACKGROUND = "white"


@dataclass
class Panel:
    """What one picture panel shows.

    Attributes:
        node_positions_m: (n, 3) node positions (model.n_nodes rows), metres.
        activations: (M,) muscle activations in [0, 1], or None (neutral colours).
        captured_markers_m: (k, 3) captured markers (red); NaN rows are skipped.
        simulated_markers_m: (k, 3) simulated / tracked markers (green).
        title: text drawn in the panel's upper left corner.
        cranium_affine: (3, 4) cranium rest-to-world affine (bones in the "muscles" style).
        jaw_affine: (3, 4) jaw affine, relative to the cranium (``wface.controls``' convention).
    """

    node_positions_m: np.ndarray
    activations: np.ndarray | None = None
    captured_markers_m: np.ndarray | None = None
    simulated_markers_m: np.ndarray | None = None
    title: str = ""
    cranium_affine: np.ndarray | None = None
    jaw_affine: np.ndarray | None = None

    def bone_affines(self) -> dict[str, np.ndarray]:
        """World affines of the bones: {"cranium": C, "jaw": C o J} for those given."""
        return _bone_world_affines(self.cranium_affine, self.jaw_affine, "cranium")


def _bone_world_affines(cranium, jaw, jaw_frame: str) -> dict[str, np.ndarray]:
    out = {}
    if cranium is not None:
        out["cranium"] = np.asarray(cranium, dtype=np.float64).reshape(3, 4)
    if jaw is not None:
        j = np.asarray(jaw, dtype=np.float64).reshape(3, 4)
        if jaw_frame == "cranium" and "cranium" in out:
            c = out["cranium"]
            j = np.hstack([c[:, :3] @ j[:, :3], (c[:, :3] @ j[:, 3] + c[:, 3])[:, None]])
        out["jaw"] = j
    return out


def _pv():

    return offscreen_pyvista()


def _check_nodes(model, x, label="node_positions_m") -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.shape != (model.n_nodes, 3):
        raise ValueError(f"{label} must have shape ({model.n_nodes}, 3) for this model; got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{label} contains NaN/inf")
    return x


def _tri_polydata(pv, points, triangles):
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    faces = np.hstack([np.full((tri.shape[0], 1), 3), tri]).ravel()
    return pv.PolyData(np.asarray(points, dtype=np.float64), faces)


def _uniform_laplacian(surf):
    """Sparse uniform Laplacian L = D^-1 A - I of a triangle surface (pyvista PolyData)."""

    tri = np.asarray(surf.faces).reshape(-1, 4)[:, 1:]
    i = np.concatenate([tri[:, 0], tri[:, 1], tri[:, 2], tri[:, 1], tri[:, 2], tri[:, 0]])
    j = np.concatenate([tri[:, 1], tri[:, 2], tri[:, 0], tri[:, 0], tri[:, 1], tri[:, 2]])
    n = surf.n_points
    adj = sp.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    adj.data[:] = 1.0  # duplicate edges count once
    deg = np.asarray(adj.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.maximum(deg, 1)) @ adj - sp.identity(n)


def _taubin(lap, points: np.ndarray, n_iter: int, lam: float = 0.5, mu: float = -0.53) -> np.ndarray:
    """Taubin's shrink-free smoothing (lambda | mu steps): rounds the blocky faces of tet surfaces."""
    p = np.asarray(points, dtype=np.float64)
    for _ in range(n_iter):
        p = p + lam * (lap @ p)
        p = p + mu * (lap @ p)
    return p


class _Scene:
    """The actors of one panel, built once and updated per frame (for movies)."""

    def __init__(
        self,
        pv,
        plotter,
        model,
        *,
        style: str,
        marker_radius_m: float,
        show_bones: bool,
        muscle_radius_m: float | None,
        muscle_smoothing: int = 4,
    ):
        if style not in ("skin", "muscles"):
            raise ValueError(f"style must be 'skin' or 'muscles', got {style!r}")
        self.pv, self.p, self.model, self.style = pv, plotter, model, style
        self.muscle_smoothing = muscle_smoothing
        self.r = marker_radius_m
        self.skin_nodes = np.unique(model.skin_triangles)
        remap = np.full(model.n_nodes, -1, dtype=np.int64)
        remap[self.skin_nodes] = np.arange(self.skin_nodes.size)
        x0 = model.rest_positions_m
        self.skin = _tri_polydata(pv, x0[self.skin_nodes], remap[model.skin_triangles])
        self.influence = None
        self.muscles: list[tuple[int, object, np.ndarray, object, object]] = []
        self.bones: list[tuple[object, np.ndarray]] = []
        self.inside = None
        if style == "skin":
            self.inside = inner_surface(pv, model, _tri_polydata)  # dark behind the skin: an open mouth shows a cavity
            if self.inside is not None:
                self.p.add_mesh(self.inside[0], color=INSIDE_RGB, smooth_shading=True, specular=0.0, ambient=0.15)
            self.influence = skin_muscle_influence(model, self.skin_nodes, radius_m=muscle_radius_m)
            self.skin["rgb"] = np.tile(SKIN_RGB, (self.skin.n_points, 1))
            self.p.add_mesh(
                self.skin, scalars="rgb", rgb=True, smooth_shading=True, specular=0.1, diffuse=0.8, ambient=0.08
            )
        else:
            self.skin_actor = self.p.add_mesh(self.skin, color=SKIN_RGB, opacity=0.22, smooth_shading=True)
            for m in range(model.n_muscles):
                sel = (model.fibre_muscle == m) & (model.fibre_fraction >= 0.5)
                tets = model.tets[model.fibre_tet[sel]]
                if tets.size == 0:
                    continue
                grid = pv.UnstructuredGrid({pv.CellType.TETRA: tets.astype(np.int64)}, x0)
                surf = grid.extract_surface(algorithm="dataset_surface")
                ids = np.asarray(surf.point_data["vtkOriginalPointIds"])
                lap = _uniform_laplacian(surf)
                surf.points = _taubin(lap, x0[ids], muscle_smoothing)
                actor = self.p.add_mesh(surf, color=INACTIVE_RGB, smooth_shading=True, specular=0.2)
                self.muscles.append((m, surf, ids, lap, actor))
        if show_bones:  # the "skin" style draws the teeth alone: only an open mouth shows them
            for name, mesh, tri in _cropped_bones(model):
                if style == "skin" and "teeth" not in name:
                    continue  # a skull cropped to the skin's box pokes through its rim
                bp = _tri_polydata(pv, mesh.vertices_m, tri)
                self.p.add_mesh(bp, color=BONE_RGB, smooth_shading=True, specular=0.1)
                self.bones.append((bp, mesh.vertices_m, mesh.bone))
        throat = throat_quad(pv, model) if style == "skin" else None
        if throat is not None:
            self.p.add_mesh(throat[0], color=INSIDE_RGB, ambient=0.3, diffuse=0.2, specular=0.0)
            self.bones.append(throat)
        self.bone_names = {b for _, _, bone in self.bones for b in ([bone] if isinstance(bone, str) else bone)}
        self.marker_actors: dict[str, object] = {}

    def update(self, x, activations, captured, simulated, *, bone_affines: dict | None = None) -> None:
        self.skin.points = x[self.skin_nodes]
        if self.inside is not None:
            self.inside[0].points = x[self.inside[1]]
        a = None if activations is None else np.asarray(activations, dtype=np.float64)
        if a is not None and a.shape != (self.model.n_muscles,):
            raise ValueError(f"activations must have shape ({self.model.n_muscles},); got {a.shape}")
        if self.style == "skin":
            if a is None:
                rgb = np.tile(SKIN_RGB, (self.skin.n_points, 1))
            else:
                _, rgb = activation_colors(self.influence, a)
            self.skin["rgb"] = rgb
        else:
            for m, surf, ids, lap, actor in self.muscles:
                surf.points = _taubin(lap, x[ids], self.muscle_smoothing)
                level = 0.0 if a is None else float(np.clip(a[m], 0, 1))
                actor.prop.color = tuple(INACTIVE_RGB + level * (ACTIVE_RGB - INACTIVE_RGB))
        # bones no affine was given for follow their attached nodes (an edit's or a resim's frames moved
        # the head and jaw, and the teeth and throat stood at rest: an open mouth showed the background)
        given = bone_affines or {}
        if self.bone_names - given.keys():  # fitted only where needed: a movie updates every frame
            given = {**bone_affines_from_attached(self.model, x[self.model.attached_nodes]), **given}
        for bp, rest, bone in self.bones:  # bone: one name, or one per point (the throat's corners)
            names = [bone] * len(rest) if isinstance(bone, str) else list(bone)
            moved = np.array(rest, dtype=np.float64)
            for name in set(names):
                aff = given.get(name)
                if aff is not None:
                    rows = [i for i, n in enumerate(names) if n == name]
                    moved[rows] = rest[rows] @ aff[:, :3].T + aff[:, 3]
            bp.points = moved
        for key, pts, rgb in (("cap", captured, CAPTURED_RGB), ("sim", simulated, SIMULATED_RGB)):
            if key in self.marker_actors:
                self.p.remove_actor(self.marker_actors.pop(key), render=False)
            if pts is None:
                continue
            pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
            pts = pts[np.all(np.isfinite(pts), axis=1)]
            if pts.size == 0:
                continue
            glyphs = self.pv.PolyData(pts).glyph(
                geom=self.pv.Sphere(radius=self.r, theta_resolution=16, phi_resolution=16), scale=False, orient=False
            )
            self.marker_actors[key] = self.p.add_mesh(
                glyphs, color=rgb, smooth_shading=True, specular=0.4, reset_camera=False, render=False
            )


def _cropped_bones(model, margin: float = 0.03) -> list[tuple[str, object, np.ndarray]]:
    """Bone meshes with only the triangles whose rest centroid lies in the skin's box (+ margin).

    A skull usually reaches far beyond the face's skin (the top of the head): drawing it whole
    would shrink the face in the picture.
    """
    skin = model.rest_positions_m[np.unique(model.skin_triangles)]
    lo, hi = skin.min(axis=0), skin.max(axis=0)
    pad = margin * (hi - lo)
    out = []
    for name, mesh in model.bone_meshes.items():
        tri = np.asarray(mesh.triangles).reshape(-1, 3)
        c = np.asarray(mesh.vertices_m)[tri].mean(axis=1)
        keep = np.all((c >= lo - pad) & (c <= hi + pad), axis=1)
        if np.any(keep):
            out.append((name, mesh, tri[keep]))
    return out


def _framing_points(model, arrays, *, bones: bool) -> np.ndarray:
    """(N, 3) finite points the camera must keep in view: given arrays, and cropped bones."""
    pts = [np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in arrays if a is not None]
    pts = np.concatenate([p[np.all(np.isfinite(p), axis=1)] for p in pts])
    if bones:
        for _, mesh, tri in _cropped_bones(model):
            pts = np.concatenate([pts, np.asarray(mesh.vertices_m)[np.unique(tri)]])
    return pts


def _shows(markers) -> bool:
    """Whether a picture draws any of these markers ((k, 3) or (F, k, 3); NaN rows are not drawn)."""
    return markers is not None and bool(np.isfinite(np.asarray(markers, dtype=float)).all(axis=-1).any())


def _box_corners(points: np.ndarray) -> np.ndarray:
    """(F*8, 3) corners of the per-frame bounding boxes of (F, n, 3) points (cheap framing of a movie)."""
    lo, hi = points.min(axis=1), points.max(axis=1)
    pick = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    return np.concatenate(
        [np.where(pick[None, :, k], hi[:, None, k], lo[:, None, k])[..., None] for k in range(3)], axis=2
    ).reshape(-1, 3)


def _place_camera(
    plotter,
    points: np.ndarray,
    view,
    *,
    fill: float,
    pad_m: float,
    zoom: float = 1.0,
    reserve_bottom: float = 0.0,
    reserve_top: float = 0.0,
) -> None:
    """Look at the points' box centre from direction ``view`` (+y up), as close as possible while
    every point (grown by ``pad_m``) stays inside ``fill`` of the viewport (perspective projection),
    between bands of ``reserve_bottom`` and ``reserve_top`` of the viewport's height kept free (a
    colour bar's, a title's)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    d = np.asarray(view, dtype=np.float64)
    d = d / np.linalg.norm(d)
    up = np.array([0.0, 1.0, 0.0]) - d[1] * d
    up = up / np.linalg.norm(up)
    right = np.cross(up, d)
    w, h = plotter.window_size
    shape = getattr(plotter, "shape", (1, 1))
    aspect = (w / shape[1]) / (h / shape[0])
    half = np.tan(np.radians(plotter.camera.view_angle) / 2)
    t, ty = half * fill, half * fill * (1.0 - reserve_bottom - reserve_top)
    for step in range(3):  # fit the distance; centre the projected points; fit again
        r = points - centre
        depth = r @ d
        px, py = r @ right, r @ up
        lx, ly = np.abs(px) + pad_m, np.abs(py) + pad_m
        dist = float(np.max(np.maximum(depth + ly / ty, depth + lx / (t * aspect))))
        if step == 2:
            break
        sx, sy = px / (dist - depth), py / (dist - depth)  # tangents of the view angles
        centre = centre + dist * ((sx.max() + sx.min()) / 2 * right + (sy.max() + sy.min()) / 2 * up)
    centre = centre - up * (dist * half * (reserve_bottom - reserve_top))  # the points' centre: between the bands
    plotter.camera_position = [tuple(centre + dist * d), tuple(centre), tuple(up)]
    if zoom != 1.0:
        plotter.camera.zoom(zoom)
    plotter.renderer.ResetCameraClippingRange()


_TITLE_BAND = 0.08  # share of a panel's height its title takes at the top (above the head, not over it)


def _new_plotter(pv, shape, window_size):
    p = pv.Plotter(off_screen=True, shape=shape, window_size=list(window_size), border=False, lighting="light_kit")
    p.set_background(_BACKGROUND)
    for r in range(shape[0]):
        for c in range(shape[1]):
            p.subplot(r, c)
            p.add_light(pv.Light(light_type="headlight", intensity=0.18))  # fill: no black lower face
    return p


def render_panels(
    model,
    panels: list[Panel],
    out_path: str | Path,
    *,
    style: str = "skin",
    view=DEFAULT_VIEW,
    panel_size: tuple[int, int] = (720, 800),
    marker_radius_m: float | None = None,
    show_bones: bool = True,
    muscle_radius_m: float | None = None,
    fill: float = 0.92,
    zoom: float = 1.0,
    muscle_smoothing: int = 4,
) -> Path:
    """Render panels side by side (same camera in each) into one PNG.

    Args:
        model: the ``FaceModel``.
        panels: one ``Panel`` per column.
        out_path: PNG file to write.
        style: "skin" (skin coloured by muscles underneath) or "muscles" (muscle volumes, bones,
            translucent skin).
        view: direction from the face to the camera (model coordinates, +y up).
        panel_size: (width, height) pixels of one panel.
        marker_radius_m: marker sphere radius; default 1% of the face's bounding-box diagonal.
        show_bones: draw bone meshes (in the "skin" style they show only through an open mouth: the teeth).
        muscle_radius_m: falloff of the skin colour around muscles (see ``skin_muscle_influence``).
        fill: fraction of the panel's width or height the framed points may take (the camera
            comes as close as that allows, perspective included).
        zoom: extra camera zoom after the fit (1: none; > 1 may clip).
        muscle_smoothing: Taubin smoothing steps of the muscle surfaces ("muscles" style; 0: the
            raw faceted tet surfaces; more rounds off thin muscles).

    Returns:
        The PNG path.
    """
    pv = _pv()
    if not panels:
        raise ValueError("no panels to render")
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    xs = [_check_nodes(model, pnl.node_positions_m, f"panel {i} node_positions_m") for i, pnl in enumerate(panels)]
    pts = _framing_points(
        model,
        [x[np.unique(model.skin_triangles)] for x in xs]
        + [pnl.captured_markers_m for pnl in panels]
        + [pnl.simulated_markers_m for pnl in panels],
        bones=show_bones and style == "muscles",
    )
    r = marker_radius_m or 0.01 * float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    p = _new_plotter(pv, (1, len(panels)), (panel_size[0] * len(panels), panel_size[1]))
    for i, (pnl, x) in enumerate(zip(panels, xs, strict=True)):
        p.subplot(0, i)
        scene = _Scene(
            pv,
            p,
            model,
            style=style,
            marker_radius_m=r,
            show_bones=show_bones,
            muscle_radius_m=muscle_radius_m,
            muscle_smoothing=muscle_smoothing,
        )
        scene.update(
            x, pnl.activations, pnl.captured_markers_m, pnl.simulated_markers_m, bone_affines=pnl.bone_affines()
        )
        if pnl.title:
            p.add_text(pnl.title, position="upper_edge", font_size=12, color="black")
        if pnl.activations is not None:
            add_activation_legend(pv, p)
        key = add_marker_legend(p, captured=_shows(pnl.captured_markers_m), simulated=_shows(pnl.simulated_markers_m))
        reserve = LEGEND_BAND if pnl.activations is not None else 0.0
        top = max(_TITLE_BAND if pnl.title else 0.0, key)
        _place_camera(p, pts, view, fill=fill, pad_m=r, zoom=zoom, reserve_bottom=reserve, reserve_top=top)
    p.enable_anti_aliasing("ssaa")
    p.screenshot(str(out_path))
    p.close()
    return out_path


def render_expression(
    model,
    node_positions_m: np.ndarray,
    out_path: str | Path,
    *,
    activations: np.ndarray | None = None,
    captured_markers_m: np.ndarray | None = None,
    simulated_markers_m: np.ndarray | None = None,
    title: str = "",
    cranium_affine: np.ndarray | None = None,
    jaw_affine: np.ndarray | None = None,
    **kwargs,
) -> Path:
    """One still of the face at ``node_positions_m`` (n, 3): muscles coloured by ``activations`` (M,),
    captured markers (k, 3) red and simulated markers (k, 3) green. Other options: ``render_panels``."""
    panel = Panel(
        node_positions_m, activations, captured_markers_m, simulated_markers_m, title, cranium_affine, jaw_affine
    )
    return render_panels(model, [panel], out_path, **kwargs)


def render_before_after(
    model,
    before: Panel,
    after: Panel,
    out_path: str | Path,
    *,
    titles: tuple[str, str] = ("before", "after"),
    **kwargs,
) -> Path:
    """Two panels side by side with the same camera (e.g. capture vs. tracked, neutral vs. expression)."""
    before = Panel(**{**before.__dict__, "title": before.title or titles[0]})
    after = Panel(**{**after.__dict__, "title": after.title or titles[1]})
    return render_panels(model, [before, after], out_path, **kwargs)


def render_take_movie(
    model,
    node_positions_m: np.ndarray,
    out_path: str | Path,
    *,
    fps: float = 30.0,
    activations: np.ndarray | None = None,
    captured_markers_m: np.ndarray | None = None,
    simulated_markers_m: np.ndarray | None = None,
    cranium_affines: np.ndarray | None = None,
    jaw_affines: np.ndarray | None = None,
    jaw_frame: str = "cranium",
    style: str = "skin",
    view=DEFAULT_VIEW,
    window_size: tuple[int, int] = (720, 800),
    marker_radius_m: float | None = None,
    show_bones: bool = True,
    fill: float = 0.92,
    zoom: float = 1.0,
    muscle_smoothing: int = 4,
    label: str = "",
    quality: int = 7,
    frame_numbers=None,
    progress: bool = False,
) -> Path:
    """An mp4 (H.264 via imageio-ffmpeg) of a take, one video frame per take frame.

    Args:
        model: the ``FaceModel``.
        node_positions_m: (F, n, 3) node positions per frame.
        out_path: ``.mp4`` file (``.gif`` also works through imageio).
        fps: frames per second of the video.
        activations: (F, M) per-frame activations (colours), or None.
        captured_markers_m / simulated_markers_m: (F, k, 3) per-frame markers (red / green).
        cranium_affines / jaw_affines: (F, 3, 4) bone motion for the "muscles" style's bones.
        jaw_frame: "cranium" (default: the jaw affines are relative to the cranium, as
            ``wface.controls``) or "world".
        style, view, marker_radius_m, show_bones, fill, zoom, muscle_smoothing: see ``render_panels``.
        window_size: video size in pixels (each rounded down to a multiple of 16).
        label: text shown with the frame number.
        quality: imageio-ffmpeg quality 0-10.
        frame_numbers: (F,) numbers shown in the frame counter (default 1..F).
        progress: show a progress bar over the frames.

    Returns:
        The movie path.
    """
    pv = _pv()
    x = np.asarray(node_positions_m, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (model.n_nodes, 3) or x.shape[0] == 0:
        raise ValueError(f"node_positions_m must have shape (frames, {model.n_nodes}, 3); got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("node_positions_m contains NaN/inf")
    F = x.shape[0]
    if jaw_frame not in ("cranium", "world"):
        raise ValueError(f"jaw_frame must be 'cranium' or 'world', got {jaw_frame!r}")
    for name, arr in (
        ("activations", activations),
        ("captured_markers_m", captured_markers_m),
        ("simulated_markers_m", simulated_markers_m),
        ("cranium_affines", cranium_affines),
        ("jaw_affines", jaw_affines),
    ):
        if arr is not None and np.asarray(arr).shape[0] != F:
            raise ValueError(f"{name} has {np.asarray(arr).shape[0]} frames but node_positions_m has {F}")
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    skin_nodes = np.unique(model.skin_triangles)
    pts = _framing_points(
        model,
        [_box_corners(x[:, skin_nodes]), captured_markers_m, simulated_markers_m],
        bones=show_bones and style == "muscles",
    )
    r = marker_radius_m or 0.01 * float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    w, h = (int(window_size[0]) // 16 * 16, int(window_size[1]) // 16 * 16)
    p = _new_plotter(pv, (1, 1), (w, h))
    scene = _Scene(
        pv,
        p,
        model,
        style=style,
        marker_radius_m=r,
        show_bones=show_bones,
        muscle_radius_m=None,
        muscle_smoothing=muscle_smoothing,
    )
    if activations is not None:
        add_activation_legend(pv, p)
    key = add_marker_legend(p, captured=_shows(captured_markers_m), simulated=_shows(simulated_markers_m))
    reserve = LEGEND_BAND if activations is not None else 0.0
    _place_camera(p, pts, view, fill=fill, pad_m=r, zoom=zoom, reserve_bottom=reserve, reserve_top=key)
    p.enable_anti_aliasing("msaa", multi_samples=8)  # ssaa costs ~4x per frame; fxaa is not in OSMesa builds
    p.open_movie(str(out_path), framerate=int(round(fps)), quality=quality)
    text = None
    numbers = np.arange(1, F + 1) if frame_numbers is None else np.asarray(frame_numbers)
    last = int(numbers[-1]) if frame_numbers is not None else F
    try:
        for f in tqdm(range(F), desc="movie", unit="frame", disable=not progress, leave=False):
            bone = _bone_world_affines(
                None if cranium_affines is None else cranium_affines[f],
                None if jaw_affines is None else jaw_affines[f],
                jaw_frame,
            )
            scene.update(
                x[f],
                None if activations is None else activations[f],
                None if captured_markers_m is None else captured_markers_m[f],
                None if simulated_markers_m is None else simulated_markers_m[f],
                bone_affines=bone,
            )
            caption = f"{label}  frame {int(numbers[f])}/{last}".strip()
            if text is None:
                text = p.add_text(caption, position="upper_left", font_size=12, color="black")
            else:
                text.SetText(2, caption)  # vtkCornerAnnotation corner 2 = upper left
            p.write_frame()
    finally:
        p.close()
    return out_path
