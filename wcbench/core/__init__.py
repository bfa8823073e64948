"""The core layer: what every other part of wcbench builds on, importing nothing else of it.

Errors that reach the user (:mod:`.errors`), atomic writes and content hashes (:mod:`.storage`),
strict image and video I/O (:mod:`.image_io`), lazy registries (:mod:`.registry`), progress bars
(:mod:`.progress`), frame timing (:mod:`.timing`), machine and version records
(:mod:`.environment`), cache folders (:mod:`.paths`), the weather vocabulary (:mod:`.weathers`),
ImageNet normalisation (:mod:`.imagenet`) and the model store (:mod:`.models`). See
docs/architecture.md for the layers above it.
"""
