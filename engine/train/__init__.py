"""Training: config and presets, the DNGaussian trainer, progress events, checkpoints.

Public API used by the workers, the CLI and the benchmarks::

    from sparsesplat.engine.train import Trainer, preset
    result = Trainer(scene, preset("llff"), priors, out_dir, on_progress=cb).run()
"""

from sparsesplat.engine.train.checkpoint import (
    CheckpointError,
    TrainedModel,
    load_checkpoint,
    load_model,
)
from sparsesplat.engine.train.config import PRESETS, ConfigError, TrainConfig, preset
from sparsesplat.engine.train.progress import ProgressRecord, StateChange
from sparsesplat.engine.train.trainer import ModelCollapsed, Trainer, TrainResult, model_sh

__all__ = [
    "PRESETS",
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
