"""Sparsity pattern of the 3x3-block stiffness matrix, built once per mesh and set of unknown nodes.

The element kernel writes each tet's 16 3x3 blocks straight into BSR values through
``block_index`` (m, 16): the position of block (a, b) of tet t in the BSR value array, or -1 when
node a or b is not an unknown (a Dirichlet node). scipy then turns the BSR matrix into CSR.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["BlockPattern"]


class BlockPattern:
    """Block sparsity of K restricted to ``dof_nodes`` (sorted node ids), in their order.

    Attributes:
        dof_nodes: (k,) node ids of the unknowns; row block r is node dof_nodes[r].
        node_to_dof: (n,) block row of each node, -1 for nodes left out.
        indptr, indices: BSR structure (block rows / columns).
        block_index: (m, 16) int32 position of block (a, b) of each tet in the values, or -1.
    """

    def __init__(self, tets: np.ndarray, n_nodes: int, dof_nodes: np.ndarray | None = None):
        tets = np.asarray(tets, dtype=np.int64)
        if dof_nodes is None:
            dof_nodes = np.arange(n_nodes)
        self.dof_nodes = np.asarray(dof_nodes, dtype=np.int64)
        self.n_nodes = int(n_nodes)
        self.node_to_dof = np.full(n_nodes, -1, dtype=np.int64)
        self.node_to_dof[self.dof_nodes] = np.arange(self.dof_nodes.size)
        k = self.dof_nodes.size
        local = self.node_to_dof[tets]  # (m, 4)
        rows = np.repeat(local, 4, axis=1)  # block (a, b) at column 4a + b
        cols = np.tile(local, (1, 4))
        valid = (rows >= 0) & (cols >= 0)
        keys = rows * k + cols
        unique, inverse = np.unique(keys[valid], return_inverse=True)
        self.block_index = np.full(keys.shape, -1, dtype=np.int32)
        self.block_index[valid] = inverse.astype(np.int32)
        self.n_blocks = unique.size
        brow = unique // k
        self.indices = (unique % k).astype(np.int32)
        self.indptr = np.zeros(k + 1, dtype=np.int32)
        np.cumsum(np.bincount(brow, minlength=k), out=self.indptr[1:])
        self.shape = (3 * k, 3 * k)

    def to_csr(self, blocks: np.ndarray) -> sp.csr_matrix:
        """CSR matrix from (n_blocks, 3, 3) block values laid out by this pattern."""
        bsr = sp.bsr_matrix((blocks, self.indices, self.indptr), shape=self.shape)
        csr = bsr.tocsr()
        csr.sort_indices()
        return csr

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
