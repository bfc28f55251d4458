"""The Newton tangent with contact: the elastic tangent plus the contact pairs' Hessian
(docs/design.md, "Contact")."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["ContactTangent"]


class ContactTangent:
    """Elastic tangent + contact Hessian, with the ``Tangent`` interface used by the Newton solver
    (``matvec``, ``diagonal``, ``assemble``): the Gauss-Newton contact Hessian, or for smooth lip
    surfaces with the exact (unprojected) elastic tangent, their exact Hessian too."""

    def __init__(self, tangent, pairs):  # pairs: wface.physics.contact.ContactPairs
        self.elastic = tangent
        self.contact = pairs
        self._sim = tangent._sim
        self.projected = tangent.projected
        self._exact = not tangent.projected

    def matvec(self, v: np.ndarray) -> np.ndarray:
        return self.elastic.matvec(v) + self.contact.matvec(v, exact=self._exact)

    def diagonal(self) -> np.ndarray:
        return self.elastic.diagonal() + self.contact.diagonal(exact=self._exact)

    def assemble(self, pattern=None) -> sp.csr_matrix:
        pattern = pattern or self._sim.pattern(None)
        K = self.elastic.assemble(pattern)
        if not len(self.contact.node):
            return K
        K = (K + self.contact.assemble(pattern, exact=self._exact)).tocsr()
        K.sort_indices()
        return K
