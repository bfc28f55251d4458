"""Input and output: motion capture, meshes, USD."""
