"""The reference TST engine (``op0``): executes fully instantiated trees for the delegation
service (seed section 14).

``tree`` holds an executing tree's state, ``executor`` the pure state machine over it
(`TreeExecutor`, timing rules in `EngineOptions`), ``core`` the pure unit core that speaks the
TST Execution API (`EngineCore`), ``unit`` puts that core on a broker (`TstEngine`).
"""

from delegation.engine.core import EngineCore
from delegation.engine.executor import (
    Action,
    EngineOptions,
    NodeChanged,
    SendSignal,
    SendStartTask,
    TreeExecutor,
)
from delegation.engine.tree import check_instantiated
from delegation.engine.unit import TstEngine

__all__ = [
    "Action",
    "EngineCore",
    "EngineOptions",
    "NodeChanged",
    "SendSignal",
    "SendStartTask",
    "TreeExecutor",
    "TstEngine",
    "check_instantiated",
]
