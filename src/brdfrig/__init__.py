"""brdfrig: measure isotropic BRDFs under natural light with a chrome probe and sample spheres.

Layers (imports flow downward only; ``tests/test_layers.py`` checks it):
``rig`` (device drivers) and ``hdr`` (images) and ``fit`` (numbers) at the bottom,
``lighting`` the one bridge between ``hdr`` and ``fit``, ``session`` (capture and
offline pipeline), ``sim`` (simulated devices), ``evaluate`` (benchmarks shipped
with the tool), and ``cli`` (the ``brdfrig`` command) on top.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("brdfrig")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"
