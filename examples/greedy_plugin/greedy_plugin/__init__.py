"""An example delegation strategy plugin (docs/strategies.md): ``least_loaded``."""

from greedy_plugin.strategy import least_loaded

__all__ = ["least_loaded"]
