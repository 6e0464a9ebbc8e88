"""polyslam: multi-robot exploration with polynomial-landmark EKF SLAM in the loop."""

from polyslam_env.errors import ConfigError, MapFileError, PolyslamError

__version__ = "0.1.0"

__all__ = ["ConfigError", "MapFileError", "PolyslamError", "__version__"]
