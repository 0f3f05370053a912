"""Per-Gaussian appearance models of the trainer: SH basis, spotlight, low-frequency light, BRDFs, Gaussian parameters
and the shading entry point that turns them into one linear RGB colour per Gaussian (before rasterization).

Import the submodules directly (`spotlessgs.models.shading`, ...); this package file imports nothing heavy.
"""
