"""Native CPU photometric loss (L1 + D-SSIM, value and gradient in one pass); the torch
implementation in ``engine.losses`` is the reference and the fallback."""
