"""Vendor-defined read functions: the wire format of a frame read with a non-public function code.

Many tactile products serve their whole frame through a function code of their own (a
60-point skin reads its frame with function 0x42: start point and point count, then a
byte count and two bytes per point). ``VendorRead`` describes such a read by a handful of
field widths, so a configuration can name it, and turns it into bytes and back. Pure
(stdlib only): the pymodbus backend (``client``) wraps it in a PDU class, the virtual bus
(``virtual``) serves it from memory.

Layout (all fields big-endian)::

    request:   function code | start (0, 1 or 2 bytes) | count (0, 1 or 2 bytes)
    answer:    function code | byte count (1 or 2 bytes) | data (byte count bytes)
    exception: function code | 0x80, exception code (1 byte)

The data are read as big-endian 16-bit words. ``count`` in the methods below always counts
16-bit words (the registers the caller wants); the count field of the request carries it in
``count_unit`` (words or bytes).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from ..errors import ConfigError, DecodeError, GatewayError

#: Function codes the Modbus application protocol (V1.1b3) assigns publicly: a vendor read
#: may not use them (1-8, 11, 12, 15-17, 20-24, 43).
PUBLIC_FUNCTION_CODES: frozenset[int] = frozenset(
    {1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 15, 16, 17, 20, 21, 22, 23, 24, 43}
)
#: The ranges the protocol leaves to users (vendors).
USER_DEFINED_RANGES: tuple[tuple[int, int], ...] = ((65, 72), (100, 110))
#: Largest Modbus PDU (function code included), bytes: 256-byte RTU ADU less address and CRC.
MAX_PDU_BYTES = 253
COUNT_UNITS: tuple[str, ...] = ("registers", "bytes")


@dataclass(frozen=True)
class VendorRead:
    """A vendor-defined read: request = function code, then a start field and a count field
    (big-endian, each 0, 1 or 2 bytes wide); answer = function code, a byte-count field (1 or 2
    bytes, big-endian), then that many data bytes, read as big-endian 16-bit words. An
    exception answer is function_code | 0x80 followed by one exception-code byte."""

    #: 1..127, not a public code (user-defined 65-72 and 100-110 are the intended ones)
    function_code: int
    #: width of the start field of the request, bytes: 0 (no field), 1 or 2
    address_bytes: int = 2
    #: width of the count field of the request, bytes: 0 (the device fixes the size), 1 or 2
    count_bytes: int = 2
    #: what the count field counts: "registers" (16-bit words) or "bytes"
    count_unit: str = "registers"
    #: width of the byte-count field of the answer, bytes: 1 or 2
    byte_count_bytes: int = 1

    def __post_init__(self) -> None:
        fc = self.function_code
        if isinstance(fc, bool) or not isinstance(fc, int) or not 1 <= fc <= 127:
            raise ConfigError(
                f"function_code = {fc!r} must be an integer in 1..127 (user-defined: 65-72 or 100-110)"
            )
        if fc in PUBLIC_FUNCTION_CODES:
            public = ", ".join(str(c) for c in sorted(PUBLIC_FUNCTION_CODES))
            raise ConfigError(
                f"function_code = {fc} (0x{fc:02X}) is a public Modbus function ({public}); a vendor "
                "read needs a user-defined code (65-72 = 0x41-0x48 or 100-110 = 0x64-0x6E) or another "
                "code in 1..127 that the protocol does not assign"
            )
        for name, allowed in (
            ("address_bytes", (0, 1, 2)),
            ("count_bytes", (0, 1, 2)),
            ("byte_count_bytes", (1, 2)),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or value not in allowed:
                raise ConfigError(f"{name} = {value!r} must be one of {', '.join(str(a) for a in allowed)}")
        if self.count_unit not in COUNT_UNITS:
            raise ConfigError(f"count_unit = {self.count_unit!r} must be one of {', '.join(COUNT_UNITS)}")

    # ------------------------------------------------------------------ limits
    @property
    def max_count(self) -> int:
        """Most 16-bit words one read may ask for: what the byte-count field can state (127
        words for 1 byte, 32767 for 2), the count field can carry, and a Modbus PDU
        (253 bytes, function code and byte count included) can hold: 125 words for the
        field widths above; a 1-byte count field in bytes allows 127."""
        words = (256**self.byte_count_bytes - 1) // 2
        words = min(words, (MAX_PDU_BYTES - 1 - self.byte_count_bytes) // 2)
        if self.count_bytes:
            field_max = 256**self.count_bytes - 1
            words = min(words, field_max if self.count_unit == "registers" else field_max // 2)
        return words

    # ------------------------------------------------------------------ request
    def request_data(self, address: int, count: int) -> bytes:
        """The request bytes after the function code for ``count`` words from ``address``.

        ``GatewayError`` if ``address`` does not fit the start field (a
        read without a start field must start at 0) or ``count`` is outside 1..``max_count``.
        """
        if not 1 <= count <= self.max_count:
            raise GatewayError(
                f"count {count} outside 1..{self.max_count} words for function 0x{self.function_code:02X}"
            )
        if self.address_bytes == 0:
            if address != 0:
                raise GatewayError(
                    f"function 0x{self.function_code:02X} has no start field: "
                    f"address must be 0, got {address}"
                )
        elif not 0 <= address < 256**self.address_bytes:
            raise GatewayError(
                f"address {address} does not fit the {self.address_bytes}-byte start field "
                f"(0..{256**self.address_bytes - 1})"
            )
        out = address.to_bytes(self.address_bytes, "big") if self.address_bytes else b""
        if self.count_bytes:
            value = count if self.count_unit == "registers" else 2 * count
            out += value.to_bytes(self.count_bytes, "big")
        return out

    # ------------------------------------------------------------------ answer
    def registers(self, data: bytes, count: int) -> list[int]:
        """The words of an answer (``data``: the bytes after the function code).

        ``DecodeError`` if the byte-count field is missing, disagrees with the number of data
        bytes that follow it, or with ``2 * count``.
        """
        head = self.byte_count_bytes
        if len(data) < head:
            raise DecodeError(f"answer of {len(data)} bytes has no {head}-byte byte count")
        stated = int.from_bytes(data[:head], "big")
        payload = data[head:]
        if stated != len(payload):
            raise DecodeError(f"byte count {stated} but {len(payload)} data bytes follow")
        if stated != 2 * count:
            raise DecodeError(f"byte count {stated}, expected {2 * count} for {count} words")
        return list(struct.unpack_from(f">{count}H", payload))

    def response_size(self, head: bytes) -> int | None:
        """Length of the whole answer after the function code (byte count + data, bytes),
        given its first bytes ``head``; None while the byte-count field is incomplete."""
        if len(head) < self.byte_count_bytes:
            return None
        return self.byte_count_bytes + int.from_bytes(head[: self.byte_count_bytes], "big")

    def response_data(self, words: list[int]) -> bytes:
        """The answer bytes after the function code for ``words`` (for simulated devices)."""
        data = b"".join(int(w).to_bytes(2, "big") for w in words)
        return len(data).to_bytes(self.byte_count_bytes, "big") + data

    def parse_request(self, data: bytes) -> tuple[int, int | None]:
        """(address, count in words or None when the request has no count field) of request
        bytes after the function code (for simulated devices); ``DecodeError`` if malformed."""
        need = self.address_bytes + self.count_bytes
        if len(data) != need:
            raise DecodeError(f"request of {len(data)} bytes, expected {need}")
        address = int.from_bytes(data[: self.address_bytes], "big") if self.address_bytes else 0
        if not self.count_bytes:
            return address, None
        value = int.from_bytes(data[self.address_bytes :], "big")
        if self.count_unit == "bytes":
            if value % 2:
                raise DecodeError(f"odd byte count {value} in the request")
            value //= 2
        return address, value
