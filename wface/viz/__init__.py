"""Pictures, plots, movies and HTML reports people look at (pyvista, matplotlib, imageio: optional)."""
