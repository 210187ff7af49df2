"""Copy the benchmark tables from ``scripts/results/*.md`` into README.md.

README.md marks each generated block with ``<!-- results:NAME -->`` … ``<!-- /results:NAME -->``;
NAME is a results file (``scripts/results/NAME.md``) optionally followed by ``#K`` to take only
its K-th table (1-based). The block is replaced by the table(s) verbatim, so the README always
shows what the benchmarks last printed. Run after any benchmark: ``python scripts/update_readme.py``
(``--check`` exits 1 if the README is stale, for CI or a pre-commit hook).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "scripts" / "results"
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


def render_block(name: str, k: str | None) -> str:
    path = RESULTS / f"{name}.md"
    if not path.is_file():
        raise SystemExit(f"update_readme: {path} does not exist (run its benchmark first)")
    found = tables(path.read_text())
    if not found:
        raise SystemExit(f"update_readme: {path} has no Markdown table")
    chosen = found if k is None else [found[int(k) - 1]]
    return "\n\n".join(chosen) + "\n"


def update(text: str) -> str:
    def replace(match: re.Match[str]) -> str:
        return match.group(1) + render_block(match.group("name"), match.group("k")) + match.group(5)

    return BLOCK.sub(replace, text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if README.md is stale")
    args = parser.parse_args()
    readme = ROOT / "README.md"
    old = readme.read_text()
    new = update(old)
    if args.check:
        if new != old:
            print("README.md results tables are stale: run python scripts/update_readme.py")
            return 1
        print("README.md results tables are up to date")
        return 0
    readme.write_text(new)
    print(f"updated {readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
