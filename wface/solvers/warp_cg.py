"""Conjugate gradients entirely on a Warp device (the CUDA path; docs/design.md, "Linear solvers").

``warp.optim.linear.cg`` drives the iteration; the operator's ``device_matvec`` (the matrix-free
K.v kernel) is applied with the Dirichlet rows and columns masked out, and the preconditioner is
Jacobi. Vectors stay on the device as (n, 3) arrays; Dirichlet entries stay zero. On the CPU prefer
``wface.solvers.linear.pcg`` (numpy Krylov loop): Warp's CG is ~100x slower per iteration there.
"""

from __future__ import annotations

import numpy as np

__all__ = ["warp_pcg"]


def warp_pcg(operator, pattern, rhs: np.ndarray, *, rtol: float = 1e-8, maxiter: int | None = None):
    """Solve K_UU X = rhs on the operator's device; rhs (3k,) or (3k, c) over ``pattern``'s unknowns.

    ``operator`` (``wface.solvers.solver`` protocol): ``device``, ``n_nodes``, ``dtype`` (numpy
    float32 or float64), ``diagonal()`` and ``device_matvec(x, out)`` (out = K x on Warp arrays of
    vec3, out zeroed by the caller). Returns (X with rhs's shape, total iterations).
    """
    import warp as wp
    from warp.optim.linear import LinearOperator, cg

    from wface.kernels.fem import fem_kernels

    dt = np.dtype(operator.dtype).type
    k = fem_kernels(wp.float64 if dt == np.float64 else wp.float32)
    dev = operator.device
    n = operator.n_nodes
    mask_np = np.zeros(n, dtype=dt)
    mask_np[pattern.dof_nodes] = 1
    mask = wp.array(mask_np, dtype=k.scalar, device=dev)
    diag = operator.diagonal()
    inv = np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1.0), 0.0) * mask_np[:, None]
    inv_diag = wp.array(inv.astype(dt), dtype=k.vec3, device=dev)
    tmp = wp.zeros(n, dtype=k.vec3, device=dev)

    def matvec(x, y, z, alpha, beta):
        tmp.zero_()
        operator.device_matvec(x, tmp)
        wp.launch(k.masked_axpby, n, inputs=[tmp, y, mask, k.scalar(alpha), k.scalar(beta), z], device=dev)

    def precond(x, y, z, alpha, beta):
        wp.launch(k.diagonal_axpby, n, inputs=[inv_diag, x, y, k.scalar(alpha), k.scalar(beta), z], device=dev)

    A = LinearOperator(shape=(n, n), dtype=k.vec3, device=dev, matvec=matvec)
    M = LinearOperator(shape=(n, n), dtype=k.vec3, device=dev, matvec=precond)
    B = rhs[:, None] if rhs.ndim == 1 else rhs
    X = np.zeros_like(B, dtype=np.float64)
    total = 0
    for j in range(B.shape[1]):
        b = wp.array(pattern.scatter(B[:, j]).astype(dt), dtype=k.vec3, device=dev)
        x = wp.zeros(n, dtype=k.vec3, device=dev)
        its, _, _ = cg(A, b, x, tol=rtol, maxiter=maxiter or 20 * B.shape[0], M=M, use_cuda_graph=False)
        total += int(its)
        X[:, j] = pattern.gather(x.numpy().astype(np.float64))
    return (X[:, 0] if rhs.ndim == 1 else X), total
