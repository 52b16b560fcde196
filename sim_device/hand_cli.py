"""``tactile-sim run --map hand``: the hand from the command line's options (``sim_device.cli``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from . import hand_map as hm
from .hand import HandDevice
from .hand_scenarios import parse_taxel_specs


def make_hand(
    scenario: str,
    layout: str,
    base_offset: int,
    dead: str,
    frozen: str,
    stuck: str,
    saturation_code: int,
    joint_errors: Sequence[str],
    *,
    seed: int,
    speed: float,
    noise_lsb: float,
    device_id: int,
    rest_offset_lsb: float = 0.0,
    **array_options: Any,
) -> HandDevice:
    """The hand the options describe; ``ValueError`` (or ``ScenarioError``) with a precise message."""
    hand = HandDevice(
        scenario,
        layout=hm.Layout(layout, base_offset),
        seed=seed,
        speed=speed,
        noise_lsb=noise_lsb,
        rest_offset_lsb=rest_offset_lsb,
        saturation_code=saturation_code,
        dead=parse_taxel_specs(dead, "--dead"),
        frozen=parse_taxel_specs(frozen, "--frozen", allow_value=True),
        stuck=parse_taxel_specs(stuck, "--stuck"),
        device_id=device_id,
        **array_options,
    )
    for item in joint_errors:
        joint, sep, bit = item.partition(":")
        if not sep:
            raise ValueError(f"--joint-error {item!r} is not JOINT:BIT (e.g. index:stall)")
        hand.set_error(joint.strip(), bit.strip())
    return hand


def describe(hand: HandDevice) -> str:
    """One line: what is served, where the blocks sit."""
    blocks = ", ".join(f"{g} {hand.layout.block_address(g)}" for g in hm.PUBLIC_BLOCK_BYTES)
    return (
        f"a hand of {hm.N_TAXELS} taxels in {len(hm.REGIONS)} regions (device id {hand.device_id}); "
        f"layout {hand.layout.kind}, base offset {hand.layout.base_offset}: blocks at registers {blocks}; "
        f"control {hm.CONTROL_FIRST}..{hm.CONTROL_LAST}; "
        f"scenario {hand.scenario.name}, speed {hand.speed:g}; map hand"
    )
