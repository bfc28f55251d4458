"""The stiffness of a ``Simulator`` at one state: its element tangents (``Tangent``: matrix-free products,
diagonal, BSR/CSR assembly) and a factorised or preconditioned K_UU bound to a linear solver
(``StiffnessSolver``). Split from ``wface.physics.simulator``, which makes them (``Simulator.tangent``,
``Simulator.stiffness_solver``); they read the simulator's Warp state and kernels."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from wface.solvers import BlockPattern, LinearSolver

__all__ = ["StiffnessSolver", "Tangent"]


class Tangent:
    """The stiffness K = -df/dx at one configuration, held as per-tet 9x9 tangents V0 dP/dF
    (symmetric, stored packed: 45 values per tet).

    ``matvec`` is matrix-free (one Warp launch over tets), ``assemble`` builds a scipy CSR matrix
    over the unknowns of a ``BlockPattern`` (a Warp kernel scatters element blocks into BSR values),
    ``diagonal`` gives diag(K) for Jacobi preconditioning.
    """

    def __init__(self, sim, tangent_wp, projected: bool):  # sim: the Simulator that made it
        self._sim = sim
        self.element_tangents = tangent_wp  # wp.array of packed symmetric 9x9 (45 values), one per tet
        self.projected = projected
        self.device = sim.device
        self.n_nodes = sim.model.n_nodes
        self.dtype = sim._np_dtype  # the precision of the element tangents (``device_matvec``)
        self._upper: dict = {}  # pattern id -> upper-triangle values already assembled

    @property
    def rest_positions_m(self) -> np.ndarray:
        """(n, 3) rest positions of the nodes (the rigid-body modes of an AMG preconditioner)."""
        return self._sim.model.rest_positions_m

    def device_matvec(self, x, out) -> None:
        """out += K x on Warp arrays of vec3 on ``device`` (out zeroed by the caller): one launch."""
        s = self._sim
        inputs = [s._tets, s._dm_inv, self.element_tangents, x, out]
        s._wp.launch(s._k.tangent_matvec, s.model.n_tets, inputs=inputs, device=s.device)

    def matvec(self, v: np.ndarray) -> np.ndarray:
        """K v for v of shape (n, 3) (or flat 3n); returns (n, 3) float64."""
        s = self._sim
        v = np.asarray(v)
        n = s.model.n_nodes
        if v.shape not in ((n, 3), (3 * n,)):
            raise ValueError(f"v has shape {v.shape}, expected ({n}, 3) or ({3 * n},)")
        s._v.assign(v.astype(s._np_dtype).reshape(-1, 3))
        s._out.zero_()
        inputs = [s._tets, s._dm_inv, self.element_tangents, s._v, s._out]
        s._launch_tets(s._k.tangent_matvec, inputs, sliced=(0, 1, 2), scattered=(4,))
        return s._out.numpy().astype(np.float64)

    def diagonal(self) -> np.ndarray:
        """diag(K) as (n, 3)."""
        s = self._sim
        s._out.zero_()
        inputs = [s._tets, s._dm_inv, self.element_tangents, s._out]
        s._launch_tets(s._k.tangent_diagonal, inputs, sliced=(0, 1, 2), scattered=(3,))
        return s._out.numpy().astype(np.float64)

    def assemble_blocks(self, pattern: BlockPattern):
        """The (n_blocks,) 3x3 block values of K over ``pattern`` as a Warp array on ``device``."""
        s = self._sim
        block_index = s._block_index_array(pattern)
        blocks = s._wp.zeros(pattern.n_blocks, dtype=s._k.mat33, device=s.device)
        inputs = [s._dm_inv, self.element_tangents, block_index, blocks]
        s._launch_tets(s._k.tangent_assemble, inputs, sliced=(0, 1, 2), scattered=(3,))
        return blocks

    def assemble(self, pattern: BlockPattern | None = None) -> sp.csr_matrix:
        """K restricted to the rows and columns of ``pattern`` (default: all nodes) as CSR float64,
        (3k, 3kc); a pattern with ``col_nodes`` gives a coupling block such as K_UC."""
        pattern = pattern or self._sim.pattern(None)
        return pattern.to_csr(self.assemble_blocks(pattern).numpy().astype(np.float64))

    def assemble_upper(self, pattern: BlockPattern) -> np.ndarray:
        """(nnz,) float64 upper-triangle values of K_UU in the order of ``pattern.upper`` (the sparse
        direct solvers' input, with no format conversion)."""
        cached = self._upper.get(id(pattern))
        if cached is not None:
            return cached
        return pattern.upper_values(self.assemble_blocks(pattern).numpy())

    def assemble_free_and_coupling(self) -> sp.csr_matrix:
        """K_UC over the free rows and attached columns (``Simulator.pattern("coupling")``) as CSR, and
        K_UU's upper-triangle values, kept for ``assemble_upper(pattern("free"))``: one assembly pass
        over the tets for both (the tracker's Jacobians need both at every new stiffness)."""
        s = self._sim
        rows, uu, uc = s._free_rows_pattern()
        blocks = self.assemble_blocks(rows).numpy().astype(np.float64)
        free = s.pattern("free")
        self._upper[id(free)] = free.upper_values(blocks[uu])
        return s.pattern("coupling").to_csr(blocks[uc])


class StiffnessSolver:
    """K_UU X = B for many right-hand sides at one configuration (the Jacobian solves, docs/design.md
    "Linear solvers"): factored once with the direct backend, or Jacobi-preconditioned CG per column,
    through ``wface.solvers.LinearSolver``.

    Right-hand sides live on the unknowns of ``pattern`` (``pattern.gather`` / ``pattern.scatter``
    convert from / to nodal (n, 3) arrays); ``solve_nodal`` does that for you.
    """

    def __init__(self, tangent: Tangent, pattern: BlockPattern, engine: str):
        self.tangent = tangent
        self.pattern = pattern
        self.engine = engine
        self._linear = LinearSolver(engine, tangent.device)
        self._bound = self._linear.bind(tangent, pattern)

    @property
    def cg_iterations(self) -> int:
        """CG iterations over all ``solve`` calls (0 with the direct engine)."""
        return self._linear.cg_iterations

    def solve(self, B: np.ndarray, *, rtol: float = 1e-10) -> np.ndarray:
        """X = K_UU^-1 B for B of shape (3k,) or (3k, c)."""
        return self._bound.solve(np.asarray(B, dtype=np.float64), rtol=rtol)

    def coupling(self, dx_c: np.ndarray) -> np.ndarray:
        """K_UC dx_C over the unknowns (3k,) for moves dx_C (a, 3) of the model's attached nodes
        (the chord steps' lift, ``wface.physics.newton``): one matrix-free K v."""
        sim = self.tangent._sim
        v = np.zeros((sim.model.n_nodes, 3))
        v[sim.model.attached_nodes] = dx_c
        return self.pattern.gather(self.tangent.matvec(v))

    @property
    def factor(self):
        """The factorisation (direct engine), or None with CG."""
        return self._bound.factor

    def solve_nodal(self, F: np.ndarray, *, rtol: float = 1e-10) -> np.ndarray:
        """Nodal right-hand sides (n, 3) or (c, n, 3) -> nodal solutions, zero on Dirichlet nodes."""
        F = np.asarray(F, dtype=np.float64)
        if F.ndim == 2:
            return self.pattern.scatter(self.solve(self.pattern.gather(F), rtol=rtol))
        B = np.stack([self.pattern.gather(f) for f in F], axis=1)
        return self.pattern.scatter(self.solve(B, rtol=rtol))

    def free(self) -> None:
        """Release the factorisation now."""
        self._bound.free()
