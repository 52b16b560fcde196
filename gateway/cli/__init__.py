"""The ``tactile-gateway`` command line: thin wrappers that parse, build config, call the library.

Each subcommand's module is imported only when that subcommand runs (or ``--help`` lists it):
``calibrate`` does not pay for the web page, the poller and MQTT, about a second of imports.
"""

from __future__ import annotations

import importlib

import click

from . import _threads  # noqa: F401  (before numpy loads: see the module)

#: Every subcommand: its name, and the module and attribute that define it.
COMMANDS: dict[str, tuple[str, str]] = {
    "model": ("model_cmd", "model"),
    "check-config": ("config_cmd", "check_config"),
    "channels": ("config_cmd", "channels"),
    "calibrate": ("calibrate_cmd", "calibrate_cmd"),
    "discrepancy": ("discrepancy_cmd", "discrepancy_cmd"),
    "run": ("run_cmd", "run"),
    "poll-once": ("run_cmd", "poll_once"),
    "demo": ("run_cmd", "demo"),
    "record": ("record_cmd", "record"),
    "paper": ("record_cmd", "paper"),
    "tare": ("tare_cmd", "tare"),
    "scan": ("scan_cmd", "scan"),
    "subscribe": ("subscribe_cmd", "subscribe"),
    "apply": ("apply_cmd", "apply_cmd"),
    "action": ("action_cmd", "action_cmd"),
    "view": ("view_cmd", "view"),
}


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use (click's lazy-loading pattern)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(COMMANDS))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in COMMANDS and cmd_name not in self.commands:
            module_name, attribute = COMMANDS[cmd_name]
            module = importlib.import_module(f"{__name__}.{module_name}")
            command = getattr(module, attribute)
            if not isinstance(command, click.Command):
                raise TypeError(f"{module_name}.{attribute} is not a click command")
            self.add_command(command, cmd_name)
        return super().get_command(ctx, cmd_name)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="tactile-gateway")
def main() -> None:
    """Tactile-array gateway: Modbus in, drift-corrected forces out, Prometheus metrics."""


__all__ = ["COMMANDS", "main"]
