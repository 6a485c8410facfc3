"""Training: config and presets (``config/``), the DNGaussian trainer and the parts every run
builds (``loop/``), the optional regularizer parts (``regularizers/``), the initial Gaussians
(``init/``) and the run recipe (``run.py``). The trained model itself (checkpoints, rendering,
SH, exports) lives in ``engine/model/``.

Public API used by the workers, the CLI and the benchmarks::

    from sparsesplat.engine.train.run import RunSpec, build_run
    run = build_run(RunSpec("llff", {"depth.prior": "none"}), scene, out_dir="runs/x")
    result = run.trainer.run()

or, one level down, ``Trainer(scene, preset("llff"), priors, out_dir).run()``.
"""

from sparsesplat.engine.train.config import ConfigError, TrainConfig
from sparsesplat.engine.train.config.presets import PRESET_ITERATIONS, PRESETS, preset
from sparsesplat.engine.train.loop.densify import ModelCollapsed
from sparsesplat.engine.train.loop.progress import ProgressRecord, StateChange
from sparsesplat.engine.train.loop.result import TrainResult
from sparsesplat.engine.train.loop.trainer import Trainer

__all__ = [
    "PRESETS",
    "PRESET_ITERATIONS",
    "ConfigError",
    "ModelCollapsed",
    "ProgressRecord",
    "StateChange",
    "TrainConfig",
    "TrainResult",
    "Trainer",
    "preset",
]
