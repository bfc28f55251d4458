"""Linear solvers: PCG (single and many right-hand sides) against the sparse direct factorisation
and a dense solve, the factor as a preconditioner, detection of indefinite matrices, and the
"auto" choice with its fallback when no direct backend is installed."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from wface.physics import Simulator
from wface.solvers import LinearSolver, linear
from wface.solvers.linear import (
    DirectFactor,
    FactorPreconditioner,
    JacobiPreconditioner,
    NotPositiveDefiniteError,
    direct_backend,
    pcg,
    resolve_linear_solver,
)
from wface.testing.models import box_model

needs_direct = pytest.mark.skipif(direct_backend() is None, reason="no sparse direct backend installed")


@pytest.fixture(scope="module")
def stiffness():
    """Projected stiffness of a deformed, activated box, Dirichlet rows removed (SPD, cond ~1e4)."""
    model = box_model((4, 2, 2), cranium_faces=("x-",), muscles=2)
    sim = Simulator(model)
    X = model.rest_positions_m
    x = X + 0.002 * np.random.default_rng(0).normal(size=X.shape)
    a = np.array([0.8, 0.3])
    return sim, x, a, sim.assemble_stiffness(x, a, nodes="free")


@needs_direct
def test_direct_and_cg_solve_many_right_hand_sides(stiffness):
    _, _, _, K = stiffness
    B = np.random.default_rng(1).normal(size=(K.shape[0], 44))  # the Jacobian issue's column count
    dense = np.linalg.solve(K.toarray(), B)
    factor = DirectFactor(K)
    X_direct = factor.solve(B)
    np.testing.assert_allclose(X_direct, dense, rtol=0, atol=1e-9 * np.abs(dense).max())
    np.testing.assert_allclose(factor.solve(B[:, 3]), dense[:, 3], rtol=0, atol=1e-9 * np.abs(dense).max())
    res = pcg(lambda v: K @ v, B, preconditioner=JacobiPreconditioner(K.diagonal()), rtol=1e-10)
    assert res.converged and res.x.shape == B.shape
    np.testing.assert_allclose(res.x, dense, rtol=0, atol=1e-7 * np.abs(dense).max())  # rtol 1e-10 x cond ~1e4
    assert np.all(np.linalg.norm(K @ res.x - B, axis=0) <= 1.01e-10 * np.linalg.norm(B, axis=0))


@needs_direct
def test_factor_of_a_nearby_matrix_preconditions_cg(stiffness):
    sim, x, a, K0 = stiffness
    K1 = sim.assemble_stiffness(x * 1.01, a * 0.9, nodes="free")  # next Newton step's matrix
    b = np.random.default_rng(2).normal(size=K1.shape[0])
    jacobi = pcg(lambda v: K1 @ v, b, preconditioner=JacobiPreconditioner(K1.diagonal()), rtol=1e-10)
    factored = pcg(lambda v: K1 @ v, b, preconditioner=FactorPreconditioner(DirectFactor(K0)), rtol=1e-10)
    assert factored.converged and jacobi.converged
    assert factored.iterations < jacobi.iterations / 3, (factored.iterations, jacobi.iterations)
    np.testing.assert_allclose(factored.x, jacobi.x, atol=1e-7 * np.abs(jacobi.x).max())


@settings(max_examples=25, deadline=None)
@given(n=st.integers(2, 40), k=st.integers(1, 4), seed=st.integers(0, 2**31 - 1))
def test_pcg_solves_random_spd_systems(n, k, seed):
    rng = np.random.default_rng(seed)
    Q = rng.normal(size=(n, n))
    A = Q @ Q.T + n * np.eye(n)  # SPD, condition number bounded by construction
    B = rng.normal(size=(n, k))
    res = pcg(lambda v: A @ v, B, preconditioner=JacobiPreconditioner(np.diag(A)), rtol=1e-12)
    assert res.converged and res.iterations <= 3 * n
    np.testing.assert_allclose(A @ res.x, B, atol=1e-9 * np.abs(B).max())


def test_indefinite_matrices_are_reported():
    A = sp.diags([2.0, 1.0, -1.0, 3.0]).tocsr()
    b = np.ones(4)
    assert pcg(lambda v: A @ v, b).indefinite
    if direct_backend() is not None:
        with pytest.raises(NotPositiveDefiniteError):
            DirectFactor(A)


def test_auto_picks_direct_and_falls_back_to_cg_with_a_notice(monkeypatch):
    if direct_backend() is not None:
        assert resolve_linear_solver("auto", "cpu") == "direct"
    assert resolve_linear_solver("auto", "cuda:0") == "cg"
    assert resolve_linear_solver("cg", "cpu") == "cg"
    monkeypatch.setattr(linear, "direct_backend", lambda: None)
    with pytest.warns(RuntimeWarning, match="no sparse direct solver"):
        assert resolve_linear_solver("auto", "cpu") == "cg"
    with pytest.warns(RuntimeWarning):
        assert resolve_linear_solver("direct", "cpu") == "cg"
    with pytest.raises(ValueError, match="unknown linear solver"):
        resolve_linear_solver("lu", "cpu")


def test_simulator_without_direct_backend_still_solves(monkeypatch):
    monkeypatch.setattr(linear, "direct_backend", lambda: None)
    model = box_model((3, 2, 2), cranium_faces=("x-",), muscles=1)
    with pytest.warns(RuntimeWarning):
        sim = Simulator(model, solver="auto")
    eq = sim.solve({"muscle_0": 0.5})
    assert eq.converged and eq.solver == "cg" and eq.cg_iterations > 0


def test_warp_cg_path_solves_the_masked_system(stiffness):
    """The device-side CG used on CUDA (warp.optim.linear.cg + matrix-free K.v + Jacobi), run here
    on the CPU device for correctness: K_UU X = B for two right-hand sides."""
    from wface.solvers.warp_cg import warp_pcg

    sim, x, a, K = stiffness
    tan = sim.tangent(x, a)
    B = np.random.default_rng(3).normal(size=(K.shape[0], 2))
    X, iterations = warp_pcg(tan, sim.pattern("free"), B, rtol=1e-10)
    assert iterations > 0
    assert np.abs(K @ X - B).max() < 1e-8 * np.abs(B).max()  # rtol 1e-10 on ||r||, max-norm slack


def test_activation_jacobian_by_one_factorisation_matches_finite_differences():
    """dX/da_i = K_UU^-1 f_i(X*) (Sifakis et al. 2005, eq. 5), all muscles against one factor / with CG,
    compared with central differences of the equilibrium (h = 1e-4 in activation; Newton to 1e-11)."""
    model = box_model((4, 2, 2), cranium_faces=("x-",), muscles=2)
    sim = Simulator(model)
    a = np.array([0.4, 0.6])
    eq = sim.solve(a, tol=1e-11)
    fi = sim.muscle_forces(eq.x)
    J_direct = sim.stiffness_solver(eq.x, a, project=False, solver="direct").solve_nodal(fi)
    J_cg = sim.stiffness_solver(eq.x, a, project=False, solver="cg").solve_nodal(fi)
    np.testing.assert_allclose(J_cg, J_direct, atol=1e-7 * np.abs(J_direct).max())
    h = 1e-4
    for i in range(2):
        e = np.eye(2)[i] * h
        xp = sim.solve(a + e, x0=eq.x, tol=1e-11).x
        xm = sim.solve(a - e, x0=eq.x, tol=1e-11).x
        fd = (xp - xm) / (2 * h)
        assert np.abs(J_direct[i] - fd).max() < 1e-4 * np.abs(fd).max()  # O(h^2) + Newton tolerance


@needs_direct
def test_refactorisation_with_the_same_sparsity_reuses_the_analysis(stiffness):
    sim, x, a, K0 = stiffness
    K1 = sim.assemble_stiffness(x * 1.02, a * 0.5, nodes="free")
    b = np.random.default_rng(4).normal(size=(K1.shape[0], 3))
    first = DirectFactor(K0)
    second = DirectFactor(K1, reuse=first)
    fresh = DirectFactor(K1)
    assert second.reused_analysis == (second.backend == "pardiso") and not fresh.reused_analysis
    X = second.solve(b)
    np.testing.assert_allclose(X, fresh.solve(b), rtol=0, atol=1e-9 * np.abs(X).max())
    np.testing.assert_allclose(K1 @ X, b, rtol=0, atol=1e-8 * np.abs(b).max())
    if second.backend == "pardiso":
        with pytest.raises(RuntimeError, match="freed"):
            first.solve(b)  # its PARDISO handle now belongs to the newer factor


# ---------------------------------------------------------------------------------------------
# PARDISO through ctypes, the pattern's kept analysis, other backends and AMG (issue "Paper scale")


def _pardiso_or_skip():
    from wface.solvers.pardiso import mkl_runtime

    if mkl_runtime() is None:
        pytest.skip("MKL PARDISO not installed here")


def test_upper_structure_and_coupling_block_match_scipy(stiffness):
    sim, x, a, K = stiffness
    tan = sim.tangent(x, a)
    pattern = sim.pattern("free")
    U = sp.triu(K, format="csr")
    U.sort_indices()
    assert np.array_equal(pattern.upper.indptr, U.indptr) and np.array_equal(pattern.upper.indices, U.indices)
    np.testing.assert_array_equal(tan.assemble_upper(pattern), U.data)  # a gather of the same sums
    full = tan.assemble(sim.pattern("all"))
    free, fixed = sim.model.free_nodes, sim.model.attached_nodes
    rows, cols = (3 * free[:, None] + np.arange(3)).ravel(), (3 * fixed[:, None] + np.arange(3)).ravel()
    K_uc = tan.assemble(sim.pattern("coupling"))
    assert (K_uc != full[rows][:, cols]).nnz == 0
    fused = sim.tangent(x, a).assemble_free_and_coupling()
    assert (fused != K_uc).nnz == 0


def test_pardiso_slots_hold_two_factors_of_one_analysis(stiffness):
    _pardiso_or_skip()
    from wface.solvers.linear import pattern_analysis

    sim, x, a, K0 = stiffness
    pattern = sim.pattern("free")
    t1 = sim.tangent(x * 1.01, a * 0.5)
    K1 = t1.assemble(pattern)
    f0 = DirectFactor.of_pattern(pattern, sim.tangent(x, a).assemble_upper(pattern))
    f1 = DirectFactor.of_pattern(pattern, t1.assemble_upper(pattern))
    analysis = pattern_analysis(pattern)
    assert analysis.analyses == 1 and analysis.slots_in_use >= 2 and f1.reused_analysis
    B = np.random.default_rng(5).normal(size=(K0.shape[0], 3))
    for factor, K in ((f0, K0), (f1, K1), (f0, K0)):  # interleaved: each slot keeps its own factor
        np.testing.assert_allclose(K @ factor.solve(B), B, rtol=0, atol=1e-9 * np.abs(B).max())
    in_use = analysis.slots_in_use
    f0.free()
    f1.free()
    assert analysis.slots_in_use == in_use - 2


def test_pardiso_indefinite_matrix_is_reported_and_frees_its_slot():
    _pardiso_or_skip()
    from wface.solvers.pardiso import PardisoAnalysis, PardisoError

    A = sp.csr_matrix(np.array([[2.0, 1.0, 0.0], [1.0, -3.0, 1.0], [0.0, 1.0, 2.0]]))
    analysis, values = PardisoAnalysis.of_matrix(A, slots=1)
    with pytest.raises(PardisoError) as err:
        analysis.factor(values)
    assert err.value.code == -4 and analysis.slots_in_use == 0


@pytest.mark.parametrize("backend", ["cholespy", "cholmod"])
def test_other_direct_backends_solve_the_stiffness(stiffness, backend):
    if backend not in linear.available_direct_backends():
        pytest.skip(f"{backend} is not installed")
    sim, x, a, K = stiffness
    B = np.random.default_rng(6).normal(size=(K.shape[0], 4))
    factor = DirectFactor.of_pattern(
        sim.pattern("free"), sim.tangent(x, a).assemble_upper(sim.pattern("free")), backend=backend
    )
    np.testing.assert_allclose(K @ factor.solve(B), B, rtol=0, atol=1e-9 * np.abs(B).max())
    np.testing.assert_allclose(factor.solve(B[:, 1]), factor.solve(B)[:, 1], rtol=0, atol=1e-12 * np.abs(B).max())


def test_rigid_body_modes_span_the_nullspace_of_the_unconstrained_stiffness():
    from wface.solvers.amg import rigid_body_modes

    model = box_model((3, 2, 2), cranium_faces=("x-",), muscles=1)
    sim = Simulator(model)
    K = sim.assemble_stiffness(model.rest_positions_m, None, nodes="all")  # no Dirichlet rows, at rest
    B = rigid_body_modes(model.rest_positions_m)
    assert np.allclose(B.T @ B, np.eye(6), atol=1e-12)
    # rigid motions of the stress-free rest shape cost no force: K B = 0 to round-off of K's scale
    assert np.abs(K @ B).max() <= 1e-9 * abs(K).max() * np.abs(B).max()


def test_amg_preconditioned_cg_beats_jacobi():
    pytest.importorskip("pyamg")
    from wface.solvers.amg import AMGPreconditioner

    model = box_model((12, 6, 6), cranium_faces=("x-",), muscles=1)
    sim = Simulator(model)
    K = sim.assemble_stiffness(model.rest_positions_m, None, nodes="free")
    b = np.random.default_rng(7).normal(size=K.shape[0])
    amg = pcg(
        lambda v: K @ v, b, preconditioner=AMGPreconditioner(K, model.rest_positions_m[model.free_nodes]), rtol=1e-10
    )
    jac = pcg(lambda v: K @ v, b, preconditioner=JacobiPreconditioner(K.diagonal()), rtol=1e-10)
    assert amg.converged and jac.converged
    assert amg.iterations < jac.iterations / 3, (amg.iterations, jac.iterations)
    np.testing.assert_allclose(amg.x, jac.x, rtol=0, atol=1e-6 * np.abs(jac.x).max())  # both to rtol 1e-10


def test_linear_solver_counts_factorisations_and_back_solves(stiffness):
    if direct_backend() is None:
        pytest.skip("no sparse direct backend installed")
    from wface.solvers import LinearSolver

    sim, x, a, K = stiffness
    solver = LinearSolver("direct")
    bound = solver.bind(sim.tangent(x, a), sim.pattern("free"))
    bound.solve(np.ones((K.shape[0], 5)))
    bound.solve(np.ones(K.shape[0]))
    assert (solver.factorizations, solver.back_solves) == (1, 6)
    assert solver.factor_seconds > 0 and solver.solve_seconds > 0
    bound.free()


def test_linear_solver_cg_with_the_amg_preconditioner(stiffness):
    pytest.importorskip("pyamg")
    from wface.solvers import LinearSolver

    sim, x, a, K = stiffness
    b = np.random.default_rng(8).normal(size=K.shape[0])
    solver = LinearSolver("cg", preconditioner="amg")
    X = solver.solve(sim.tangent(x, a), sim.pattern("free"), b, rtol=1e-10)
    assert np.linalg.norm(K @ X - b) <= 1.01e-10 * np.linalg.norm(b)
    jacobi = LinearSolver("cg")
    jacobi.solve(sim.tangent(x, a), sim.pattern("free"), b, rtol=1e-10)
    assert solver.cg_iterations < jacobi.cg_iterations


def test_more_live_factors_than_kept_slots_still_factor(stiffness):
    _pardiso_or_skip()
    from wface.solvers.linear import pattern_analysis

    sim, x, a, K = stiffness
    pattern = sim.pattern("free")
    values = sim.tangent(x, a).assemble_upper(pattern)
    slots = pattern_analysis(pattern).slots
    factors = [DirectFactor.of_pattern(pattern, values) for _ in range(slots + 2)]  # two beyond the slots
    b = np.ones(K.shape[0])
    for f in factors:
        np.testing.assert_allclose(K @ f.solve(b), b, rtol=0, atol=1e-9)
    for f in factors:
        f.free()


@pytest.mark.parametrize("backend", ["pardiso", "cholespy"])
def test_single_precision_factors_solve_to_float32_accuracy(stiffness, backend):
    if backend not in linear.available_direct_backends():
        pytest.skip(f"{backend} is not installed")
    sim, x, a, K = stiffness
    pattern = sim.pattern("free")
    values = sim.tangent(x, a).assemble_upper(pattern)
    B = np.random.default_rng(9).normal(size=(K.shape[0], 3))
    X64 = DirectFactor.of_pattern(pattern, values, backend=backend).solve(B)
    f32 = DirectFactor.of_pattern(pattern, values, backend=backend, precision="float32")
    X32 = f32.solve(B)
    assert f32.precision == "float32" and X32.dtype == np.float64
    err = np.linalg.norm(X32 - X64) / np.linalg.norm(X64)
    assert 1e-12 < err < 1e-3, err  # float32 round-off (eps 6e-8) times the box's condition (~1e4)


# ------------------------------------------------------------------ cuDSS guard (checked on the CPU)
class _DeviceTangent:
    """Stands in for a CUDA ``Tangent``: what ``LinearSolver.factor`` reads to pick cuDSS."""

    device = "cuda:0"

    def __init__(self, projected: bool):
        self.projected = projected

    def device_matvec(self, x, out):  # pragma: no cover - never called here
        raise AssertionError


def test_cudss_is_handed_projected_stiffnesses_only(monkeypatch):
    """On CUDA with cuDSS an exact tangent is refused before the GPU sees it (an indefinite one stalled
    cuDSS's Cholesky on an H200, docs/design.md "The GPU path"); a projected one is factored."""
    import wface.solvers.solver as solver_module

    handed = []
    monkeypatch.setattr(solver_module, "cudss_available", lambda: True)
    monkeypatch.setattr(solver_module, "resolve_linear_solver", lambda solver, device: "direct")
    monkeypatch.setattr(solver_module.CudssFactor, "of_operator", classmethod(lambda cls, op, p: handed.append(op)))
    lin = LinearSolver("auto", "cuda:0")
    assert not lin.exact_tangents_ok
    with pytest.raises(NotPositiveDefiniteError, match="projected"):
        lin.factor(_DeviceTangent(projected=False), None)
    assert handed == [] and lin.factorizations == 0
    lin.factor(_DeviceTangent(projected=True), None)
    assert len(handed) == 1 and lin.factorizations == 1
    assert LinearSolver("auto", "cpu").exact_tangents_ok  # PARDISO reports an indefinite matrix itself


def test_cudss_refuses_non_finite_stiffness_before_factoring():
    from wface.solvers.cudss import _Session

    class Untouched:  # no solver: the check comes first
        pass

    values = np.ones(5)
    values[3] = np.nan
    with pytest.raises(NotPositiveDefiniteError, match="non-finite"):
        _Session.factor(Untouched(), values, owner=None)


def test_without_exact_tangents_newton_and_the_rig_use_the_projected_stiffness(monkeypatch):
    """What the GPU path does (``exact_tangents_ok`` False), run on the CPU: Newton takes projected steps
    only and reaches the same equilibrium; the tracker's chord is the projected tangent, without a warning."""
    import warnings

    from wface.faces.builtin import build_face
    from wface.tracking.rig import FaceRig

    model = build_face(2000)
    a = {"zygomaticus_major_l": 0.6, "orbicularis_oris_upper": 0.3}
    ref = Simulator(model).solve(a, tol=1e-9)
    monkeypatch.setattr(LinearSolver, "exact_tangents_ok", property(lambda self: False))
    eq = Simulator(model).solve(a, tol=1e-9)
    assert ref.projected_steps < ref.iterations - ref.chord_steps  # exact steps where they work
    assert eq.converged and eq.projected_steps == eq.iterations - eq.chord_steps  # 12 projected vs 5
    assert np.abs(eq.x - ref.x).max() <= 1e-6 * np.abs(ref.x - model.rest_positions_m).max()
    rig = FaceRig(model)
    c = rig.rest_controls()
    c[model.muscle_index("zygomaticus_major_l")] = 0.6
    state = rig.equilibrium(c)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        chord = rig.stiffness_at(state.controls, state.y_m)
    assert chord.projected


class _StandInDirectSolver:
    """nvmath's ``DirectSolver`` as ``wface.solvers.cudss`` uses it (plan, reset_operands, factorize with
    INFO, solve, free), dense and on the CPU: CI has no GPU, so this runs the wrapper's own logic (the
    padded blocks, the one plan per pattern, refactoring when another factor of the pattern is used)."""

    plans = factorizations = solves = 0

    def __init__(self, a, b, options=None, execution=None):
        self.a, self.b, self.shape = a, np.asarray(b), np.asarray(b).shape

    def plan(self):
        type(self).plans += 1

    def reset_operands(self, a=None, b=None):
        if a is not None:
            self.a = a
        if b is not None:
            assert np.asarray(b).shape == self.shape  # nvmath refuses another shape
            self.b = np.asarray(b)

    def factorize(self):
        type(self).factorizations += 1
        upper = self.a.toarray()
        full = upper + np.triu(upper, 1).T
        info = type("Info", (), {"info": 0})()
        try:
            self.L = np.linalg.cholesky(full)
        except np.linalg.LinAlgError:
            info.info = 1  # cuDSS: the column where the Cholesky failed
        return info

    def solve(self):
        type(self).solves += 1
        return np.linalg.solve(self.L.T, np.linalg.solve(self.L, self.b))

    def free(self):
        pass


@pytest.fixture
def stand_in_cudss(monkeypatch):
    import sys
    import types
    import weakref

    import wface.solvers.cudss as cudss_module

    adv = types.ModuleType("nvmath.sparse.advanced")
    adv.DirectSolverMatrixType = types.SimpleNamespace(SPD="spd")
    adv.DirectSolverMatrixViewType = types.SimpleNamespace(UPPER="upper")
    adv.DirectSolverOptions = lambda **kw: kw
    solver = type("DirectSolver", (_StandInDirectSolver,), {})
    adv.DirectSolver = solver
    for name, mod in (("nvmath", types.ModuleType("nvmath")), ("nvmath.sparse", types.ModuleType("nvmath.sparse"))):
        monkeypatch.setitem(sys.modules, name, mod)
    monkeypatch.setitem(sys.modules, "nvmath.sparse.advanced", adv)
    monkeypatch.setattr(cudss_module, "_SESSIONS", weakref.WeakKeyDictionary())
    return solver


def test_cudss_factor_pads_blocks_keeps_one_plan_and_refactors_on_switch(stiffness, stand_in_cudss):
    from wface.solvers.cudss import DEFAULT_WIDTH, CudssFactor

    sim, x, a, _ = stiffness
    tan = sim.tangent(x, a)
    pattern = sim.pattern("free")
    K = tan.assemble(pattern).toarray()
    rng = np.random.default_rng(4)
    first = CudssFactor.of_operator(tan, pattern)
    for width in (None, 1, 5, DEFAULT_WIDTH):  # a vector, narrow and full blocks: one plan, one factor
        B = rng.normal(size=K.shape[0] if width is None else (K.shape[0], width))
        X = first.solve(B)
        assert X.shape == B.shape
        assert np.abs(K @ X - B).max() <= 1e-9 * np.abs(B).max()
    assert stand_in_cudss.plans == 1 and stand_in_cudss.factorizations == 1
    solves = stand_in_cudss.solves
    B = rng.normal(size=(K.shape[0], DEFAULT_WIDTH + 1))  # the built-in face's M + 12 = 48 columns
    assert np.abs(K @ first.solve(B) - B).max() <= 1e-9 * np.abs(B).max()
    assert stand_in_cudss.solves == solves + 1  # one wider block (a new plan, the factor made again)
    assert stand_in_cudss.plans == 2 and stand_in_cudss.factorizations == 2
    B = rng.normal(size=(K.shape[0], 300))  # wider than MAX_WIDTH: in pieces of the kept width
    assert np.abs(K @ first.solve(B) - B).max() <= 1e-9 * np.abs(B).max()
    assert stand_in_cudss.plans == 2
    second = CudssFactor(pattern, 2.0 * tan.assemble_upper(pattern))  # another matrix of the pattern
    b = rng.normal(size=K.shape[0])
    assert np.allclose(second.solve(b), np.linalg.solve(2.0 * K, b))
    assert np.allclose(first.solve(b), np.linalg.solve(K, b))  # refactored: the session held the second
    assert stand_in_cudss.plans == 2 and stand_in_cudss.factorizations == 4  # the wider plan kept
    first.free()
    with pytest.raises(RuntimeError, match="freed"):
        first.solve(b)


def test_cudss_failed_cholesky_raises_and_leaves_no_current_factor(stiffness, stand_in_cudss):
    from wface.solvers.cudss import CudssFactor

    sim, x, a, _ = stiffness
    tan = sim.tangent(x, a)
    pattern = sim.pattern("free")
    with pytest.raises(NotPositiveDefiniteError, match="INFO 1"):
        CudssFactor(pattern, -tan.assemble_upper(pattern))
    good = CudssFactor(pattern, tan.assemble_upper(pattern))  # the same session serves the next matrix
    b = np.ones(pattern.shape[0])
    assert np.allclose(tan.assemble(pattern) @ good.solve(b), b)
