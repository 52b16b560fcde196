"""A simulated MIS tactile array: piezoresistive sensors (Kalantari et al.) behind Modbus.

Physics from ``gateway.model`` (tunneling, contact, creep) plus switchable world effects,
a divider and noisy ADC per channel (eq. 18), scripted loads (``scenarios``), ground-truth
records, fault injection, and Modbus TCP / RTU / RTU-over-TCP / TLS servers.

The register map is ``docs/register-map.md``; scenarios are described in
``docs/scenarios.md``.
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
    "Profile",
    "ProfileBuilder",
    "Record",
    "Recorder",
    "SampleBatch",
    "Scenario",
    "ScenarioError",
    "ServerStartError",
    "SimArray",
    "SimServer",
    "TemperatureProgram",
    "UniformLoad",
    "builtin_scenarios",
    "record_offline",
    "serve_serial",
    "serve_tcp",
    "serve_tls",
]
