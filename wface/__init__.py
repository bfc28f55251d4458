"""wface: anatomically based, muscle-driven facial animation.

Layers (data flows one way): model -> physics -> solvers -> tracking / basis / editing -> io / viz.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
