"""Warp device code for wface (installed as ``wface.kernels``).

Only ``@wp.func`` / ``@wp.kernel`` definitions live here; host code that prepares arrays and
launches kernels is in the ``wface`` package.
"""
