"""defocus: the command line of the Defocus toolbox (`defocus ...`) and its version.

The library lives in the packages `optics` (physics, rendering, calibration), `models`
(networks, losses, metrics, training) and `datasets` (loaders, synthetic scenes). This package
only parses arguments and calls them; nothing imports it.
"""

__version__ = "0.2.0"
