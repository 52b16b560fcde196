"""The "hand" map (``docs/register-map-hand.md``): our simulator's register map of a dexterous
robot hand with a 1,062-taxel skin, written from public facts of its community drivers.

Taxels: 17 sub-grids in six blocks. Each of four fingers (little, ring, middle, index) is a
block of a tip 3x3, a nail 12x8 and a pad 10x8 (185 taxels); the thumb a tip 3x3, a nail
12x8, a middle 3x3 and a pad 12x8 (210); the palm 14x8 (112). The public documents give
each block's start in BYTES (3000, 3370, 3740, 4110, 4480; the palm 4900), two bytes per
taxel. The simulator serves them under one of two readings (``Layout``):

- ``"byte"`` (the default): the public numbers are byte addresses; a block starts at
  register ``byte / 2`` and holds one register per taxel (the blocks are contiguous);
- ``"register"``: the public numbers are register addresses; one register per taxel, the
  registers between blocks are not mapped (exception 2).

``base_offset`` shifts every taxel block by that many registers (the control registers stay
where they are). The finger order (little first) and the sub-grid order inside a block (tip,
nail, [middle,] pad, each row-major from its first row) are our choice: the public facts do
not state them.

Control and status (holding registers, fixed, ``CONTROL_FIRST .. CONTROL_LAST``): six joints
(``JOINTS``) with angle and force set points (writable), actual values, a status code and
error bits each; register 1009 calibrates the finger force sensors (a write is accepted and
leaves the taxels alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

MAP_NAME: Final = "hand"
#: Byte addresses of the blocks in the public documents.
PUBLIC_BLOCK_BYTES: Final = {
    "little": 3000,
    "ring": 3370,
    "middle": 3740,
    "index": 4110,
    "thumb": 4480,
    "palm": 4900,
}
FINGERS: Final = ("little", "ring", "middle", "index")
LAYOUTS: Final = ("byte", "register")


@dataclass(frozen=True)
class Region:
    """One sub-grid: ``name`` ("index-tip", "palm"), its block (``group``), rows x columns, and
    its first taxel's index inside the block."""

    name: str
    group: str
    rows: int
    columns: int
    offset_in_block: int

    @property
    def size(self) -> int:
        return self.rows * self.columns


def _block(group: str, parts: tuple[tuple[str, int, int], ...]) -> list[Region]:
    out: list[Region] = []
    at = 0
    for part, rows, columns in parts:
        name = group if part == "" else f"{group}-{part}"
        out.append(Region(name, group, rows, columns, at))
        at += rows * columns
    return out


_FINGER_PARTS = (("tip", 3, 3), ("nail", 12, 8), ("pad", 10, 8))
_THUMB_PARTS = (("tip", 3, 3), ("nail", 12, 8), ("middle", 3, 3), ("pad", 12, 8))

#: The 17 regions in block order.
REGIONS: Final[tuple[Region, ...]] = tuple(
    [r for f in FINGERS for r in _block(f, _FINGER_PARTS)]
    + _block("thumb", _THUMB_PARTS)
    + _block("palm", (("", 14, 8),))
)
REGION_NAMES: Final = tuple(r.name for r in REGIONS)
N_TAXELS: Final = sum(r.size for r in REGIONS)

#: The raw value of a saturated taxel (0xFF00 and above are never a pressure).
SATURATION_CODE: Final = 0xFFFF
SPECIAL_FROM: Final = 0xFF00

# ---------------------------------------------------------------- control registers
#: Joints of the set points, actual values, status codes and error bits (one register each).
JOINTS: Final = ("little", "ring", "middle", "index", "thumb-bend", "thumb-rotate")
N_JOINTS: Final = len(JOINTS)
CONTROL_FIRST: Final = 1000
HR_ANGLE_SET: Final = 1000  # 1000..1005, per mille of the joint's travel (0 open, 1000 closed)
HR_RESERVED: Final = 1006  # 1006..1008 read 0, read-only
HR_FORCE_CALIBRATE: Final = 1009  # write any value: calibrate the finger force sensors
HR_FORCE_SET: Final = 1010  # 1010..1015, centinewtons (0: no force limit)
HR_ANGLE_ACTUAL: Final = 1016  # 1016..1021
HR_FORCE_ACTUAL: Final = 1022  # 1022..1027, centinewtons
HR_STATUS: Final = 1028  # 1028..1033, STATUS_CODES
HR_ERRORS: Final = 1034  # 1034..1039, ERROR_BITS
CONTROL_LAST: Final = 1039
ANGLE_MAX: Final = 1000
FORCE_SET_MAX_CN: Final = 3000

STATUS_CODES: Final = {0: "idle", 1: "grasping", 2: "force reached", 3: "stall", 4: "fault"}
ERROR_BITS: Final = {0: "stall", 1: "over-temperature", 2: "over-current", 3: "motor", 4: "communication"}


class LayoutError(ValueError):
    """A layout that cannot be served (unknown kind, or blocks outside 0..65535 or on the
    control registers)."""


@dataclass(frozen=True)
class Layout:
    """Where the taxel blocks sit: ``kind`` "byte" or "register" (see the module docstring)
    and ``base_offset`` registers added to every block."""

    kind: str = "byte"
    base_offset: int = 0

    def __post_init__(self) -> None:
        if self.kind not in LAYOUTS:
            raise LayoutError(f"layout {self.kind!r} must be one of {', '.join(LAYOUTS)}")
        for region in REGIONS:
            first = self.region_address(region)
            last = first + region.size - 1
            if first < 0 or last > 0xFFFF:
                raise LayoutError(
                    f"base offset {self.base_offset}: {region.name} would sit at registers "
                    f"{first}..{last}, outside 0..65535"
                )
            if first <= CONTROL_LAST and last >= CONTROL_FIRST:
                raise LayoutError(
                    f"base offset {self.base_offset}: {region.name} (registers {first}..{last}) "
                    f"overlaps the control registers {CONTROL_FIRST}..{CONTROL_LAST}"
                )

    def block_address(self, group: str) -> int:
        """The register of the block's first taxel."""
        public = PUBLIC_BLOCK_BYTES[group]
        return (public // 2 if self.kind == "byte" else public) + self.base_offset

    def region_address(self, region: Region) -> int:
        """The register of the region's first taxel."""
        return self.block_address(region.group) + region.offset_in_block

    def addresses(self) -> dict[str, int]:
        """Each region's first register, by name."""
        return {r.name: self.region_address(r) for r in REGIONS}


def region(name: str) -> Region:
    """The region called ``name``; ``KeyError`` naming the valid ones if there is none."""
    for r in REGIONS:
        if r.name == name:
            return r
    raise KeyError(f"no region {name!r} (regions: {', '.join(REGION_NAMES)})")
