"""Sem-CS: frequency-weighted IoU of segmentations of source and edit.

The scoring path needs no torch: :mod:`.consistency` (fwIoU and the metric) and :mod:`.segmenter`
(preprocessing, the onnxruntime segmenter, upsampling + argmax) and :mod:`.loading` (which
segmenter, which backend). The torch-only parts (SegFormer
and UperNet-ConvNeXt networks, checkpoint reading, conversion and ONNX export, a torch backend)
live in :mod:`.pytorch`.
"""
