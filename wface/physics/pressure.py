"""Pressure actuators: a pressure on a surface of the flesh as one more activation channel.

A pressure p on a surface S that bounds the flesh pushes it with the traction -p n (n the unit
normal pointing out of the flesh, into the cavity): per triangle the force -p A n, shared equally
by its three vertices (the consistent load of linear triangles for a uniform pressure). The load is
*dead*: A n is the rest configuration's, in the frame the face is simulated in (the cranium's), so
the actuator's force is linear in its control and independent of x,

    f_p(a) = a P g,    g_v = -sum_{T ni v} (A n)_T / 3,    E_p = -a P g . (x - X)

with a in [-1, 1] (suction to pressure) and P the actuator's maximum pressure (Pa). It is exactly
the f(x, a) = f0(x) + sum_i a_i f_i(x) of Sifakis et al. 2005 (eq. 1) with a constant f_i = P g, so
the Newton solves, the activation Jacobian K dY/da_i = f_i and the dynamics take it as they take
a muscle, and it adds nothing to the stiffness. A follower load (normals turning with the surface)
would add a non-symmetric load stiffness; for the few-millimetre puffs of a cheek the wall turns by
a few degrees (docs/design.md, "Intra-oral pressure", has the measurement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wface.model import FaceModel

__all__ = ["PressureLoad", "pressure_loads"]


@dataclass(frozen=True)
class PressureLoad:
    """One pressure actuator's nodal load at full control (a = 1)."""

    channel: int  # index into model.muscle_names
    nodes: np.ndarray  # (k,) int64 node ids that carry a load
    force_n: np.ndarray  # (k, 3) newtons at full control, P g on those nodes


def pressure_loads(model: FaceModel) -> list[PressureLoad]:
    """The dead nodal loads of every pressure actuator of ``model`` (module docstring)."""
    out = []
    x = model.rest_positions_m
    for name, max_pa in model.pressure_actuators.items():
        tri = np.asarray(model.surface_groups[name], dtype=np.int64)
        p = x[tri]
        area_normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # A n, out of the flesh
        g = np.zeros_like(x)
        for j in range(3):
            np.add.at(g, tri[:, j], -area_normal / 3.0)
        nodes = np.unique(tri)
        out.append(PressureLoad(model.muscle_index(name), nodes, max_pa * g[nodes]))
    return out
