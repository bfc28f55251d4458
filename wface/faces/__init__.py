"""Face models: where a ``wface.model.FaceModel`` comes from.

``builtin`` (the procedural face at any resolution: ``build_face``), ``artisynth`` (the ArtiSynth
"Badin" FEM face: hexes split into tets, slivers removed, muscles from fibre points), ``ansys``
(the ANSYS mesh and element files ArtiSynth reads), ``artisynth_markers`` (the AnimFace-named
markers placed on the Badin skin), ``fibres`` (muscle fibre fields from polylines),
``summary`` (a model in numbers).
"""

from __future__ import annotations

from wface.faces.artisynth import import_artisynth
from wface.faces.builtin import build_face
from wface.faces.summary import model_summary

__all__ = ["build_face", "import_artisynth", "model_summary"]
