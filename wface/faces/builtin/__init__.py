"""The built-in face: a procedurally generated anatomical face model at any resolution."""

from wface.faces.builtin.face import build_face

__all__ = ["build_face"]
