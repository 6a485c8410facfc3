"""What a run is told: :class:`TrainConfig` and its sections, values read by name
(``overrides.py``, checked by ``values.py``) and the presets (``presets.py``).

The names below are the config's public surface (``from sparsesplat.engine.train.config
import TrainConfig``); each is defined in the module named beside it.
"""

from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.model.raster import RasterBackendName, RasterConfig
from sparsesplat.engine.train.config.sections import (
    AuxiliaryStepName,
    Box,
    ColorConfig,
    ConsistencyConfig,
    ConsistencyPartnersName,
    CorrespondenceConfig,
    DensifyConfig,
    DepthConfig,
    DropoutConfig,
    DtuConfig,
    GuardConfig,
    InitConfig,
    MatcherName,
    MatchesConfig,
    NearPruneConfig,
    OptimConfig,
    PartnerDepthName,
    PhotometricConfig,
    RecordConfig,
)
from sparsesplat.engine.train.config.train_config import (
    REFERENCE_ITERATIONS,
    SCHEDULE_FIELDS,
    TrainConfig,
)

__all__ = [
    "REFERENCE_ITERATIONS",
    "SCHEDULE_FIELDS",
    "AuxiliaryStepName",
    "Box",
    "ColorConfig",
    "ConfigError",
    "ConsistencyConfig",
    "ConsistencyPartnersName",
    "CorrespondenceConfig",
    "DensifyConfig",
    "DepthConfig",
    "DropoutConfig",
    "DtuConfig",
    "GuardConfig",
    "InitConfig",
    "MatcherName",
    "MatchesConfig",
    "NearPruneConfig",
    "OptimConfig",
    "PartnerDepthName",
    "PhotometricConfig",
    "RasterBackendName",
    "RasterConfig",
    "RecordConfig",
    "TrainConfig",
]
