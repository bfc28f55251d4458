"""Fixtures with known answers, for the tests, the benchmarks and the data-free examples.

Not anatomy: ``box`` (structured tet meshes of a box), ``models`` (box-shaped ``FaceModel``s with a
muscle along x, bones on chosen faces), ``synthetic_face`` (a spherical-cap face with fake muscles,
bones and markers, and a hand-made animated take, for writers and renderers) and
``synthetic_head`` (an ellipsoid head with the ICT landmark names, for the Waters layouts).
"""
