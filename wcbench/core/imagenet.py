"""ImageNet normalisation: the mean and standard deviation torchvision's backbones were trained with.

The VGG16 features (LPIPS-vgg and the content loss) and the ADE20K segmenters (SegFormer,
UperNet-ConvNeXt, as their Hugging Face image processors do) normalise RGB in [0, 1] with these.
"""

from __future__ import annotations

IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)
