"""The constants of LPIPS v0.1 (Zhang et al., CVPR 2018), shared by the numpy scorer and the torch network.

Both :mod:`wcbench.metrics.perceptual.lpips` (numpy / onnxruntime) and
:mod:`wcbench.metrics.perceptual.pytorch.network` (the torch reference that exports the ONNX graph)
read them from here, so the two backends cannot drift apart.
"""

from __future__ import annotations

#: Backbones: AlexNet (the authors' recommended forward metric) and VGG16.
NETS = ("alex", "vgg")
#: The ScalingLayer of richzhang/PerceptualSimilarity: ``(x - shift) / scale`` on inputs in [-1, 1].
LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)
#: Added to the channel norm before unit-normalising features.
NORM_EPS = 1e-10
#: Channels of the five tapped layers (one learned linear weight per channel).
CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}
#: The VGG16 layers LPIPS taps (the last ReLU of each block).
VGG_LAYERS = ("relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3")
