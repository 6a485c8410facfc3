"""What a run is told: :class:`TrainConfig` and its sections, values read by name
(``overrides.py``, checked by ``values.py``) and the presets (``presets.py``).

The names below are the config's public surface (``from sparsesplat.engine.train.config
import TrainConfig``); each is defined in the module named beside it, the sections and their
value names in ``sections.py`` (the loop's) and ``regularizer_sections.py`` (the regularizer
parts'), each with its ``__all__``.
"""

from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.model.raster import RasterBackendName, RasterConfig
from sparsesplat.engine.train.config import regularizer_sections, sections
from sparsesplat.engine.train.config.regularizer_sections import *  # noqa: F403 (its __all__)
from sparsesplat.engine.train.config.sections import *  # noqa: F403 (its __all__: the sections)
from sparsesplat.engine.train.config.train_config import (
    REFERENCE_ITERATIONS,
    SCHEDULE_FIELDS,
    TrainConfig,
)

__all__ = [
    "REFERENCE_ITERATIONS",
    "SCHEDULE_FIELDS",
    "ConfigError",
    "RasterBackendName",
    "RasterConfig",
    "TrainConfig",
    *sections.__all__,
    *regularizer_sections.__all__,
]
