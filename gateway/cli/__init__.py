"""The ``tactile-gateway`` command line: thin wrappers that parse, build config, call the library."""

from __future__ import annotations

import click

from . import _threads  # noqa: F401  (before numpy loads: see the module)
from .action_cmd import action_cmd
from .apply_cmd import apply_cmd
from .calibrate_cmd import calibrate_cmd
from .config_cmd import channels, check_config
from .discrepancy_cmd import discrepancy_cmd
from .model_cmd import model
from .record_cmd import paper, record
from .run_cmd import demo, poll_once, run
from .scan_cmd import scan
from .subscribe_cmd import subscribe
from .tare_cmd import tare
from .view_cmd import view


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="tactile-gateway")
def main() -> None:
    """Tactile-array gateway: Modbus in, drift-corrected forces out, Prometheus metrics."""


main.add_command(model)
main.add_command(check_config)
main.add_command(channels)
main.add_command(calibrate_cmd)
main.add_command(discrepancy_cmd)
main.add_command(run)
main.add_command(poll_once)
main.add_command(demo)
main.add_command(record)
main.add_command(paper)
main.add_command(tare)
main.add_command(scan)
main.add_command(subscribe)
main.add_command(apply_cmd)
main.add_command(action_cmd)
main.add_command(view)

__all__ = ["main"]
