"""How long the site's pages read: the words of each built page's article, as a reader sees
them (text of the rendered HTML, code blocks and tables included, navigation left out).

    make docs && python -m research.studies.site_length          # build/site, every page
    python -m research.studies.site_length --json-out site_length.json

Targets (the site's pages should be read, not waded through): results <= 2,500 words, the env
card <= 1,800, models <= 2,500.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path
from typing import Annotated

from tendon2r_gym.app.args import arg, parse

#: Page (its path under the site) -> the most words it should hold.
TARGETS = {"results/index.html": 2500, "env/index.html": 1800, "models/index.html": 2500}
#: What a word is: a run of letters or digits, with inner apostrophes, dots or dashes.
WORD = re.compile(r"[A-Za-z0-9]+(?:['.\-/][A-Za-z0-9]+)*")


class _Article(HTMLParser):
    """Collects the text inside a page's ``<article>`` (Material's content)."""

    def __init__(self) -> None:
        super().__init__()
        self.depth = 0
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list) -> None:
        if tag == "article" or self.depth:
            self.depth += 1 if tag not in ("br", "img", "hr", "input", "meta", "link") else 0

    def handle_endtag(self, tag: str) -> None:
        if self.depth and tag not in ("br", "img", "hr", "input", "meta", "link"):
            self.depth -= 1

    def handle_data(self, data: str) -> None:
        if self.depth:
            self.text.append(data)


def words(html: str) -> int:
    """Returns the number of words in a built page's article."""
    parser = _Article()
    parser.feed(html)
    return len(WORD.findall(" ".join(parser.text)))


def measure(site: Path) -> dict[str, int]:
    """Returns the words of every built page under ``site``, by its path."""
    if not site.is_dir():
        raise ValueError(f"--site {str(site)!r} is invalid; allowed: a built site (make docs)")
    return {
        p.relative_to(site).as_posix(): words(p.read_text())
        for p in sorted(site.rglob("index.html"))
        if "assets" not in p.parts
    }


@dataclass
class Args:
    """How long the site's pages read (module docstring)."""

    site: Annotated[str, arg("the built site (mkdocs build --site-dir)")] = "build/site"
    json_out: Annotated[str | None, arg("also write the counts to this JSON file")] = None


def main(argv: list[str] | None = None) -> dict[str, int]:
    args = parse(Args, argv, __doc__)
    counts = measure(Path(args.site))
    for page, n in counts.items():
        target = TARGETS.get(page)
        mark = (
            ""
            if target is None
            else f"  (target <= {target}: {'met' if n <= target else 'MISSED'})"
        )
        print(f"{n:6d}  {page}{mark}")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(counts, indent=1) + "\n")
    return counts


if __name__ == "__main__":
    main()
