"""LPIPS v0.1: the metric without torch (:mod:`.lpips`: onnxruntime or numpy), its constants
(:mod:`.spec`), the converters of the real weights (:mod:`.weights`) and the torch network with
its ONNX export (:mod:`.pytorch`)."""
