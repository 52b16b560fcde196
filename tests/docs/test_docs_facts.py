"""Facts the docs state that the code can check: lists that must name everything shipped."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_profiles_table_names_every_shipped_profile() -> None:
    shipped = {p.stem for p in (REPO / "gateway" / "config" / "profiles").glob("*.toml")}
    text = (REPO / "docs" / "profiles.md").read_text(encoding="utf-8")
    section = text.split("## Shipped profiles", 1)[1].split("\n## ", 1)[0]
    rows = set(re.findall(r"^\| `([\w.-]+)` \|", section, re.MULTILINE))
    assert shipped, "no shipped profile found"
    assert rows == shipped, (
        f"missing from the table: {sorted(shipped - rows)}; not shipped: {sorted(rows - shipped)}"
    )


def test_web_doc_lists_every_status_label_with_its_code_range() -> None:
    from gateway.runtime.snapshot import STATUS_LABELS

    text = " ".join((REPO / "docs" / "web.md").read_text(encoding="utf-8").split())
    m = re.search(r"label is `status_labels\[code\]` \(((?:`\w+`, )+`\w+`): codes 0 to (\d+);", text)
    assert m is not None, "docs/web.md no longer lists the status labels"
    assert re.findall(r"`(\w+)`", m[1]) == list(STATUS_LABELS)
    assert int(m[2]) == len(STATUS_LABELS) - 1


def test_web_doc_playwright_snippet_needs_no_eval() -> None:
    """The page's Content-Security-Policy has no 'unsafe-eval': a string predicate may be refused."""
    text = (REPO / "docs" / "web.md").read_text(encoding="utf-8")
    snippets = re.findall(r"^```python\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    playwright = [s for s in snippets if "playwright" in s]
    assert playwright, "docs/web.md no longer shows the Playwright snippet"
    for snippet in playwright:
        assert "wait_for_function(" not in snippet and "evaluate(" not in snippet
        assert "#state" in snippet
