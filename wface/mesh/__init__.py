"""Mesh utilities: surfaces, closest points, quality, import/export."""
