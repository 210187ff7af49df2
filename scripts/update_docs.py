"""Copy the benchmark tables from ``scripts/results/*.md`` into ``docs/results.md``.

``docs/results.md`` marks each generated block with ``<!-- results:NAME -->`` …
``<!-- /results:NAME -->``; NAME is a results file (``scripts/results/NAME.md``) optionally
followed by ``#K`` to take only its K-th table (1-based). The block is replaced by the table(s)
verbatim, so the page always shows what the benchmarks last wrote. The block named ``index``
lists every results file with its title. Run after any benchmark:
``python scripts/update_docs.py`` (``--check`` exits 1 if the page is stale, for CI or a
pre-commit hook). The README's status table is written by hand; ``tests/test_readme.py``
checks its numbers against the same files.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "scripts" / "results"
PAGE = ROOT / "docs" / "results.md"
BLOCK = re.compile(
    r"(<!-- results:(?P<name>[\w.-]+)(?:#(?P<k>\d+))? -->\n)(.*?)"
    r"(<!-- /results:(?P=name)(?:#\d+)? -->)",
    re.S,
)


def tables(markdown: str) -> list[str]:
    """The Markdown tables of a document, each as its lines joined."""
    out: list[list[str]] = []
    current: list[str] = []
    for line in markdown.splitlines():
        if line.lstrip().startswith("|"):
            current.append(line)
        elif current:
            out.append(current)
            current = []
    if current:
        out.append(current)
    return ["\n".join(t) for t in out]


def _title(path: Path) -> str:
    """A results file's first heading, or its name where it has none."""
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return path.stem


def render_index() -> str:
    """One line per results file: a link from ``docs/`` and the file's title."""
    lines = [f"- [`{p.name}`](../scripts/results/{p.name}): {_title(p)}"
             for p in sorted(RESULTS.glob("*.md"))]
    return "\n".join(lines) + "\n"


def render_block(name: str, k: str | None) -> str:
    if name == "index":
        return render_index()
    path = RESULTS / f"{name}.md"
    if not path.is_file():
        raise SystemExit(f"update_docs: {path} does not exist (run its benchmark first)")
    found = tables(path.read_text())
    if not found:
        raise SystemExit(f"update_docs: {path} has no Markdown table")
    chosen = found if k is None else [found[int(k) - 1]]
    return "\n\n".join(chosen) + "\n"


def update(text: str) -> str:
    """``text`` with every generated block replaced by what the results files hold now."""
    def replace(match: re.Match[str]) -> str:
        return match.group(1) + render_block(match.group("name"), match.group("k")) + match.group(5)

    return BLOCK.sub(replace, text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/results.md is stale")
    args = parser.parse_args()
    old = PAGE.read_text()
    new = update(old)
    if args.check:
        if new != old:
            print("docs/results.md is stale: run python scripts/update_docs.py")
            return 1
        print("docs/results.md is up to date")
        return 0
    PAGE.write_text(new)
    print(f"updated {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
