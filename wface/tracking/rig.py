"""The face as a function of its controls, X(c), and its Jacobian dX/dc (Sifakis et al. 2005, sections 5-8).

c = (a, b): M activations then the 24 bone parameters of ``wface.controls``. The equilibrium is
solved in the cranium frame, Y(a, Mm, tm); world positions are X = Mc Y + tc.

Jacobians at an equilibrium Y* (K = -df/dx, the exact tangent at Y*):
- activations (eq. 5):   K_UU dY_U/da_i = f_i(Y*)_U          (f_i: muscle i at full activation)
- jaw parameters (eq. 6): K_UU dY_U/db_j = -K_UC dX_C/db_j
- cranium parameters:     dX/dMc_rc = e_r Y_c,  dX/dtc = I    (analytic)
and dX/da = Mc dY/da, dX/db_jaw = Mc dY/db_jaw. All M + 12 solved columns share one
factorisation of K_UU (multi right-hand side), or one preconditioner when no direct solver exists.

With contact (``FaceRig(model, contact=Contact(...))``) the equilibria include the penalty forces
f_c(Y) and the Jacobians follow from the implicit-function theorem with the active set fixed:
K is the elastic tangent plus the contact Hessian H_c(Y*): k'' dg dg^T + E'(g) d2g of every active
pair with its closest feature held fixed, the derivatives of the normals and closest-point weights
with respect to the triangle vertices included (the Newton solves drop them;
``wface.physics.frozen.exact_self_hessian``). Obstacles that follow the jaw (the lower teeth, the
jaw bone) add d f_c / d b_jaw = Q dc/db_jaw + E'(g) dn/db_jaw to the jaw columns (c: the closest
point on the obstacle, moving with the jaw affine; Q: the pair's Hessian block; n turns with a face
feature); other obstacles are fixed in the cranium frame. The Jacobian is exact where no pair enters
or leaves contact for small control changes (pairs at exactly zero penetration are a kink of the C1
penalty: ``Contact(smoothing_m=...)`` makes it C2; the tracking commands use
``wface.physics.penalty.TRACKING_SMOOTHING_M``).

Factor reuse (docs/design.md, "Performance"): ``linearize`` keeps the factorisation of K_UU at the
equilibrium together with dY/dc and the coupling block K_UC (``RigLinearization``); the next
equilibria near it (the line-search trials of the next Gauss-Newton step, the next frame) take
chord Newton steps with that factor (``equilibrium(..., chord=...)``) instead of factoring anew, so
a tracked frame costs one factorisation at its new equilibrium plus one back-solve per column. With
contact the kept factor is of K_UU plus the contact Hessian at the equilibrium, and the solves' chord
steps use it the same way (where the contact set has changed, a chord step contracts poorly and the
solve refactors at its iterate, contact included).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from wface.controls import IDENTITY_BONES, affine_from_params, attached_positions, attached_positions_jacobian
from wface.model import FaceModel
from wface.physics.frozen import exact_self_hessian
from wface.physics.simulator import Simulator
from wface.solvers import LinearSolver, MatrixOperator, NotPositiveDefiniteError

__all__ = ["FaceRig", "RigLinearization", "RigState", "RowsLinearization", "TWIN_MIN_TOL"]

TWIN_MIN_TOL = 1e-4  # the tightest solve tolerance a float32 twin may serve (its reading error: ~1e-5)


class _OwnsChord:
    """The factor of K_UU a linearisation owns (held in the attribute ``_chord_attr``): freed, replaced
    or handed on (``wface.tracking.adaptive``)."""

    _chord_attr = "chord"

    def free(self) -> None:
        chord = getattr(self, self._chord_attr)
        if chord is not None:
            chord.free()
            setattr(self, self._chord_attr, None)

    def replace_chord(self, new) -> None:
        """Adaptive refactorisation: ``new`` (a solve's ``new_chord``) replaces the factor, which is freed."""
        if new is not None and new is not getattr(self, self._chord_attr):
            self.free()
            setattr(self, self._chord_attr, new)

    def take_chord(self):
        """The factor, handed over (this linearisation no longer owns it)."""
        chord = getattr(self, self._chord_attr)
        setattr(self, self._chord_attr, None)
        return chord

    @property
    def factored_at(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(controls, cranium-frame positions (n, 3)) where the chord's factor was taken, or None:
        ``FaceRig.linearize(state, stiffness=rig.stiffness_at(*factored_at))`` rebuilds this
        linearisation bit for bit (a resumed take continues as the interrupted run would have)."""
        return getattr(getattr(self, self._chord_attr), "at", None)


@dataclass
class RigLinearization(_OwnsChord):
    """The rig linearised at an equilibrium: dY/d(a, b_jaw) and the factor of K_UU there.

    ``chord`` (``solve(rhs)`` and ``coupling(dx_c)``, see ``wface.physics.newton``) is None when no
    factorisation exists (the CG engine); with contact it is the factor of K_UU plus the contact
    Hessian. ``free()`` releases the factor."""

    state: RigState
    jy: np.ndarray  # (3n, M + 12) cranium-frame Jacobian of all nodes
    chord: object | None = None
    seconds: dict = field(default_factory=dict)
    age: int = 0  # frames since ``jy`` was solved (``wface.tracking.adaptive``: a kept Jacobian)
    jacobian_at: tuple | None = None  # (cranium-frame y where jy was solved, (controls, y) of its factor)
    held: np.ndarray | None = None  # (M,) bool: muscles whose columns were not solved (zero; ``linearize``)
    fill: tuple | None = None  # (nodes, rows (k, 3, M + 12)): older rows standing in for the held columns there

    full = True  # dY/dc of every node (``RowsLinearization``: of a few)

    def node_rows(self, nodes: np.ndarray) -> np.ndarray:
        """(k, 3, M + 12) dY/d(a, b_jaw) of the nodes ``nodes`` (held columns from ``fill`` at its nodes)."""
        rows = self.jy.reshape(-1, 3, self.jy.shape[1])[nodes]
        if self.held is not None and self.fill is not None and np.array_equal(nodes, self.fill[0]):
            cols = np.flatnonzero(self.held)
            rows[:, :, cols] = np.asarray(self.fill[1])[:, :, cols]
        return rows

    def predict(self, dc_y: np.ndarray) -> np.ndarray:
        """(n, 3) dY = dY/d(a, b_jaw) dc_y: the linear change of the equilibrium (cranium frame)."""
        return (self.jy @ dc_y).reshape(-1, 3)


class RowsLinearization(_OwnsChord):
    """The rig at an equilibrium whose Jacobian is known on some nodes only (a first pass's rows, kept
    in its frame file: ``FaceRig.linearize_rows``). A Gauss-Newton step needs only the marker nodes'
    rows; the linear prediction dY/dc dc of every node, the warm start of the line search's solves,
    is one back-solve K_UU^-1 (f_a da - K_UC dX_C/db db) with the factor of K_UU at the equilibrium,
    taken on first use (``chord``) and serving the solves' chord steps too. So a second pass re-estimates
    a frame from its first-pass solution with one factorisation and no Jacobian columns."""

    full = False
    _chord_attr = "_chord"

    def __init__(self, rig: FaceRig, state: RigState, nodes: np.ndarray, rows: np.ndarray, chord=None):
        self.rig, self.state = rig, state
        self.nodes, self.rows = np.asarray(nodes), np.asarray(rows, dtype=np.float64)
        self._chord: _Chord | None = chord  # a nearby factor handed on (adaptive refactorisation), else made here
        self._jaw_contact: np.ndarray | None = None  # with contact: (3|U|, 12) jaw-following obstacles' forces
        self.seconds: dict = {}

    @property
    def chord(self) -> _Chord | None:
        """The factorised stiffness at the equilibrium (``FaceRig.stiffness_at``), made on first use."""
        if self._chord is None:
            self._chord = self.rig.stiffness_at(self.state.controls, self.state.y_m, warn=False)
        return self._chord

    def node_rows(self, nodes: np.ndarray) -> np.ndarray:
        if not np.array_equal(nodes, self.nodes):
            raise ValueError("these Jacobian rows are of other nodes")
        return self.rows

    def predict(self, dc_y: np.ndarray) -> np.ndarray:
        rig, M = self.rig, self.rig.n_muscles
        chord = self.chord
        dxc = rig._dxc_djaw @ dc_y[M:]
        rhs = -(chord.k_uc @ dxc)
        if M:
            rhs += rig.sim.muscle_force_sum(dc_y[:M], self.state.y_m).reshape(-1)[rig._free_dofs]
        if rig.contact is not None:  # the obstacles that follow the jaw push the flesh with it
            if self._jaw_contact is None:  # d f_c / d b_jaw at the equilibrium, once for all predictions
                pairs = rig._contact_pairs(self.state.controls, self.state.y_m)
                self._jaw_contact = rig._contact_jaw_rhs(pairs, self.state.y_m)[rig._free_dofs]
            rhs += self._jaw_contact @ dc_y[M:]
        counts0 = rig._linear.counters()
        sol = chord.bound.solve(rhs[:, None], rtol=1e-10)[:, 0]
        rig._count(counts0)
        out = np.zeros(3 * rig._n)
        out[rig._free_dofs] = sol
        out[rig._fixed_dofs] = dxc
        return out.reshape(-1, 3)


class _Chord:
    """K_UU bound to its solver (factorised with the direct engine) and the coupling block K_UC at one
    configuration (``FaceRig.stiffness_at``): the chord steps of nearby solves (``solve``, ``coupling``)
    and the back-solves of a Jacobian."""

    def __init__(self, bound, k_uc, seconds: dict | None = None):
        self.bound, self.k_uc = bound, k_uc
        self.seconds = seconds or {}
        self.projected = False  # the projected tangent was factored (the exact one is not definite there)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self.bound.solve(rhs)

    def coupling(self, dx_c: np.ndarray) -> np.ndarray:
        return self.k_uc @ np.asarray(dx_c, dtype=np.float64).reshape(-1)

    def free(self) -> None:
        self.bound.free()


@dataclass
class RigState:
    """An equilibrium of the rig for controls c."""

    controls: np.ndarray  # (M + 24,)
    y_m: np.ndarray  # (n, 3) equilibrium in the cranium frame
    x_m: np.ndarray  # (n, 3) world positions
    newton_iterations: int = 0
    residual_rel: float = 0.0
    converged: bool = True
    inverted_elements: int = 0
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)
    new_chord: object | None = None  # a factor its solve made (``equilibrium(..., refactor=True)``), the caller's


class FaceRig:
    """Forward model X(c) and Jacobians of a face model.

    Args:
        model: the face.
        device, precision, solver: passed to ``wface.physics.simulator.Simulator``.
        tol: relative residual of the quasistatic solves.
        contact: a ``wface.physics.contact.Contact`` used in every equilibrium and Jacobian (module
            docstring), or None (default: no contact, results unchanged).
        max_iterations: Newton iteration cap of each equilibrium.
        factor_precision: of the Jacobians' factorisations (and the chords made from them): "float64",
            or "float32" (the tracker's default, ``TrackOptions.factor_precision``: 1.5x faster, within
            8e-6 of float64 at 100K tets; docs/design.md, "Linear solvers").
    """

    def __init__(
        self,
        model: FaceModel,
        *,
        device: str = "cpu",
        precision: str = "float64",
        solver: str = "auto",
        tol: float = 1e-6,
        simulator=None,
        contact=None,
        max_iterations: int = 40,
        factor_precision: str = "float64",
    ):
        self.model = model
        self.sim = simulator or Simulator(model, device=device, precision=precision, solver=solver)
        # the Jacobian solves (and the tracker's chord steps)
        self._linear = LinearSolver(self.sim.linear_solver, self.sim.device, factor_precision=factor_precision)
        self.factor_precision = factor_precision
        self.exact_tangents_ok = self._linear.exact_tangents_ok  # False: it factors projected ones (cuDSS)
        self.tol = tol
        self.contact = contact
        self.max_iterations = int(max_iterations)
        self.n_muscles = model.n_muscles
        self.n_controls = model.n_muscles + 24
        self._dxc_djaw = attached_positions_jacobian(model).reshape(-1, 12)  # (3a, 12)
        n = model.n_nodes
        free = model.free_nodes
        fixed = model.attached_nodes
        self._free_dofs = (3 * free[:, None] + np.arange(3)).ravel()
        self._fixed_dofs = (3 * fixed[:, None] + np.arange(3)).ravel()
        self._n = n
        self.counters = {
            "quasistatic_solves": 0,
            "linear_solves": 0,  # Jacobian columns solved
            "newton_iterations": 0,
            "cg_iterations": 0,  # Newton and Jacobian CG iterations
            "factorizations": 0,  # Newton and Jacobian numeric factorisations
            "back_solves": 0,  # right-hand sides solved with a factor (Newton, chord and Jacobian)
            "chord_steps": 0,
        }

    # ------------------------------------------------------------------ controls
    def rest_controls(self) -> np.ndarray:
        return np.concatenate([np.zeros(self.n_muscles), IDENTITY_BONES])

    def split(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(c, dtype=np.float64)
        if c.shape != (self.n_controls,):
            raise ValueError(f"controls have shape {c.shape}, expected ({self.n_controls},)")
        return c[: self.n_muscles], c[self.n_muscles :]

    # ------------------------------------------------------------------ forward model
    def equilibrium(
        self,
        c: np.ndarray,
        y0: np.ndarray | None = None,
        *,
        chord=None,
        refactor: bool = False,
        tol: float | None = None,
        load_scale: bool = False,
        twin: bool = False,
    ) -> RigState:
        """Solve the quasistatic equilibrium for controls c, warm-started from y0 (cranium frame);
        ``chord``: a nearby ``RigLinearization.chord`` for chord Newton steps (module docstring).
        ``refactor``: where the chord contracts poorly, factor the exact tangent at the iterate
        (``stiffness_at``) and go on with it; the new factor is ``RigState.new_chord`` (the caller's to
        keep or free). ``tol``: relative residual (default the rig's). ``load_scale``: the residual
        relative to ``load_force_scale`` (no force evaluation at X_load). ``twin``: energies and forces
        from a float32 twin of the simulator (``float32_twin``) when the tolerance is at least
        ``TWIN_MIN_TOL`` (its residual reading error is ~1e-5 of the load). Activations outside [0, 1] (a
        penalty method's iterates) are solved clipped (``Simulator.solve`` refuses them); NaN/inf raise."""
        if not np.all(finite := np.isfinite(np.asarray(c, dtype=np.float64).reshape(-1))):
            raise ValueError(f"controls have NaN or inf at {np.flatnonzero(~finite)[:5].tolist()}")
        a, b = self.split(c)
        # the physics sees activations clipped (the tracker's penalty keeps them near the box)
        a_phys = self.model.clip_activations(a)
        t0 = time.perf_counter()
        kwargs = {} if self.contact is None else {"contact": self.contact}
        if chord is not None:
            kwargs["chord"] = chord
        if self.factor_precision != "float64":
            kwargs["factor_precision"] = self.factor_precision
        targets = attached_positions(self.model, b, frame="cranium")
        if chord is not None and refactor:
            kwargs["refactor"] = lambda x: self.stiffness_at(c, x, warn=False)
        if load_scale and self.contact is None:
            kwargs["force_scale"] = self.load_force_scale(a_phys, targets)
        tol = self.tol if tol is None else float(tol)
        if twin and tol >= TWIN_MIN_TOL and self.contact is None:
            kwargs["twin"] = self.float32_twin()
        eq = self.sim.solve(a_phys, targets, y0, tol=tol, max_iterations=self.max_iterations, **kwargs)
        self.counters["quasistatic_solves"] += 1
        self.counters["newton_iterations"] += eq.iterations
        self.counters["cg_iterations"] += getattr(eq, "cg_iterations", 0)
        self.counters["factorizations"] += eq.factorizations
        self.counters["back_solves"] += eq.back_solves
        self.counters["chord_steps"] += eq.chord_steps
        if not eq.converged:
            warnings.warn(f"quasistatic solve stopped at residual {eq.residual_rel:.2e} (tol {tol:g})", stacklevel=2)
        Mc, tc = affine_from_params(b[:12])
        stats = {}
        if self.contact is not None:
            stats = {
                "contact_active_nodes": eq.contact_active_nodes,
                "contact_max_penetration_m": eq.contact_max_penetration_m,
                "contact_force_n": eq.contact_force_n,
            }
        return RigState(
            np.array(c, dtype=np.float64),
            eq.x,
            eq.x @ Mc.T + tc,
            eq.iterations,
            eq.residual_rel,
            eq.converged,
            eq.inverted_elements,
            time.perf_counter() - t0,
            stats,
            eq.new_chord,
        )

    def float32_twin(self) -> Simulator | None:
        """A single-precision ``Simulator`` of the model (made once) for the energies and forces of loose
        solves: about 2x cheaper per evaluation on the CPU; at a float64 equilibrium its forces read a
        relative residual of 6e-6 (20K tets; docs/design.md, "Performance"). None when the rig's own
        simulator is single precision."""
        if self.sim.precision == "float32":
            return None
        if getattr(self, "_twin", None) is None:
            sim = self.sim
            self._twin = Simulator(self.model, device=sim.device, precision="float32", solver=sim.linear_solver)
            self._twin.force_length_scale = sim.force_length_scale
            self._twin.parallel_min_tets = sim.parallel_min_tets
        return self._twin

    def load_force_scale(self, a: np.ndarray, targets: np.ndarray) -> float:
        """The linearised load on the rest face, ||sum_i a_i f_i(X)_U - K_UC(X) (x_C - X_C)||_2 (N), with
        f_i the muscles' forces at full activation and K the stiffness of the rest shape: the first-order
        ||f_U(X_load)|| of the relative residual (``wface.physics.newton``) without a force evaluation
        (docs/design.md, "Performance"); floored as there."""
        if not hasattr(self, "_load_parts"):
            rest = self.model.rest_positions_m
            M = self.n_muscles
            f_rest = self.sim.muscle_forces(rest).reshape(M, -1)[:, self._free_dofs] if M else None
            k_uc = self.sim.tangent(rest, np.zeros(M), project=False).assemble_free_and_coupling()
            mat = self.model.material
            floor = 1e-3 * (mat.mu10_pa + mat.mu01_pa) * float(self.model.rest_volume_m3.sum()) ** (2.0 / 3.0)
            self._load_parts = (f_rest, k_uc, floor)
        f_rest, k_uc, floor = self._load_parts
        rest_c = self.model.rest_positions_m[self.model.attached_nodes]
        load = -(k_uc @ (np.asarray(targets) - rest_c).reshape(-1))
        if f_rest is not None:
            load += np.asarray(a, dtype=np.float64) @ f_rest
        return max(float(np.linalg.norm(load)), floor)

    def predict_y(self, state: RigState, dy_dc: np.ndarray, dc: np.ndarray) -> np.ndarray:
        """Linearised equilibrium Y(c + dc) ~ Y + dY/dc dc in the cranium frame (a warm start)."""
        return state.y_m + (dy_dc @ dc).reshape(-1, 3)

    # ------------------------------------------------------------------ Jacobians
    def jacobian_y(self, state: RigState) -> np.ndarray:
        """dY/d(a, b_jaw) in the cranium frame: (3n, M + 12) for all nodes."""
        lin = self.linearize(state, keep_factor=False)
        return lin.jy

    def stiffness_at(self, c: np.ndarray, y: np.ndarray, *, warn: bool = True) -> _Chord | None:
        """The factorised K_UU (exact; projected, with a warning, where the exact one is not positive
        definite; projected always where the solver takes no exact tangents: cuDSS) and K_UC at
        controls c and cranium-frame positions y, e.g. the linear prediction of
        an equilibrium: the chord of its solve and the factor of its Jacobian (``projected`` says which
        tangent was factored; ``warn``: say so when it is the projected one). With contact, K_UU and
        K_UC include the contact Hessian of the pairs at y (``_contact_stiffness``)."""
        if self.contact is not None:
            return self._contact_stiffness(c, y, warn=warn)[0]
        a = self.model.clip_activations(self.split(c)[0])
        sim, pattern = self.sim, self.sim.pattern("free")
        t0 = time.perf_counter()
        projected = not self.exact_tangents_ok  # cuDSS: projected only (wface.solvers.solver)
        tan = sim.tangent(y, a, project=projected)
        k_uc = tan.assemble_free_and_coupling()  # (3|U|, 3|C|) of the tangent factored below
        t1 = time.perf_counter()
        counts0 = self._linear.counters()
        try:
            bound = self._linear.bind(tan, pattern)
        except NotPositiveDefiniteError:
            if warn:
                warnings.warn(
                    "exact tangent not positive definite at this equilibrium; Jacobians use the projected tangent",
                    stacklevel=3,
                )
            bound, projected = self._linear.bind(sim.tangent(y, a, project=True), pattern), True
        self._count(counts0)
        chord = _Chord(bound, k_uc, {"tangent_s": t1 - t0, "factor_s": time.perf_counter() - t1})
        chord.projected = projected
        chord.at = (np.array(c, dtype=np.float64), np.array(y, dtype=np.float64))  # where it was factored
        return chord

    def _count(self, counts0: dict) -> None:
        for key in ("factorizations", "back_solves", "cg_iterations"):
            self.counters[key] += getattr(self._linear, key) - counts0[key]

    def linearize(
        self,
        state: RigState,
        *,
        keep_factor: bool = True,
        stiffness: _Chord | None = None,
        held: np.ndarray | None = None,
    ) -> RigLinearization:
        """dY/d(a, b_jaw) at the equilibrium ``state`` and, with ``keep_factor``, the factor of K_UU
        there for chord steps of nearby equilibria (module docstring).

        ``stiffness``: a ``stiffness_at`` of a point near ``state`` (the linear prediction its solve
        started from) whose factor and K_UC serve instead of the exact ones at ``state``: no new
        factorisation, at the price of a Jacobian error of the order of the prediction's (measured
        1 % at 100K tets; docs/design.md, "Performance"). It is owned by the result from here.
        ``held``: (M,) bool, muscles whose columns are not solved and stay zero: those a prior holds at
        rest (``GaussianPrior.held``), which the steps leave where they are (docs/design.md,
        "Performance").
        """
        if self.contact is not None:
            return self._linearize_contact(state, keep_factor=keep_factor, stiffness=stiffness)
        y = state.y_m
        M, U = self.n_muscles, self._free_dofs
        t0 = time.perf_counter()
        chord = stiffness if stiffness is not None else self.stiffness_at(state.controls, y)
        t1 = time.perf_counter()
        solved = np.arange(M) if held is None else np.flatnonzero(~np.asarray(held, dtype=bool))
        columns = np.concatenate([solved, np.arange(M, M + 12)])  # of J solved here; the others stay zero
        rhs = np.empty((len(U), columns.size), order="F")  # column-major: the solvers' layout
        if solved.size:
            rhs[:, : solved.size] = self.sim.muscle_forces(y).reshape(M, -1)[np.ix_(solved, U)].T
        rhs[:, solved.size :] = -(chord.k_uc @ self._dxc_djaw)
        t2 = time.perf_counter()
        counts0 = self._linear.counters()
        sol = chord.bound.solve(rhs, rtol=1e-10)
        self._count(counts0)
        t3 = time.perf_counter()
        self.counters["linear_solves"] += rhs.shape[1]
        J = np.zeros((3 * self._n, M + 12))
        J[np.ix_(U, columns)] = sol  # the held columns stay zero
        J[self._fixed_dofs, M:] = self._dxc_djaw
        at = getattr(chord, "at", None)
        if not (keep_factor and chord.bound.factor is not None):
            chord.free()
            chord = None
        seconds = {"stiffness_s": t1 - t0, "rhs_s": t2 - t1, "back_solve_s": t3 - t2}
        held = None if solved.size == M else np.asarray(held, dtype=bool).copy()
        return RigLinearization(state, J, chord, seconds, jacobian_at=None if at is None else (y, at), held=held)

    def linearize_rows(
        self, state: RigState, nodes: np.ndarray, rows: np.ndarray, chord=None
    ) -> RowsLinearization | None:
        """The rig at the equilibrium ``state`` from Jacobian rows ``rows`` (k, 3, M + 12) of the nodes
        ``nodes`` known there (``RowsLinearization``); None where it cannot serve (no factor).
        ``chord``: a nearby factor to use instead of factoring at ``state`` (owned by the result)."""
        if self.sim.linear_solver != "direct":
            return None
        return RowsLinearization(self, state, nodes, rows, chord=chord)

    def _contact_pairs(self, c: np.ndarray, y: np.ndarray):
        """The contact pairs at cranium-frame positions y with the bones posed by controls c."""
        self.contact.set_pose(attached_positions(self.model, self.split(c)[1], frame="cranium"))
        return self.contact.evaluate(y)

    def _contact_stiffness(self, c: np.ndarray, y: np.ndarray, *, warn: bool = True) -> tuple[_Chord, object]:
        """(``stiffness_at`` with contact, the contact pairs at y): the exact elastic tangent plus the
        exact contact Hessian of the pairs at y (module docstring), factored; the projected tangent
        plus the contact Gauss-Newton Hessian where that is not positive definite."""
        U, C, t0 = self._free_dofs, self._fixed_dofs, time.perf_counter()
        a = self.model.clip_activations(self.split(c)[0])
        pairs = self._contact_pairs(c, y)
        K = self.sim.assemble_stiffness(y, a, project=False).tocsr()
        if len(pairs.node):
            K = (K + exact_self_hessian(self.contact, pairs, y, self.sim.pattern("all"))).tocsr()
        t1 = time.perf_counter()
        pattern = self.sim.pattern("free")
        counts0 = self._linear.counters()
        projected = False
        try:
            bound = self._linear.bind(MatrixOperator(K), pattern)
        except NotPositiveDefiniteError:
            if warn:
                warnings.warn(
                    "exact tangent not positive definite at this equilibrium; Jacobians use the projected tangent",
                    stacklevel=3,
                )
            K = self.sim.assemble_stiffness(y, a, project=True).tocsr()
            if len(pairs.node):
                K = (K + pairs.assemble(self.sim.pattern("all"))).tocsr()
            bound, projected = self._linear.bind(MatrixOperator(K), pattern), True
        self._count(counts0)
        chord = _Chord(bound, K[U][:, C], {"tangent_s": t1 - t0, "factor_s": time.perf_counter() - t1})
        chord.projected = projected
        chord.at = (np.array(c, dtype=np.float64), np.array(y, dtype=np.float64))
        return chord, pairs

    def _linearize_contact(self, state: RigState, *, keep_factor: bool, stiffness: _Chord | None) -> RigLinearization:
        """``linearize`` with contact: every column solved with the factor of K_UU plus the contact
        Hessian at ``state`` (``_contact_stiffness``), or with ``stiffness``'s (a nearby one), the
        jaw columns with the contact forces of the obstacles that follow the jaw (module docstring)."""
        y = state.y_m
        M, U = self.n_muscles, self._free_dofs
        t0 = time.perf_counter()
        c = state.controls
        chord, pairs = self._contact_stiffness(c, y) if stiffness is None else (stiffness, self._contact_pairs(c, y))
        t1 = time.perf_counter()
        rhs = np.empty((len(U), M + 12))
        if M:
            rhs[:, :M] = self.sim.muscle_forces(y).reshape(M, -1)[:, U].T
        rhs[:, M:] = -(chord.k_uc @ self._dxc_djaw)
        if len(pairs.node):
            rhs[:, M:] += self._contact_jaw_rhs(pairs, y)[U]
        t2 = time.perf_counter()
        counts0 = self._linear.counters()
        sol = chord.bound.solve(rhs, rtol=1e-10)
        self._count(counts0)
        self.counters["linear_solves"] += rhs.shape[1]
        J = np.zeros((3 * self._n, M + 12))
        J[U] = sol
        J[self._fixed_dofs, M:] = self._dxc_djaw
        seconds = {"stiffness_s": t1 - t0, "rhs_s": t2 - t1, "back_solve_s": time.perf_counter() - t2}
        lin = RigLinearization(state, J, chord, seconds, jacobian_at=(y, chord.at))
        if not (keep_factor and chord.bound.factor is not None):
            lin.free()
        return lin

    def _contact_jaw_rhs(self, pairs, y: np.ndarray) -> np.ndarray:
        """(3n, 12) d f_c / d b_jaw of the pairs on obstacles that follow the jaw (module docstring)."""
        out = np.zeros((self._n, 3, 12))
        if self.contact.fixed_bone_affines is not None:
            return out.reshape(-1, 12)
        jaw_sources = [s for s, (_, ob) in enumerate(self.contact.rigid) if getattr(ob, "bone", None) == "jaw"]
        sel = np.flatnonzero(np.isin(pairs.source, jaw_sources))
        if not sel.size:
            return out.reshape(-1, 12)
        A = self.contact.bone_affines["jaw"]
        n, node = pairs.normal[sel], pairs.node[sel]
        c = y[node] - pairs.distance_m[sel, None] * n  # closest point on the obstacle (x - c = phi n)
        c_rest = np.linalg.solve(A[:, :3], (c - A[:, 3]).T).T  # in the jaw's rest frame
        dc = np.zeros((sel.size, 3, 12))  # d(M c_rest + t)/d b_jaw, b_jaw = (M row-major, t)
        for r in range(3):
            dc[:, r, 3 * r : 3 * r + 3] = c_rest
            dc[:, r, 9 + r] = 1.0
        Q = pairs._projector()[sel]  # k'' n n^T (+ the curvature of an edge / vertex feature)
        df = np.einsum("pde,pec->pdc", Q, dc)
        # a face feature turns with the jaw: n ~ M^-T n_rest, dn = -(I - n n^T) M^-T dM^T n
        face = pairs.tangential[sel] == 0
        Minv_T = np.linalg.inv(A[:, :3]).T
        for r in range(3):
            for col in range(3):
                dM = np.zeros((3, 3))
                dM[r, col] = 1.0
                u = (Minv_T @ dM.T @ n.T).T
                dn = -(u - np.einsum("pd,pd->p", u, n)[:, None] * n)
                df[:, :, 3 * r + col] += (face * pairs.force_magnitude[sel])[:, None] * dn
        np.add.at(out, node, df)
        return out.reshape(-1, 12)

    def jacobian(self, state: RigState, nodes: np.ndarray | None = None) -> np.ndarray:
        """World dX/dc for the given nodes (default all): (len(nodes), 3, M + 24)."""
        nodes = np.arange(self._n) if nodes is None else np.asarray(nodes, dtype=np.int64)
        Jy = self.jacobian_y(state).reshape(self._n, 3, -1)[nodes]  # (k, 3, M + 12)
        return self.world_jacobian(state, Jy, nodes)

    def world_jacobian(self, state: RigState, jy_nodes: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """Assemble world dX/dc (k, 3, M + 24) from cranium-frame dY/d(a, b_jaw) of k nodes."""
        M = self.n_muscles
        _, b = self.split(state.controls)
        Mc, _ = affine_from_params(b[:12])
        y = state.y_m[nodes]
        k = len(nodes)
        J = np.zeros((k, 3, M + 24))
        moved = np.einsum("rs,ksc->krc", Mc, jy_nodes)
        J[:, :, :M] = moved[:, :, :M]
        J[:, :, M + 12 :] = moved[:, :, M:]
        for r in range(3):
            J[:, r, M + 3 * r : M + 3 * r + 3] = y  # dX_r/dMc_rc = Y_c
            J[:, r, M + 9 + r] = 1.0
        return J
