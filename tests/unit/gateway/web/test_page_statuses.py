"""The page knows every channel status: its code table matches ``ChannelStatus``, the legend
lists each status it draws apart (and disabled channels), and an extrapolated channel is
drawn with its force."""

from __future__ import annotations

import re
from pathlib import Path

from gateway.runtime.snapshot import VALUED_STATUSES, ChannelStatus

STATIC = Path(__file__).resolve().parents[4] / "gateway" / "web" / "static"


def test_the_page_s_status_codes_are_the_gateway_s() -> None:
    js = (STATIC / "app.js").read_text(encoding="utf-8")
    table = re.search(r"const ST = \{([^}]*)\};", js)
    assert table is not None
    codes = {k.strip(): int(v) for k, v in (item.split(":") for item in table.group(1).split(","))}
    assert codes == {s.name: int(s) for s in ChannelStatus}
    valued = re.search(r"const VALUED = new Set\(\[([^\]]*)\]\);", js)
    assert valued is not None
    assert {v.strip().removeprefix("ST.") for v in valued.group(1).split(",")} == {
        s.name for s in VALUED_STATUSES
    }


def test_the_legend_lists_every_status_but_ok_with_a_swatch() -> None:
    html = (STATIC / "index.html").read_text(encoding="utf-8")
    css = (STATIC / "style.css").read_text(encoding="utf-8")
    swatches = re.findall(r'<span class="sw sw-([a-z]+)"></span>', html)
    # every status, then a channel that is no status at all: off in the configuration
    statuses = ["nocontact", "saturated", "extrapolated", "nozero", "open", "short", "stale", "error"]
    assert swatches == [*statuses, "disabled"]
    for name in swatches:
        assert f".sw-{name} {{" in css, name
    assert "extrapolated (outside the calibrated range)" in html
