"""LPIPS in torch (needs the ``[model]`` extra): the reference network and its ONNX export."""
