"""Export Gaussians: the INRIA 3DGS .ply, the .splat format, and baking neural colour into SH."""

from sparsesplat.engine.export.bake import (
    bake_sh,
    fibonacci_sphere,
    sh_baking_error,
    view_directions,
)
from sparsesplat.engine.export.errors import ExportError
from sparsesplat.engine.export.ply import export_ply, ply_property_names, read_ply
from sparsesplat.engine.export.sh_eval import eval_sh, sh_basis
from sparsesplat.engine.export.splat import export_splat, read_splat

__all__ = [
    "ExportError",
    "bake_sh",
    "eval_sh",
    "export_ply",
    "export_splat",
    "fibonacci_sphere",
    "ply_property_names",
    "read_ply",
    "read_splat",
    "sh_baking_error",
    "sh_basis",
    "view_directions",
]
