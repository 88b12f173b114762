"""The reference TST engine (``op0``): executes fully instantiated trees for the delegation
service (seed section 14)."""

from delegation.engine.core import TstEngine
from delegation.engine.executor import EngineOptions, TreeExecutor

__all__ = ["EngineOptions", "TreeExecutor", "TstEngine"]
