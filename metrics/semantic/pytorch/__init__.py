"""Segmenters in torch (needs the ``[model]`` extra): :mod:`.segformer`, :mod:`.upernet_convnext`,
checkpoint reading (:mod:`.checkpoints`), conversion + ONNX export (:mod:`.convert`) and a torch
scoring backend (:mod:`.backend`)."""
