"""pyvista set up for off-screen pictures on machines without a display."""

from __future__ import annotations

__all__ = ["offscreen_pyvista"]


def offscreen_pyvista():
    """Import pyvista for off-screen rendering and return the module.

    VTK's X11 render window logs "bad X server connection" on headless machines and then renders
    off screen anyway; VTK's log is kept to errors so that warning does not reach the user.
    """
    import pyvista as pv

    pv.OFF_SCREEN = True
    try:
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    except ImportError:  # pragma: no cover - VTK without vtkLogger
        pass
    return pv
