"""Video in: the synthetic WAMI generator and reading frames from disk.

The constants below live here, not in ``synth`` (which imports cv2 and scipy),
so that the command line can show them in its help without those imports.
"""

FPS = 1.25
"""Frames per second of WPAFB 2009 (and of the synthetic videos)."""

DEFAULT_DENSITY = 1.5
"""Vehicles per 100 m of road (both directions) in a synthetic video."""
