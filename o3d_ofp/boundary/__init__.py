"""The Open3D boundary: geometries <-> arrays, files, and the geometry-level API.

Open3D is imported lazily, inside the functions that need it.
"""
