"""Pixel metrics against a ground truth: PSNR (:mod:`.psnr`) and SSIM (:mod:`.ssim`)."""
