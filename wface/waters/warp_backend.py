"""Direct Waters evaluation with a Warp kernel (``wface.kernels.waters``): every muscle on every vertex of
the *current* points each call, no precompiled field. For meshes whose rest shape changes from frame to
frame (e.g. Waters on top of a simulated skin), and for CUDA. Same results as ``WatersRig`` (float64).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from wface.warp_runtime import resolve_device
from wface.waters.layout import MuscleLayout
from wface.waters.muscles import LinearMuscle

__all__ = ["WarpWaters"]

_REGION = {"any": 0, "upper": 1, "lower": 2}


class WarpWaters:
    """A layout uploaded to a Warp device.

    Args:
        layout: the muscle layout (metres).
        device: Warp device ("cpu", "cuda:0"; None/"auto" picks CUDA when present).
    """

    def __init__(self, layout: MuscleLayout, *, device: str | None = None):
        import warp as wp

        # keep Warp's start-up banner and module-load messages off stdout (JSON output goes there)
        wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
        wp.config.quiet = True
        self.layout = layout
        self.device = resolve_device(device)
        m = layout.muscles
        zero3 = np.zeros(3)

        def col(fn, dtype=np.float64):
            return np.array([fn(u) for u in m], dtype=dtype)

        lin = [isinstance(u, LinearMuscle) for u in m]
        arrays = {
            "kind": (np.array([0 if f else 1 for f in lin], np.int32), wp.int32),
            "region": (np.array([_REGION[u.region] for u in m], np.int32), wp.int32),
            "origin": (col(lambda u: u.bone_m if isinstance(u, LinearMuscle) else u.centre_m), wp.vec3d),
            "axis": (col(lambda u: u.axis if isinstance(u, LinearMuscle) else u.horizontal), wp.vec3d),
            "vertical": (col(lambda u: zero3 if isinstance(u, LinearMuscle) else u.vertical), wp.vec3d),
            "normal": (col(lambda u: zero3 if isinstance(u, LinearMuscle) else u.normal), wp.vec3d),
            "semi_axes": (col(lambda u: np.ones(3) if isinstance(u, LinearMuscle) else u.semi_axes_m), wp.vec3d),
            "zone_rad": (col(lambda u: np.radians(u.zone_deg) if isinstance(u, LinearMuscle) else 0.0), wp.float64),
            "fall_start": (col(lambda u: u.fall_start_m if isinstance(u, LinearMuscle) else 0.0), wp.float64),
            "fall_finish": (col(lambda u: u.fall_finish_m if isinstance(u, LinearMuscle) else 0.0), wp.float64),
            "strength": (col(lambda u: u.spring_constant_m if isinstance(u, LinearMuscle) else u.tension), wp.float64),
            "elasticity": (col(lambda u: u.elasticity), wp.float64),
            "protrusion": (col(lambda u: 0.0 if isinstance(u, LinearMuscle) else u.protrusion_m), wp.float64),
            "lower_semi_axis": (col(lambda u: 0.0 if isinstance(u, LinearMuscle) else u.lower_semi_axis_m), wp.float64),
        }
        self._model = {k: wp.array(v, dtype=t, device=self.device) for k, (v, t) in arrays.items()}

    def muscle_displacement(
        self,
        points_m: np.ndarray,
        contractions: Mapping[str, float] | np.ndarray,
        *,
        jaw_weights: np.ndarray | None = None,
        movable: np.ndarray | None = None,
        limit: bool = True,
    ) -> np.ndarray:
        """(n, 3) combined, limited muscle displacement at ``points_m`` (n, 3), metres.

        Args:
            contractions: ``{muscle: value}`` or an (M,) array in [0, 1].
            jaw_weights: (n,) jaw weights for the upper/lower region factors (default: the layout's planes).
            movable: (n,) bool, vertices the muscles may move (default: all).
        """
        import warp as wp

        p = np.ascontiguousarray(points_m, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
            raise ValueError(f"points must be finite with shape (n, 3), got {p.shape}")
        n = len(p)
        c = self._contractions(contractions)
        regions = self._model["region"]
        if jaw_weights is None:
            if self.layout.jaw is None:  # no jaw: no upper/lower split (as in WatersRig)
                regions = wp.zeros(len(self.layout.muscles), dtype=wp.int32, device=self.device)
            jaw_weights = self.layout.jaw.weights(p) if self.layout.jaw is not None else np.zeros(n)
        mov = np.ones(n, np.int32) if movable is None else np.asarray(movable, dtype=bool).astype(np.int32)
        if np.shape(jaw_weights) != (n,) or mov.shape != (n,):
            raise ValueError(f"jaw_weights and movable must have shape ({n},)")
        out = wp.zeros(n, dtype=wp.vec3d, device=self.device)
        md = self._model
        wp.launch(
            _kernel(),
            dim=n,
            inputs=[
                md["kind"],
                regions,
                md["origin"],
                md["axis"],
                md["vertical"],
                md["normal"],
                md["semi_axes"],
                md["zone_rad"],
                md["fall_start"],
                md["fall_finish"],
                md["strength"],
                md["elasticity"],
                md["protrusion"],
                md["lower_semi_axis"],
                float(self.layout.max_displacement_m),
                float(self.layout.overlap_factor),
                wp.array(c, dtype=wp.float64, device=self.device),
                wp.array(p, dtype=wp.vec3d, device=self.device),
                wp.array(np.asarray(jaw_weights, np.float64), dtype=wp.float64, device=self.device),
                wp.array(mov, dtype=wp.int32, device=self.device),
                int(bool(limit)),
            ],
            outputs=[out],
            device=self.device,
        )
        return out.numpy()

    def _contractions(self, contractions) -> np.ndarray:
        names = self.layout.muscle_names
        if isinstance(contractions, Mapping):
            c = np.zeros(len(names))
            for k, v in contractions.items():
                if k not in names:
                    raise KeyError(f"unknown muscle {k!r} for layout {self.layout.name!r}")
                c[names.index(k)] = float(v)
        else:
            c = np.asarray(contractions, dtype=np.float64).reshape(-1)
            if c.shape != (len(names),):
                raise ValueError(f"contraction vector has shape {c.shape}, expected ({len(names)},)")
        if not np.all(np.isfinite(c)) or np.any((c < 0) | (c > 1)):
            raise ValueError("contractions must be finite and lie in [0, 1]")
        return c


def _kernel():
    from wface.kernels.waters import waters_displacement

    return waters_displacement
