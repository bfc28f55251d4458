"""wface: anatomically based, muscle-driven facial animation.

Layers: a package imports itself and lower layers only (docs/design.md, "Layers").
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
