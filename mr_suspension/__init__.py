"""mr_suspension: semi-active MR-damper quarter-car suspension for ROS 2."""

__version__ = '0.1.0'
