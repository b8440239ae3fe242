"""Check every internal link of a built HTML site: the file exists and, for ``page.html#id``, the id.

``python docs/check_links.py docs/_build/html`` prints each broken link with the page it is on and
exits 1 if there is any. External links (``http:``, ``https:``, ``mailto:``) are not followed: the
build runs without a network. A script or a stylesheet loaded from the network (MathJax from a CDN,
say) is reported too: the site must read the same offline, its maths rendered.
"""

from __future__ import annotations

import os
import sys
from html.parser import HTMLParser
from urllib.parse import unquote, urldefrag, urlparse


class _Page(HTMLParser):
    """The ids and the link targets (``href`` of ``a``/``link``, ``src`` of ``img``/``script``) of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.remote_assets: list[str] = []  # scripts and stylesheets a reader's browser would fetch

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for key in ("id", "name"):
            if a.get(key):
                self.ids.add(a[key])
        target = a.get("href") if tag in ("a", "link") else a.get("src") if tag in ("img", "script") else None
        if target:
            self.links.append(target)
        asset = (
            a.get("src")
            if tag == "script"
            else a.get("href")
            if tag == "link" and a.get("rel") == "stylesheet"
            else None
        )
        if asset and (urlparse(asset).scheme in ("http", "https") or asset.startswith("//")):
            self.remote_assets.append(asset)


def _parse(path: str) -> _Page:
    page = _Page()
    with open(path, encoding="utf-8") as f:
        page.feed(f.read())
    return page


def broken_links(root: str) -> list[str]:
    """``"page: link"`` for every internal link under ``root`` whose file or fragment is missing, and for
    every script or stylesheet a page loads from the network."""
    pages: dict[str, _Page] = {}
    for folder, _, files in os.walk(root):
        for name in files:
            if name.endswith(".html"):
                path = os.path.normpath(os.path.join(folder, name))
                pages[path] = _parse(path)
    bad = []
    for path, page in sorted(pages.items()):
        bad += [f"{os.path.relpath(path, root)}: {url} (loaded from the network)" for url in page.remote_assets]
        for link in page.links:
            if urlparse(link).scheme or link.startswith("//"):
                continue  # external
            target, fragment = urldefrag(link)
            target = urlparse(target).path  # drop a query such as ?v=1a2b
            target_path = os.path.normpath(os.path.join(os.path.dirname(path), unquote(target))) if target else path
            if os.path.isdir(target_path):
                target_path = os.path.join(target_path, "index.html")
            if not os.path.exists(target_path):
                bad.append(f"{os.path.relpath(path, root)}: {link} (no such file)")
            elif fragment and target_path.endswith(".html"):
                ids = pages[target_path].ids if target_path in pages else _parse(target_path).ids
                if unquote(fragment) not in ids:
                    bad.append(f"{os.path.relpath(path, root)}: {link} (no id {fragment!r} there)")
    return bad


def main(argv: list[str]) -> int:
    root = argv[0] if argv else os.path.join(os.path.dirname(os.path.abspath(__file__)), "_build", "html")
    bad = broken_links(root)
    for line in bad:
        print(line)
    print(f"{len(bad)} broken internal link(s) or remote asset(s) under {root}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
