"""Two-level structures over scenes of placed objects and instances."""
