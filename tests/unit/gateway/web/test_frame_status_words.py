"""The page's frame carries the device's status words: each bit set or clear, error bits and
error codes flagged (hand-built readings)."""

from __future__ import annotations

import json
from dataclasses import replace

from web_snapshots import device

from gateway.modbus.register_map import RegisterKind
from gateway.modbus.status_word import StatusWord
from gateway.web.frames import encode_frame


def test_a_frame_lists_the_status_words_with_their_bits() -> None:
    errors = StatusWord("thumb-errors", RegisterKind.HOLDING, 10, bits=((4, "ready"),),
                        errors=((0, "stall"), (1, "over-temperature")))  # fmt: skip
    state = StatusWord("thumb-state", RegisterKind.HOLDING, 11, codes=((0, "idle"), (2, "force reached")))
    snap = replace(device(), status_words=(errors.read(0b10010), state.read(2)))
    data = json.loads(encode_frame(snap, 1, None))
    words = {w["name"]: w for w in data["device_status"]}
    # 0b10010: bit 1 (over-temperature, an error) and bit 4 (ready) set, bit 0 (stall) clear
    assert words["thumb-errors"] == {
        "name": "thumb-errors", "value": 18, "code": None, "error": True,
        "bits": [{"bit": 0, "label": "stall", "on": False, "error": True},
                 {"bit": 1, "label": "over-temperature", "on": True, "error": True},
                 {"bit": 4, "label": "ready", "on": True, "error": False}],
    }  # fmt: skip
    assert words["thumb-state"]["code"] == "force reached" and words["thumb-state"]["error"] is False


def test_a_device_without_status_words_has_none_in_its_frame() -> None:
    assert "device_status" not in json.loads(encode_frame(device(), 1, None))
