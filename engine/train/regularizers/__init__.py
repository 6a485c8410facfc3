"""The optional regularizer parts, each built only when its config section turns it on: the
depth prior's hard/soft passes (``depth_regularizer.py``) and which views keep their prior
(``depth_gate.py``), warp consistency, DropGaussian, near-plane pruning and the DTU background
handling. Each follows the part protocol of ``engine/train/loop/parts.py``."""
