"""ampc-vo: visual odometry for an articulated multi-perspective camera (truck with trailer).

Conventions (frames, angles, pose names) are those of DESIGN section 1; see README.md.
"""
from ampc_vo.errors import AmpcError, BearingError, ConfigError, DatasetError

__all__ = ["AmpcError", "BearingError", "ConfigError", "DatasetError"]
__version__ = "0.1.0"
