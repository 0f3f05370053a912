"""Single-view 2D baselines (paper Table IV): each uneven image is mapped to an evenly lit one on its own.

Classic enhancement (CLAHE on L*, MSRCR) and an unpaired Cycle-GAN (in ``spotlessgs.baselines2d.cyclegan``, which
imports torch). All take and return float (H, W, 3) sRGB images in [0, 1]; ``enhance_folder`` runs any of them over
a folder of image files.
"""

from spotlessgs.baselines2d.clahe import ClaheConfig, clahe
from spotlessgs.baselines2d.enhance import METHODS, enhance_folder
from spotlessgs.baselines2d.msrcr import MsrcrConfig, msrcr

__all__ = ["METHODS", "ClaheConfig", "MsrcrConfig", "clahe", "enhance_folder", "msrcr"]
