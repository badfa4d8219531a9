"""learnstitch: a supervised PyTorch stitching network for three 185-degree fisheye cameras.

Built on rigjax's camera model. The data synthesis, the network and its training and evaluation
jobs arrive with their own issues; this release provides the package and its command.
"""

__version__ = "0.1.0"
