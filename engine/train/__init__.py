"""Training: config and presets, the DNGaussian trainer, progress events, checkpoints.

Public API used by the workers, the CLI and the benchmarks::

    from sparsesplat.engine.train.run import RunSpec, build_run
    run = build_run(RunSpec("llff", {"depth.prior": "none"}), scene, out_dir="runs/x")
    result = run.trainer.run()

or, one level down, ``Trainer(scene, preset("llff"), priors, out_dir).run()``.
"""

from sparsesplat.engine.train.checkpoint import (
    CheckpointError,
    TrainedModel,
    load_checkpoint,
    load_model,
)
from sparsesplat.engine.train.config import ConfigError, TrainConfig
from sparsesplat.engine.train.presets import PRESET_ITERATIONS, PRESETS, preset
from sparsesplat.engine.train.progress import ProgressRecord, StateChange
from sparsesplat.engine.train.trainer import ModelCollapsed, Trainer, TrainResult, model_sh

__all__ = [
    "PRESETS",
    "PRESET_ITERATIONS",
    "CheckpointError",
    "ConfigError",
    "ModelCollapsed",
    "ProgressRecord",
    "StateChange",
    "TrainConfig",
    "TrainResult",
    "TrainedModel",
    "Trainer",
    "load_checkpoint",
    "load_model",
    "model_sh",
    "preset",
]
