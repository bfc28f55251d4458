"""The physics face: nodal forces, energy, stiffness and quasistatic equilibria of a ``FaceModel``.

f(x, a) = f0(x) + sum_i a_i f_i(x)  (Sifakis et al. 2005, eq. 1): f0 is the passive flesh plus the passive
fibre response, f_i the active fibre force of muscle i at full activation, or the constant dead load of a
pressure actuator (``wface.physics.pressure``; its channel in [-1, 1]). The constitutive model
(Mooney-Rivlin flesh with volumetric term, transversely isotropic fibres, inversion-safe clamped
singular values, projected-definite tangent) is documented in ``wface.kernels.fem``.

Sign conventions: ``forces`` are the nodal forces f = -dE/dx (N); the stiffness is K = -df/dx
(N/m), symmetric and, in its projected form, positive semi-definite (definite once Dirichlet rows
are removed). Positions are (n, 3) float64 metres; activations (M,) in [0, 1] or a {name: value}
dict.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp

from wface.model import FIBRE_STRESSES, FaceModel
from wface.physics.newton import Equilibrium, newton_quasistatic
from wface.physics.pressure import pressure_loads
from wface.physics.stiffness import StiffnessSolver, Tangent
from wface.solvers import BlockPattern, resolve_linear_solver
from wface.warp_runtime import init_warp, resolve_device

__all__ = ["Simulator", "StiffnessSolver", "Tangent"]

PRECISIONS = ("float64", "float32")

_TET_POOLS: dict[int, ThreadPoolExecutor] = {}  # per thread count, shared by every Simulator of the process


def _require_finite(name: str, value) -> None:
    """Raise ``ValueError`` naming the rows of ``value`` (positions, (k, 3)) that hold NaN or inf."""
    arr = np.atleast_2d(np.asarray(value, dtype=np.float64))
    bad = np.flatnonzero(~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1))
    if bad.size:
        raise ValueError(f"{name} has NaN or inf in {bad.size} row(s), first {bad[:5].tolist()}")


def _tet_pool(threads: int) -> ThreadPoolExecutor:
    """The process's pool of ``threads`` threads for split per-tet launches (started once: a pool per
    launch cost ~3 ms of thread start-up, ~5 % of a 100K-tet tracking frame)."""
    pool = _TET_POOLS.get(threads)
    if pool is None:
        pool = _TET_POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="wface-tets")
    return pool


if hasattr(os, "register_at_fork"):  # a forked child has none of the parent's threads
    os.register_at_fork(after_in_child=_TET_POOLS.clear)


class Simulator:
    """Quasistatic FEM of a face model on a Warp device.

    Args:
        model: the face (validated ``FaceModel``).
        device: Warp device, "cpu", "cuda:0" or "auto".
        precision: "float64" (default; use it for Newton and derivative checks) or "float32".
        solver: linear solver of the Newton steps: "auto" (direct on the CPU when installed, else
            CG), "cg" or "direct" (see ``wface.solvers.linear``).
        force_length_scale: exaggeration beyond physical limits (Sifakis et al. 2005, section 9): scales the
            whole active force-length curve, T = k (s a f_L + f_P), so activations stay in [0, 1].
            A scalar (every muscle) or an (M,) array (one scale per muscle, as
            ``wface.takes.exaggerate`` produces). Also a mutable, validated attribute.
    """

    def __init__(
        self,
        model: FaceModel,
        *,
        device: str = "cpu",
        precision: str = "float64",
        solver: str = "auto",
        force_length_scale: float | np.ndarray = 1.0,
    ):
        init_warp()
        import warp as wp

        from wface.kernels.fem import fem_kernels

        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        _require_finite("the model's rest_positions_m", model.rest_positions_m)
        self._wp = wp
        self.model = model
        self.device = resolve_device(device)
        self.precision = precision
        self.solver = solver
        self.linear_solver = resolve_linear_solver(solver, self.device)
        scalar = wp.float64 if precision == "float64" else wp.float32
        self._np_dtype = np.float64 if precision == "float64" else np.float32
        self._k = fem_kernels(scalar)
        k, dev, dt = self._k, self.device, self._np_dtype
        m = model.material
        self._fibre_law = FIBRE_STRESSES.index(m.fibre_stress)  # the kernels' flag (wface.kernels.fem)
        kappa_log, kappa_quadratic = m.bulk_moduli_pa()
        self._material = [dt(m.mu10_pa), dt(m.mu01_pa), dt(m.mu20_pa), dt(kappa_log), dt(kappa_quadratic)]
        self._material.append(dt(m.inversion_clamp))
        curves = m.curves_of(model.muscle_names) if model.n_muscles else np.zeros(1, np.int32)
        self._muscle_curves = wp.array(curves, dtype=wp.int32, device=dev)  # FIBRE_CURVES index per muscle
        self._material += [self._fibre_law, self._muscle_curves]
        n, nt = model.n_nodes, model.n_tets
        self._tets = wp.array(model.tets.astype(np.int32), dtype=wp.int32, device=dev)
        self._dm_inv = wp.array(model.dm_inv.astype(dt), dtype=k.mat33, device=dev)
        self._volume = wp.array(model.rest_volume_m3.astype(dt), dtype=k.scalar, device=dev)
        entry_start = np.searchsorted(model.fibre_tet, np.arange(nt + 1)).astype(np.int32)
        coef = model.fibre_fraction * model.muscle_strength[model.fibre_muscle] * m.sigma_max_pa
        self._entry_start = wp.array(entry_start, dtype=wp.int32, device=dev)
        self._entry_tet = wp.array(model.fibre_tet.astype(np.int32), dtype=wp.int32, device=dev)
        self._entry_muscle = wp.array(model.fibre_muscle.astype(np.int32), dtype=wp.int32, device=dev)
        self._entry_dir = wp.array(model.fibre_direction.astype(dt), dtype=k.vec3, device=dev)
        self._entry_coef = wp.array(coef.astype(dt), dtype=k.scalar, device=dev)
        self._x = wp.zeros(n, dtype=k.vec3, device=dev)
        self._v = wp.zeros(n, dtype=k.vec3, device=dev)
        self._out = wp.zeros(n, dtype=k.vec3, device=dev)
        self._f = wp.zeros(n, dtype=k.vec3, device=dev)
        self._e = wp.zeros(nt, dtype=k.scalar, device=dev)
        self._a = wp.zeros(max(model.n_muscles, 1), dtype=k.scalar, device=dev)
        self._a_scaled = np.zeros(model.n_muscles)  # host copy of s a (the pressure loads use it)
        self._pressure = pressure_loads(model)
        self._tangent_wp = None
        self.force_length_scale = force_length_scale
        self.parallel_min_tets = 20_000  # CPU: per-tet kernels run on all cores above this size
        self._patterns: dict = {}
        self._block_index: dict = {}

    # ------------------------------------------------------------------ inputs
    @property
    def force_length_scale(self) -> float | np.ndarray:
        """Scale of the active force-length curve: a float, or an (M,) float64 array per muscle."""
        return self._force_length_scale

    @force_length_scale.setter
    def force_length_scale(self, value: float | np.ndarray) -> None:
        s = np.asarray(value, dtype=np.float64)
        if s.ndim == 0:
            if not (np.isfinite(s) and s >= 0):
                raise ValueError(f"force_length_scale must be finite and >= 0, got {value}")
            self._force_length_scale = float(s)
            return
        if s.shape != (self.model.n_muscles,):
            raise ValueError(f"per-muscle force_length_scale has shape {s.shape}, expected ({self.model.n_muscles},)")
        if not (np.all(np.isfinite(s)) and np.all(s >= 0)):
            raise ValueError("per-muscle force_length_scale must be finite and >= 0")
        self._force_length_scale = s.copy()

    def _muscle_scale(self) -> float | np.ndarray:
        """The scale as a float or an (M, 1, 1) array for per-muscle force fields."""
        s = self._force_length_scale
        return s if isinstance(s, float) else s[:, None, None]

    @property
    def n_nodes(self) -> int:
        return self.model.n_nodes

    def _set_state(self, x: np.ndarray | None, a) -> None:
        x = self.model.rest_positions_m if x is None else np.asarray(x, dtype=np.float64)
        if x.shape != (self.model.n_nodes, 3):
            raise ValueError(f"positions have shape {x.shape}, expected ({self.model.n_nodes}, 3)")
        self._x.assign(x.astype(self._np_dtype))
        if self.model.n_muscles:
            # activations are checked in [0, 1]; the kernels see s a (T is linear in a, see __init__)
            a = self.model.activation_vector(a) * self.force_length_scale
            self._a_scaled = a
            self._a.assign(a.astype(self._np_dtype))
        self._x_host = x

    def _pressure_energy_and_forces(self, f: np.ndarray | None) -> float:
        """Add the pressure actuators' dead loads s a P g to ``f`` (n, 3) at the state of the last
        ``_set_state``; return their energy -s a P g . (x - X) (``wface.physics.pressure``)."""
        e = 0.0
        for load in self._pressure:
            a = float(self._a_scaled[load.channel])
            if a == 0.0:
                continue
            u = self._x_host[load.nodes] - self.model.rest_positions_m[load.nodes]
            e -= a * float(np.sum(load.force_n * u))
            if f is not None:
                f[load.nodes] += a * load.force_n
        return e

    def _launch_tets(
        self,
        kernel,
        inputs: list,
        *,
        sliced: tuple[int, ...],
        offsets: tuple[int, ...] = (),
        scattered: tuple[int, ...] = (),
    ) -> None:
        """Launch a per-tet kernel, on the CPU over tet ranges on all cores.

        Warp CPU kernels run on one thread (docs/design.md, "Performance") but a launch releases the GIL, so
        large meshes are cut into one contiguous tet range per core. ``sliced``: indices of inputs
        indexed by tet (sliced [lo:hi], per-tet outputs included); ``offsets``: per-tet offset
        arrays (sliced [lo:hi+1]); ``scattered``: outputs accumulated with atomics at nodes or
        blocks: each extra thread gets a zeroed private copy, added to the original afterwards
        (CPU atomics are plain +=, never shared between threads).
        """
        wp = self._wp
        m = self.model.n_tets
        threads = min(os.cpu_count() or 1, 8)
        if not self.device.startswith("cpu") or threads < 2 or m < self.parallel_min_tets:
            wp.launch(kernel, m, inputs=inputs, device=self.device)
            return
        bounds = np.linspace(0, m, threads + 1).astype(int)
        private = [{i: (inputs[i] if k == 0 else wp.zeros_like(inputs[i])) for i in scattered} for k in range(threads)]

        def run(k: int) -> None:
            lo, hi = int(bounds[k]), int(bounds[k + 1])
            args = list(inputs)
            for i in sliced:
                args[i] = inputs[i][lo:hi]
            for i in offsets:
                args[i] = inputs[i][lo : hi + 1]
            for i in scattered:
                args[i] = private[k][i]
            wp.launch(kernel, hi - lo, inputs=args, device=self.device)

        list(_tet_pool(threads).map(run, range(threads)))
        for i in scattered:
            total = inputs[i].numpy()
            for k in range(1, threads):
                total += private[k][i].numpy()

    def _launch_per_tet(self, kernel, extra_inputs, *outputs, scattered: tuple[int, ...] = ()) -> None:
        """``_launch_tets`` for kernels whose inputs start with ``_model_inputs()``."""
        inputs = [*self._model_inputs(), *extra_inputs, *outputs]
        n_model = len(self._model_inputs())
        per_tet_outputs = tuple(i for i in range(n_model + len(extra_inputs), len(inputs)) if i not in scattered)
        self._launch_tets(
            kernel, inputs, sliced=(0, 1, 2, *per_tet_outputs), offsets=(3 + len(self._material),), scattered=scattered
        )

    def _model_inputs(self):
        return [
            self._tets,
            self._dm_inv,
            self._volume,
            *self._material,
            self._entry_start,
            self._entry_muscle,
            self._entry_dir,
            self._entry_coef,
        ]

    # ------------------------------------------------------------------ energy and forces
    def energy(self, x: np.ndarray | None = None, activations=None) -> float:
        """Total elastic energy (J) at positions x (n, 3) with activations (dict, (M,) array or None)."""
        self._set_state(x, activations)
        self._launch_per_tet(self._k.element_energy, [self._x, self._a], self._e)
        return float(self._e.numpy().astype(np.float64).sum()) + self._pressure_energy_and_forces(None)

    def energy_and_forces(self, x: np.ndarray | None = None, activations=None) -> tuple[float, np.ndarray]:
        """(E, f) with f = -dE/dx of shape (n, 3), in one pass."""
        self._set_state(x, activations)
        self._f.zero_()
        n_in = len(self._model_inputs()) + 2
        self._launch_per_tet(self._k.element_forces, [self._x, self._a], self._f, self._e, scattered=(n_in,))
        f = self._f.numpy().astype(np.float64)
        e = float(self._e.numpy().astype(np.float64).sum()) + self._pressure_energy_and_forces(f)
        return e, f

    def forces(self, x: np.ndarray | None = None, activations=None) -> np.ndarray:
        """Nodal forces f(x, a) = f0(x) + sum_i a_i f_i(x), (n, 3) newtons."""
        return self.energy_and_forces(x, activations)[1]

    def last_element_energies(self) -> np.ndarray:
        """(m,) per-tet energies of the latest ``energy`` / ``energy_and_forces`` call (the elastic
        energy: the pressure actuators' potential is not a tet's)."""
        return self._e.numpy().astype(np.float64)

    def element_energies(self, x: np.ndarray | None = None, activations=None) -> np.ndarray:
        """(m,) energy of each tet (J)."""
        self.energy(x, activations)
        return self._e.numpy().astype(np.float64)

    def _fibre_inputs(self) -> list:
        """The model inputs of the per-fibre-entry muscle force kernels."""
        return [
            self._tets,
            self._dm_inv,
            self._volume,
            self._entry_tet,
            self._entry_muscle,
            self._entry_dir,
            self._entry_coef,
            self._np_dtype(self.model.material.inversion_clamp),
            self._fibre_law,
            self._muscle_curves,
        ]

    def muscle_forces(self, x: np.ndarray | None = None) -> np.ndarray:
        """f_i(x): active force of each muscle at full activation, (M, n, 3) newtons, one launch
        (times ``force_length_scale``); a pressure actuator's row is its constant dead load."""
        wp = self._wp
        if x is not None:
            _require_finite("positions", x)
        self._set_state(x, None)
        M, n = self.model.n_muscles, self.model.n_nodes
        out = wp.zeros((max(M, 1), n), dtype=self._k.vec3, device=self.device)
        if self.model.fibre_tet.size:
            wp.launch(
                self._k.muscle_forces,
                self.model.fibre_tet.size,
                inputs=[*self._fibre_inputs(), self._x, out],
                device=self.device,
            )
        forces = out.numpy()[:M].astype(np.float64)  # a copy: scaled in place
        for load in self._pressure:
            forces[load.channel, load.nodes] = load.force_n
        forces *= self._muscle_scale()
        return forces

    def muscle_force_sum(self, weights: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """sum_i w_i f_i(x), (n, 3) newtons: ``weights @ muscle_forces(x)`` in one launch, without the
        (M, n, 3) array (``weights``: (M,) per muscle, e.g. an activation step)."""
        wp = self._wp
        M, n = self.model.n_muscles, self.model.n_nodes
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != (M,):
            raise ValueError(f"weights have shape {w.shape}, expected ({M},)")
        w = w * self._force_length_scale  # float, or (M,) per muscle
        self._set_state(x, None)
        out = wp.zeros(n, dtype=self._k.vec3, device=self.device)
        if self.model.fibre_tet.size and np.any(w != 0.0):
            w_wp = wp.array(w.astype(self._np_dtype), dtype=self._k.scalar, device=self.device)
            wp.launch(
                self._k.muscle_force_sum,
                self.model.fibre_tet.size,
                inputs=[*self._fibre_inputs(), self._x, w_wp, out],
                device=self.device,
            )
        forces = out.numpy().astype(np.float64)
        for load in self._pressure:
            forces[load.nodes] += w[load.channel] * load.force_n
        return forces

    # ------------------------------------------------------------------ stiffness
    def tangent(self, x: np.ndarray | None = None, activations=None, *, project: bool = True) -> Tangent:
        """Stiffness K = -df/dx at (x, a): projected to PSD (default) or the exact Hessian of E."""
        wp = self._wp
        self._set_state(x, activations)
        tangent = wp.empty(self.model.n_tets, dtype=self._k.vec45, device=self.device)
        self._launch_per_tet(self._k.element_tangent, [int(bool(project)), self._x, self._a], tangent)
        return Tangent(self, tangent, project)

    def stiffness_matvec(self, x: np.ndarray | None, activations, v: np.ndarray, *, project: bool = True) -> np.ndarray:
        """K(x, a) v, matrix-free; v and the result are (n, 3)."""
        return self.tangent(x, activations, project=project).matvec(v)

    def assemble_stiffness(
        self, x: np.ndarray | None = None, activations=None, *, project: bool = True, nodes: str | np.ndarray = "all"
    ) -> sp.csr_matrix:
        """Assembled K as scipy CSR float64.

        Args:
            nodes: "all" (3n x 3n), "free" (rows/columns of nodes not attached to a bone), or an
                array of node ids (in increasing order) whose rows and columns are kept.
        """
        return self.tangent(x, activations, project=project).assemble(self.pattern(nodes))

    def stiffness_solver(
        self,
        x: np.ndarray | None = None,
        activations=None,
        *,
        project: bool = True,
        nodes: str | np.ndarray = "free",
        solver: str | None = None,
    ) -> StiffnessSolver:
        """A ``StiffnessSolver`` for K_UU at (x, a) over the unknown ``nodes`` (default: free nodes).

        Example (activation Jacobian, Sifakis et al. 2005, eq. 5): ``dX = sim.stiffness_solver(x, a)
        .solve_nodal(sim.muscle_forces(x))`` gives dX_U/da_i for every muscle i, shape (M, n, 3).
        """
        engine = resolve_linear_solver(solver, self.device) if solver else self.linear_solver
        return StiffnessSolver(self.tangent(x, activations, project=project), self.pattern(nodes), engine)

    def pattern(self, nodes: str | np.ndarray | None = "all") -> BlockPattern:
        """Block sparsity pattern (cached) over "all" nodes, the "free" nodes, given node ids, or
        "coupling": rows of the free nodes, columns of ``model.attached_nodes`` in their order (K_UC)."""
        if isinstance(nodes, str) and nodes == "coupling":
            if "coupling" not in self._patterns:
                m = self.model
                self._patterns["coupling"] = BlockPattern(m.tets, m.n_nodes, m.free_nodes, col_nodes=m.attached_nodes)
            return self._patterns["coupling"]
        if nodes is None or (isinstance(nodes, str) and nodes == "all"):
            key, ids = "all", None
        elif isinstance(nodes, str) and nodes == "free":
            key, ids = "free", self.model.free_nodes
        else:
            ids = np.unique(np.asarray(nodes, dtype=np.int64))
            key = ("ids", ids.tobytes())
        if key not in self._patterns:
            self._patterns[key] = BlockPattern(self.model.tets, self.model.n_nodes, ids)
        return self._patterns[key]

    def _free_rows_pattern(self):
        """(pattern of the free rows and the free-then-attached columns, mask of its K_UU blocks, mask of
        its K_UC blocks); both subsets come out in the order of ``pattern("free")`` / ``pattern("coupling")``
        (blocks sorted by row, then column, and the free columns come first)."""
        if "free_rows" not in self._patterns:
            m = self.model
            cols = np.concatenate([m.free_nodes, m.attached_nodes])
            rows = BlockPattern(m.tets, m.n_nodes, m.free_nodes, col_nodes=cols)
            uu = rows.indices < m.free_nodes.size
            self._patterns["free_rows"] = (rows, uu, ~uu)
        return self._patterns["free_rows"]

    def _block_index_array(self, pattern: BlockPattern):
        key = id(pattern)
        if key not in self._block_index:
            self._block_index[key] = self._wp.array(pattern.block_index, dtype=self._wp.int32, device=self.device)
        return self._block_index[key]

    # ------------------------------------------------------------------ equilibrium
    def solve(
        self,
        activations=None,
        attached_positions: np.ndarray | None = None,
        x0: np.ndarray | None = None,
        *,
        tol: float | None = None,
        max_iterations: int = 40,
        solver: str | None = None,
        stiffness: str = "auto",
        reuse_factor: bool = False,
        contact=None,
        chord=None,
        factor_precision: str = "float64",
        refactor=None,
        force_scale: float | None = None,
        twin=None,
    ) -> Equilibrium:
        """Quasistatic equilibrium f_U(x, a) = 0 with attached nodes at ``attached_positions``.

        Args:
            activations: dict {muscle: value}, (M,) array, or None (all zero).
            attached_positions: (a, 3) positions of ``model.attached_nodes`` (default: rest), e.g.
                from ``wface.controls.attached_positions_from_affines``.
            x0: warm start (n, 3); its attached nodes are replaced by the targets through one
                linearised "lift" step. Default: rest positions.
            tol: convergence on the relative residual (see ``Equilibrium``); default 1e-6 in float64 and
                1e-3 in float32, whose forces carry a relative round-off of about 1e-4 (a float32 solve
                stalls at a residual of 2-3e-4 with positions within 1e-5 mm of float64's).
            max_iterations: Newton iteration cap.
            solver: override of the simulator's linear solver ("auto" | "cg" | "direct").
            stiffness: "auto" (exact Hessian when definite, else projected), "projected" or "exact";
                see ``wface.physics.newton``.
            reuse_factor: with the direct solver, precondition CG with the previous step's factor
                and refactor only when that CG does not converge within a few iterations (off by
                default: on the 2-core CPU at 20K-100K tets a fresh factorisation was as fast).
            contact: a ``wface.physics.contact.Contact`` (lips, teeth, bones, rigid obstacles) or
                None (default: no contact, the solve is unchanged). Teeth and bone meshes follow the
                bones implied by ``attached_positions``; contact statistics land on the result.
            chord: the factor of K_UU at a nearby configuration (e.g. a ``StiffnessSolver``, or the
                tracker's last Jacobian factor) for chord Newton steps: back-solves instead of fresh
                factorisations while they converge fast (``wface.physics.newton``).
            factor_precision: "float64", or "float32" for single-precision factors (inexact Newton
                steps, 1.5x cheaper factorisations; the tracker's choice).
            refactor: with ``chord``, a callable x -> a new chord factored at x, for adaptive
                refactorisation where the chord contracts poorly (``wface.physics.newton``).
            force_scale: the relative residual's denominator (N); default ||f_U(X_load)||.
            twin: a float32 ``Simulator`` of the model for the energies and forces of the solve
                (loose tolerances only; ``wface.physics.newton``).

        Returns:
            ``wface.physics.newton.Equilibrium``.
        """
        start = time.perf_counter()
        if tol is None:
            tol = 1e-6 if self.precision == "float64" else 1e-3
        if not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be a positive number, got {tol}")
        if int(max_iterations) < 1:
            raise ValueError(f"max_iterations must be at least 1, got {max_iterations}")
        for name, value in (("attached_positions", attached_positions), ("x0", x0)):
            if value is not None:
                _require_finite(name, value)
        result = newton_quasistatic(
            self,
            self.model.activation_vector(activations),
            attached_positions,
            x0,
            tol=tol,
            max_iterations=max_iterations,
            solver=solver or self.linear_solver,
            stiffness=stiffness,
            reuse_factor=reuse_factor,
            contact=contact,
            chord=chord,
            factor_precision=factor_precision,
            refactor=refactor,
            force_scale=force_scale,
            twin=twin,
        )
        result.seconds = time.perf_counter() - start
        return result
