"""Spherical harmonics, rotations, lighting projection, BRDF fitting and relighting.

Knows nothing of devices (``rig``) or of image files (``hdr``): it takes plain
arrays (directions, radiance, solid angles, normals, weights).
"""
