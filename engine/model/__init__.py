"""The trained model as one object: Gaussians + colour model, stored in checkpoints, rendered
(one render wrapper), baked to SH (one bake) and exported (.ply, .splat).

The trainer's evaluation, its recorder and checkpoints, the render worker and the local
``render`` command all go through here; nothing here imports the training package, so a
renderer loads none of it::

    from sparsesplat.engine.model import load_model
    image = load_model("runs/x").render(camera).image
"""

from sparsesplat.engine.model.checkpoint import (
    CHECKPOINT_NAME,
    CheckpointError,
    load_checkpoint,
    model_state,
    save_checkpoint,
)
from sparsesplat.engine.model.trained import TrainedModel, load_model

__all__ = [
    "CHECKPOINT_NAME",
    "CheckpointError",
    "TrainedModel",
    "load_checkpoint",
    "load_model",
    "model_state",
    "save_checkpoint",
]
