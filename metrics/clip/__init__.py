"""CLIP-S and CLIP-DS.

The scoring path needs no torch: :mod:`.score` (the metrics), :mod:`.encoder` (preprocessing +
tokenizer + a backend + the embedding cache), :mod:`.onnx_backend` (onnxruntime), with
:mod:`.config`, :mod:`.tokenizer`, :mod:`.preprocess` and :mod:`.cache`. The torch-only parts
(the network, checkpoint conversion, ONNX export, a torch backend) live in :mod:`.pytorch`.
"""
