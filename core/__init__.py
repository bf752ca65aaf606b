"""NumPy-only algorithms of Nephele.  Nothing here imports Blender."""
