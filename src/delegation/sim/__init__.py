"""Simulated units speaking the Heartbeat, Sensor and Direct Execution APIs.

`SimVehicle` is the body (tasks, kinematics, battery; time advances only through `step`);
`SimUnitCore` is the pure core around it that speaks the seed's protocol, `ExampleAgentCore` the
one that speaks the public example agent's; `SimUnit` runs either on MQTT, `SimFleet` runs one per
scenario agent.
"""

from delegation.sim.core import SIM_SIGNALS, SimCore, SimUnitCore
from delegation.sim.example_agent import EXAMPLE_AGENT_POLICY, ExampleAgentCore
from delegation.sim.fleet import SimFleet, agent_rates
from delegation.sim.unit import SimUnit
from delegation.sim.vehicle import (
    ALREADY_RUNNING,
    NOT_SUPPORTED,
    SimTask,
    SimVehicle,
    TaskEvent,
    TaskState,
    VehiclePolicy,
)

__all__ = [
    "ALREADY_RUNNING",
    "EXAMPLE_AGENT_POLICY",
    "NOT_SUPPORTED",
    "SIM_SIGNALS",
    "ExampleAgentCore",
    "SimCore",
    "SimFleet",
    "SimTask",
    "SimUnit",
    "SimUnitCore",
    "SimVehicle",
    "TaskEvent",
    "TaskState",
    "VehiclePolicy",
    "agent_rates",
]
