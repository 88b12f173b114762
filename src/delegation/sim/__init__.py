"""Simulated units speaking the Heartbeat, Sensor and Direct Execution APIs.

`SimVehicle` is the pure part (tasks, kinematics, battery; time advances only through `step`),
`SimUnit` puts one on MQTT, `SimFleet` runs one per scenario agent.
"""

from delegation.sim.fleet import SimFleet
from delegation.sim.unit import SIM_SIGNALS, SimUnit
from delegation.sim.vehicle import (
    ALREADY_RUNNING,
    NOT_SUPPORTED,
    SimTask,
    SimVehicle,
    TaskEvent,
    TaskState,
)

__all__ = [
    "ALREADY_RUNNING",
    "NOT_SUPPORTED",
    "SIM_SIGNALS",
    "SimFleet",
    "SimTask",
    "SimUnit",
    "SimVehicle",
    "TaskEvent",
    "TaskState",
]
