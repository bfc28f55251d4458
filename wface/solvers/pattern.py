"""Sparsity pattern of the 3x3-block stiffness matrix, built once per mesh and set of unknown nodes.

The element kernel writes each tet's 16 3x3 blocks straight into BSR values through
``block_index`` (m, 16): the position of block (a, b) of tet t in the BSR value array, or -1 when
node a or b is not an unknown (a Dirichlet node). scipy then turns the BSR matrix into CSR, or, for
the sparse direct solvers, ``upper_values`` gathers the upper triangle in CSR order straight from the
block values through an index computed once per pattern (no conversion per factorisation).

A pattern may also have other *column* nodes than row nodes (``col_nodes``): the coupling block
K_UC between the unknowns U and the attached nodes C (docs/design.md, "Jacobians").
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

__all__ = ["BlockPattern", "UpperStructure"]


class UpperStructure:
    """The upper triangle of a square ``BlockPattern`` in scalar CSR (sorted, zero-based).

    Attributes:
        indptr, indices: int32 CSR structure of the upper triangle (diagonal included), (3k + 1,), (nnz,).
        take: (nnz,) int64 positions of these entries in the flattened (n_blocks, 3, 3) block values.
    """

    def __init__(self, pattern: BlockPattern):
        k = pattern.dof_nodes.size
        brow = np.repeat(np.arange(k), np.diff(pattern.indptr))  # block row of each block
        bcol = pattern.indices.astype(np.int64)
        nb = bcol.size
        i, j = np.divmod(np.arange(9), 3)
        rows = (3 * brow[:, None] + i[None, :]).ravel()
        cols = (3 * bcol[:, None] + j[None, :]).ravel()
        keep = np.flatnonzero(cols >= rows)
        order = np.lexsort((cols[keep], rows[keep]))  # CSR order: by row, then column
        self.take = keep[order].astype(np.int64)
        self.indices = cols[self.take].astype(np.int32)
        counts = np.bincount(rows[self.take], minlength=3 * k)
        self.indptr = np.zeros(3 * k + 1, dtype=np.int32)
        np.cumsum(counts, out=self.indptr[1:])
        self.n = 3 * k
        self.nnz = int(self.take.size)
        assert nb * 9 >= self.nnz


class BlockPattern:
    """Block sparsity of K restricted to ``dof_nodes`` (sorted node ids), in their order.

    Args:
        tets: (m, 4) tet node ids.
        n_nodes: node count of the mesh.
        dof_nodes: row (and, by default, column) nodes; default: every node.
        col_nodes: other column nodes (sorted ids), for a rectangular block such as K_UC.

    Attributes:
        dof_nodes: (k,) node ids of the unknowns; row block r is node dof_nodes[r].
        col_nodes: (kc,) node ids of the block columns (``dof_nodes`` for a square pattern).
        node_to_dof: (n,) block row of each node, -1 for nodes left out.
        indptr, indices: BSR structure (block rows / columns).
        block_index: (m, 16) int32 position of block (a, b) of each tet in the values, or -1.
        shape: (3k, 3kc).
    """

    def __init__(
        self, tets: np.ndarray, n_nodes: int, dof_nodes: np.ndarray | None = None, col_nodes: np.ndarray | None = None
    ):
        tets = np.asarray(tets, dtype=np.int64)
        if dof_nodes is None:
            dof_nodes = np.arange(n_nodes)
        self.dof_nodes = np.asarray(dof_nodes, dtype=np.int64)
        self.square = col_nodes is None
        self.col_nodes = self.dof_nodes if col_nodes is None else np.asarray(col_nodes, dtype=np.int64)
        self.n_nodes = int(n_nodes)
        self.node_to_dof = np.full(n_nodes, -1, dtype=np.int64)
        self.node_to_dof[self.dof_nodes] = np.arange(self.dof_nodes.size)
        node_to_col = self.node_to_dof
        if not self.square:
            node_to_col = np.full(n_nodes, -1, dtype=np.int64)
            node_to_col[self.col_nodes] = np.arange(self.col_nodes.size)
        k, kc = self.dof_nodes.size, self.col_nodes.size
        rows = np.repeat(self.node_to_dof[tets], 4, axis=1)  # block (a, b) at column 4a + b
        cols = np.tile(node_to_col[tets], (1, 4))
        valid = (rows >= 0) & (cols >= 0)
        keys = rows * kc + cols
        unique, inverse = np.unique(keys[valid], return_inverse=True)
        self.block_index = np.full(keys.shape, -1, dtype=np.int32)
        self.block_index[valid] = inverse.astype(np.int32)
        self.n_blocks = unique.size
        brow = unique // kc if kc else unique
        self.indices = (unique % kc if kc else unique).astype(np.int32)
        self.indptr = np.zeros(k + 1, dtype=np.int32)
        np.cumsum(np.bincount(brow, minlength=k), out=self.indptr[1:])
        self.shape = (3 * k, 3 * kc)

    def to_csr(self, blocks: np.ndarray) -> sp.csr_matrix:
        """CSR matrix from (n_blocks, 3, 3) block values laid out by this pattern."""
        bsr = sp.bsr_matrix((blocks, self.indices, self.indptr), shape=self.shape)
        csr = bsr.tocsr()
        csr.sort_indices()
        return csr

    @cached_property
    def upper(self) -> UpperStructure:
        """The upper-triangle CSR structure of a square pattern (computed once)."""
        if not self.square:
            raise ValueError("only a square pattern has an upper triangle")
        return UpperStructure(self)

    def upper_values(self, blocks: np.ndarray) -> np.ndarray:
        """(nnz,) float64 values of the upper triangle in the order of ``upper`` from (n_blocks, 3, 3) blocks."""
        return np.ascontiguousarray(np.asarray(blocks, dtype=np.float64).reshape(-1)[self.upper.take])

    def gather(self, v: np.ndarray) -> np.ndarray:
        """(n, 3) nodal vector -> (3k,) vector of the unknowns."""
        return np.ascontiguousarray(v[self.dof_nodes]).reshape(-1)

    def scatter(self, u: np.ndarray, n_columns: int | None = None) -> np.ndarray:
        """(3k,) or (3k, c) unknowns -> (n, 3) or (c, n, 3) nodal array, zeros elsewhere."""
        if u.ndim == 1:
            out = np.zeros((self.n_nodes, 3))
            out[self.dof_nodes] = u.reshape(-1, 3)
            return out
        c = u.shape[1]
        out = np.zeros((c, self.n_nodes, 3))
        out[:, self.dof_nodes] = u.T.reshape(c, -1, 3)
        return out
