"""Linear actuation basis of Choe & Ko (2001): analysis, refinement and retargeting.

Modules: ``core`` (the basis, builders, save/load), ``analysis`` (per-frame contractions, by the
active-set bounded least squares of ``wface.solvers.bvls``, re-exported here),
``capture`` (take -> model frame), ``refine`` (fixed-point
refinement and RBF carry-over), ``retarget`` (drive another basis), ``landmarks`` (AnimFace on
ICT), ``pipeline`` (the steps the CLI runs), ``plots``.
"""

from wface.basis.analysis import Analysis, FaceSplit, MarkerBasis, analyze, default_face_split
from wface.basis.capture import CaptureOnBasis, MarkerLayout, stabilise_capture
from wface.basis.core import ActuationBasis, load_basis
from wface.basis.refine import RefinementResult, interpolate_to_mesh, model_marker_shapes, refine_marker_basis
from wface.basis.retarget import ElementMatch, RetargetResult, match_elements, retarget
from wface.solvers.bvls import BoundedLSQResult, bounded_lstsq, bounded_qp

__all__ = [
    "ActuationBasis",
    "Analysis",
    "BoundedLSQResult",
    "CaptureOnBasis",
    "ElementMatch",
    "FaceSplit",
    "MarkerBasis",
    "MarkerLayout",
    "RefinementResult",
    "RetargetResult",
    "analyze",
    "bounded_lstsq",
    "bounded_qp",
    "default_face_split",
    "interpolate_to_mesh",
    "load_basis",
    "match_elements",
    "model_marker_shapes",
    "refine_marker_basis",
    "retarget",
    "stabilise_capture",
]
