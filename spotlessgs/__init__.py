"""SpotlessGS: relightable Gaussian Splatting for images lit by a camera-mounted spotlight.

Importing this package is cheap (no torch); heavy modules are imported where they are used.
"""

__version__ = "0.1.0"
