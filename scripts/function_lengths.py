"""Issue 12's "no function over ~80 lines outside tables and tests": the longest functions of the Rust
crates, the C++ plugin and the Python package, tests left out (Rust `#[cfg(test)]` modules, `tests/`).

    .venv/bin/python scripts/function_lengths.py [--top N] [--limit 80]

A function runs from its `fn`/`def` line to the closing brace at its own indentation (Rust, C++) or to
the last line indented deeper than it (Python); blank lines and comments count. Exits 1 when one is
longer than `--limit`.
"""

from __future__ import annotations

import argparse
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
RUST_FN = re.compile(r"^(\s*)(pub(\([a-z]+\))? )?(const )?(unsafe )?(extern \"C\" )?fn (\w+)")
PY_FN = re.compile(r"^(\s*)(async )?def (\w+)")


def rust_functions(path: pathlib.Path):
    lines = path.read_text().splitlines()
    # Unit tests live in a `#[cfg(test)] mod tests` at the end of a file, or in a module folder's
    # `tests.rs` (all of it).
    end = 0 if path.name == "tests.rs" else next(
        (i for i, ln in enumerate(lines) if ln.startswith("#[cfg(test)]")), len(lines))
    for i, ln in enumerate(lines[:end]):
        m = RUST_FN.match(ln)
        if m and not ln.rstrip().endswith(";"):
            close = m.group(1) + "}"
            j = next((j for j in range(i + 1, end) if lines[j] == close), None)
            if j is not None:
                yield m.group(7), i + 1, j - i + 1


def cpp_functions(path: pathlib.Path):
    lines = path.read_text().splitlines()
    for i, ln in enumerate(lines):
        if ln.rstrip().endswith("{") and "(" in ln and not ln.lstrip().startswith(("if", "for", "while", "switch", "//")):
            indent = len(ln) - len(ln.lstrip())
            close = " " * indent + "}"
            j = next((j for j in range(i + 1, len(lines)) if lines[j].startswith(close) and
                      len(lines[j]) - len(lines[j].lstrip()) == indent), None)
            if j is not None:
                yield ln.strip().split("(")[0].split()[-1], i + 1, j - i + 1


def python_functions(path: pathlib.Path):
    lines = path.read_text().splitlines()
    for i, ln in enumerate(lines):
        m = PY_FN.match(ln)
        if m:
            indent = len(m.group(1))
            j = i + 1
            last = i
            while j < len(lines):
                s = lines[j]
                if s.strip() and len(s) - len(s.lstrip()) <= indent:
                    break
                if s.strip():
                    last = j
                j += 1
            yield m.group(3), i + 1, last - i + 1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--top", type=int, default=8)
    ap.add_argument("--limit", type=int, default=80)
    args = ap.parse_args()
    rows = []
    for p in sorted((ROOT / "rust").rglob("*.rs")):
        rows += [(n, str(p.relative_to(ROOT)), name, line) for name, line, n in rust_functions(p)]
    for p in sorted((ROOT / "mitsuba_plugin").rglob("*.cpp")):
        rows += [(n, str(p.relative_to(ROOT)), name, line) for name, line, n in cpp_functions(p)]
    for folder in ("mitsuba_plugin", "scripts"):
        for p in sorted((ROOT / folder).rglob("*.py")):
            rows += [(n, str(p.relative_to(ROOT)), name, line) for name, line, n in python_functions(p)]
    rows.sort(reverse=True)
    for n, path, name, line in rows[: args.top]:
        print(f"{n:4d} lines  {path}:{line}  {name}")
    over = [r for r in rows if r[0] > args.limit]
    print(f"{len(rows)} functions; longest {rows[0][0]} lines; over {args.limit}: {len(over)}")
    sys.exit(1 if over else 0)


if __name__ == "__main__":
    main()
