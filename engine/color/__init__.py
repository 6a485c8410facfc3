"""Colour models: the neural colour field (DNGaussian) and plain SH colours (3DGS)."""

from sparsesplat.engine.color.hashgrid import HashGrid
from sparsesplat.engine.color.models import ColorModel, NeuralColor, SHColor, make_color_model
from sparsesplat.engine.color.neural import NeuralColorField
from sparsesplat.engine.color.sh import eval_sh, sh_basis

__all__ = [
    "ColorModel",
    "HashGrid",
    "NeuralColor",
    "NeuralColorField",
    "SHColor",
    "eval_sh",
    "make_color_model",
    "sh_basis",
]
