"""Importers of external face models into ``wface.model.FaceModel``."""

from __future__ import annotations

from wface.importers.artisynth import import_artisynth

__all__ = ["import_artisynth"]
