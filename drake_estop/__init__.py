"""drake_estop: emergency stop for walking humanoids (Morisawa et al., IROS 2005) on Drake."""

__version__ = "0.1.0"
