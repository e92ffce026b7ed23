"""The documentation stays walkable: generated env pages up to date, a short README, no dead links."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
INDEX = ROOT / "docs" / "index.md"

# [text](target) and ![alt](target); the target ends at whitespace or ")"
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def relative_links(path: Path) -> list[str]:
    """The relative link targets of a Markdown file, code blocks and inline code left out."""
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`\n]*`", "", text)
    targets = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue  # http:, https:, mailto:, or an anchor of the same page
        targets.append(target)
    return targets


def test_env_pages_up_to_date():
    result = subprocess.run([sys.executable, "docs/make_env_pages.py", "--check"], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, (
        "docs/envs is stale; run `python docs/make_env_pages.py`:\n" + result.stdout + result.stderr)


def test_readme_short_with_an_early_gym_make():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines (at most 150)"
    first = next((i for i, line in enumerate(lines, 1) if "gym.make(" in line), None)
    assert first is not None, "README.md has no gym.make( example"
    assert first <= 60, f"README.md's first gym.make( is on line {first} (at most 60)"


@pytest.mark.parametrize("page", [README, INDEX], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_exist(page):
    links = relative_links(page)
    assert links, f"{page.name} has no relative links"
    missing = [t for t in links if not (page.parent / t.split("#", 1)[0]).exists()]
    assert not missing, f"{page.relative_to(ROOT)} links to missing files: {missing}"
