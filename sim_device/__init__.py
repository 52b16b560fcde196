"""A simulated MIS tactile array: piezoresistive sensors (Kalantari et al.) behind Modbus.

An independent witness of the gateway: it imports nothing of ``gateway``. Its physics
(``sensor``: tunneling, contact, creep integrated by Runge-Kutta) and read-out
(``electronics``: divider and noisy ADC, eq. 18) are written again from the paper and
``docs/parameters.md``; ``world`` adds switchable effects beyond the paper. Scripted loads
(``scenarios``), ground-truth records, fault injection, and Modbus TCP / RTU / RTU-over-TCP
/ TLS servers. What it shares with the gateway are documents: the register map and the
record format.

The register map is ``docs/register-map.md``; a second, commercial-style map ("rawgrid",
``docs/register-map-rawgrid.md``, ``ArrayConfig(register_map="rawgrid")``) serves the same
physics with another wire format and read-out (``maps``, ``rawgrid``). Scenarios are
described in ``docs/scenarios.md``.
"""

from .array import SampleBatch, SimArray
from .config import DEFAULT_SPREAD, WORLD_EFFECTS, ArrayConfig, ConfigError
from .faults import FaultDecision, FaultError, FaultInjector
from .modbus_server import LineTiming, ServerStartError, SimServer, serve_serial, serve_tcp, serve_tls
from .record import Record, Recorder, record_offline
from .scenarios import (
    ArrayLayout,
    FaultEvent,
    Indentation,
    Profile,
    ProfileBuilder,
    Scenario,
    ScenarioError,
    TemperatureProgram,
    UniformLoad,
    builtin_scenarios,
)
from .sensor import PaperSensor, SensorParamsError, SimSensorParams

__all__ = [
    "DEFAULT_SPREAD",
    "WORLD_EFFECTS",
    "ArrayConfig",
    "ArrayLayout",
    "ConfigError",
    "FaultDecision",
    "FaultError",
    "FaultEvent",
    "FaultInjector",
    "Indentation",
    "LineTiming",
    "PaperSensor",
    "Profile",
    "ProfileBuilder",
    "Record",
    "Recorder",
    "SampleBatch",
    "Scenario",
    "ScenarioError",
    "SensorParamsError",
    "ServerStartError",
    "SimArray",
    "SimSensorParams",
    "SimServer",
    "TemperatureProgram",
    "UniformLoad",
    "builtin_scenarios",
    "record_offline",
    "serve_serial",
    "serve_tcp",
    "serve_tls",
]
