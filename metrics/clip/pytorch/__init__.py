"""CLIP in torch (needs the ``[model]`` extra): the network (:mod:`.model`), checkpoint formats
(:mod:`.checkpoints`), conversion into the model store (:mod:`.convert`), ONNX export
(:mod:`.export`) and a torch scoring backend (:mod:`.backend`)."""
