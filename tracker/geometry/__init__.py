"""Geometry: poses, cameras, parts, symmetry groups and the depth renderers of boxes and meshes."""
