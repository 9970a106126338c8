"""HDR imaging: RAW decoding, exposure merging, EXR I/O, sphere geometry and detection, light probes.

Knows nothing of devices (``rig``) or of the fitter (``fit``).
"""
