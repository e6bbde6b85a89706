"""Issue 42's layering: the imports of the Python package and of the Rust core, checked for cycles and for
a lower layer reaching up.

    python3 scripts/check_layers.py [--python-only | --rust-only] [--edges] [--sizes]

``--sizes`` also checks the rooms' sizes: no Rust file over 1,000 lines of code before its unit tests or
1,500 in all, no binding file (``rust/motes-py``) over 450.

Python (``mitsuba_plugin/motes``): every ``import`` / ``from ... import`` of a module of the package, at
the top of a module or inside a function alike (``ast``), is an edge; ``from . import x`` is an edge to the
submodule ``x`` where there is one, else to the package (``__init__``). Importing a submodule is not
counted as an edge to its parent package. A cycle among the package's modules fails the check.

Rust (``rust/motes-core/src``): a module is a file (a folder's ``mod.rs`` and the files beside it are
separate modules). The modules are found from ``lib.rs`` by their ``mod x;`` declarations; ``#[cfg(test)]``
items (unit-test modules, inline or in a file of their own) are left out, and so are comments and string
literals. Edges are the ``use`` trees and the paths in the code that start with ``crate::``, ``super::``,
``self::`` or a child module's name, resolved to the file that defines the item (following ``pub use``
re-exports, globs included). The check fails on

* a cycle between files (a file's use of its own folder's ``mod.rs`` excepted: a folder is one module,
  whose files hold the methods of the types its ``mod.rs`` defines);
* a layer importing a higher one: ``optics < ensemble < space < render``;
* a crate-level helper module (``error``, ``rng``, ``cancel``, ``simd``, ``quadrature``, ...: any other
  top-level module but ``lib.rs``) importing any of the four layers.

Each failure names the edge(s). Exits 1 on any failure, else prints a short summary.
"""

from __future__ import annotations

import argparse
import ast
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
PY_PACKAGE = ROOT / "mitsuba_plugin" / "motes"
RUST_SRC = ROOT / "rust" / "motes-core" / "src"
#: The Rust core's layers, lowest first.
LAYERS = ("optics", "ensemble", "space", "render")


# ---------------------------------------------------------------------------------------------- graphs

def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Cycles that between them pass through every node of every strongly connected component with more than
    one node (or a self-loop), each as the list of its nodes with the first repeated at the end (Tarjan's
    algorithm, then shortest cycles by breadth-first search). Empty: the graph has no cycle."""
    index, low, on_stack, stack, comps = {}, {}, set(), [], []
    counter = [0]

    def strongconnect(v: str) -> None:  # iterative: deep graphs must not hit the recursion limit
        work = [(v, iter(sorted(graph.get(v, ()))))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    comps.append(sorted(comp))
            elif child not in index:
                index[child] = low[child] = counter[0]
                counter[0] += 1
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph.get(child, ())))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    cycles = []
    for comp in sorted(comps):
        members = set(comp)
        if len(comp) == 1 and comp[0] not in graph.get(comp[0], ()):
            continue
        covered: set[str] = set()
        for start in comp:  # a shortest cycle through each node no cycle listed so far passes through
            if start not in covered:
                cycle = _shortest_cycle(graph, start, members)
                covered.update(cycle)
                cycles.append(cycle)
    return cycles


def _shortest_cycle(graph: dict[str, set[str]], start: str, members: set[str]) -> list[str]:
    parent, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph.get(v, ())):
                if w == start:
                    path = [v]
                    while parent[path[-1]] is not None:
                        path.append(parent[path[-1]])
                    return list(reversed(path)) + [start]
                if w in members and w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    return [start, start]


def edge_count(graph: dict[str, set[str]]) -> int:
    return sum(len(v) for v in graph.values())


def _shown(path: pathlib.Path) -> str:
    try:
        return path.resolve().relative_to(ROOT).as_posix()
    except ValueError:
        return str(path)


# ---------------------------------------------------------------------------------------------- Python

def python_modules(package: pathlib.Path = PY_PACKAGE) -> dict[str, pathlib.Path]:
    """Dotted name -> file of every module of the package (``motes``, ``motes.plugins.cameras``, ...), and the
    compiled extension modules (no file to parse: None)."""
    name = package.name
    modules: dict[str, pathlib.Path] = {}
    for path in sorted(package.rglob("*")):
        rel = path.relative_to(package)
        if path.suffix == ".py":
            parts = rel.with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join((name, *parts))] = path
        elif path.suffix in (".so", ".pyd") or path.name.endswith(".pyi"):
            stem = path.name.split(".")[0]
            modules.setdefault(".".join((name, *rel.parent.parts, stem)), None)
    return modules


def _resolve_python(module: str, is_package: bool, node: ast.AST, modules) -> set[str]:
    """The package's modules that one import statement of ``module`` names."""
    def known(name: str) -> str | None:  # the module itself, or the nearest enclosing one of the package
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    out = set()
    if isinstance(node, ast.Import):
        for alias in node.names:
            target = known(alias.name)
            if target:
                out.add(target)
        return out
    if node.level:
        base = module if is_package else module.rpartition(".")[0]
        for _ in range(node.level - 1):
            base = base.rpartition(".")[0]
        source = f"{base}.{node.module}" if node.module else base
    else:
        source = node.module or ""
    if known(source) is None:
        return out
    for alias in node.names:
        sub = f"{source}.{alias.name}"
        out.add(sub if sub in modules else known(source))
    return out


def python_graph(package: pathlib.Path = PY_PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports (anywhere in its body)."""
    modules = python_modules(package)
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for module, path in modules.items():
        if path is None:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                graph[module] |= _resolve_python(module, path.name == "__init__.py", node, modules)
        graph[module].discard(module)
    return graph


def check_python(package: pathlib.Path = PY_PACKAGE) -> tuple[list[str], str]:
    graph = python_graph(package)
    failures = ["Python import cycle: " + " -> ".join(c) for c in find_cycles(graph)]
    summary = f"Python {_shown(package)}: {len(graph)} modules, {edge_count(graph)} edges"
    return failures, summary


# ---------------------------------------------------------------------------------------------- Rust

_TEST_CFG = re.compile(r"#\[cfg\((?:test|all\(test\b[^\]]*)\)\]")
_ATTR = re.compile(r"\s*#!?\[[^\]]*\]")
_ITEM_DEF = r"\b(?:fn|struct|enum|union|trait|type|const|static|macro_rules!)\s+{}\b"
_USE = re.compile(r"(?<![\w:])(pub(?:\([^)]*\))?\s+)?use\s+([^;]+);")
_MOD_DECL = re.compile(r"(?<![\w:])(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;")
_PATH = re.compile(r"(?<![\w:])(crate|super|self)((?:\s*::\s*\w+)+)")


def strip_rust(text: str) -> str:
    """The source with comments and the contents of string and char literals blanked (newlines kept), so
    that paths in docs and strings are not taken for imports and braces match."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif (m := re.match(r'b?r(#*)"', text[i:i + 260])) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            end = text.find('"' + m.group(1), i + m.end())
            j = n if end < 0 else end + 1 + len(m.group(1))
            out.append('""' + re.sub(r"[^\n]", " ", text[i + 2:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('"' + re.sub(r"[^\n]", " ", text[i + 1:j]) + '"')
            i = j + 1
        elif c == "'" and (m := re.match(r"'(\\(?:u\{[0-9a-fA-F]+\}|x[0-9a-fA-F]{2}|.)|[^\\'])'", text[i:i + 12])):
            out.append("' '" + " " * (m.end() - 3))  # a char literal; a lifetime ('a) is left alone
            i += m.end()
        else:
            out.append(c)
            i += 1
    return "".join(out)


def _item_end(text: str, start: int) -> int:
    """End of the item that starts at ``start``: its ``;`` or its closing brace, whichever comes first."""
    depth, i = 0, start
    while i < len(text):
        if text[i] == "{":
            depth += 1
        elif text[i] == "}":
            depth -= 1
            if depth == 0:
                return i + 1
        elif text[i] == ";" and depth == 0:
            return i + 1
        i += 1
    return len(text)


def drop_test_items(text: str) -> tuple[str, set[str]]:
    """The (stripped) source without its ``#[cfg(test)]`` items, and the names of the modules declared under
    ``#[cfg(test)]`` (``mod tests;``: files that are tests)."""
    test_mods = set()
    while m := _TEST_CFG.search(text):
        start = m.end()
        while a := _ATTR.match(text, start):
            start = a.end()
        end = _item_end(text, start)
        if d := _MOD_DECL.match(text[start:end].strip() + ""):
            test_mods.add(d.group(1))
        text = text[:m.start()] + re.sub(r"[^\n]", " ", text[m.start():end]) + text[end:]
    return text, test_mods


def _split_top(s: str) -> list[str]:
    parts, depth, cur = [], 0, []
    for c in s:
        if c == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        depth += (c == "{") - (c == "}")
        cur.append(c)
    parts.append("".join(cur))
    return [p.strip() for p in parts if p.strip()]


def expand_use(tree: str, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], str | None]]:
    """(path, name it binds) for each leaf of a ``use`` tree; ``*`` binds None, ``self`` its module's name."""
    tree = re.sub(r"\s+", " ", tree).strip()
    brace = tree.find("{")
    if brace >= 0 and tree.endswith("}"):
        head = tuple(s.strip() for s in tree[:brace].split("::") if s.strip())
        out = []
        for part in _split_top(tree[brace + 1:-1]):
            out += expand_use(part, prefix + head)
        return out
    alias = None
    if " as " in tree:
        tree, alias = (s.strip() for s in tree.split(" as ", 1))
    segs = tuple(s.strip() for s in tree.split("::") if s.strip())
    if segs == ("self",):
        return [(prefix, alias or (prefix[-1] if prefix else None))]
    path = prefix + segs
    return [(path, None if segs[-1] == "*" else alias or segs[-1])]


class RustModule:
    def __init__(self, path: tuple[str, ...], file: pathlib.Path, src: pathlib.Path):
        self.path, self.file = path, file
        self.name = file.relative_to(src).as_posix()
        self.text, test_mods = drop_test_items(strip_rust(file.read_text()))
        self.children = {m for m in _MOD_DECL.findall(self.text) if m not in test_mods}
        self.uses = [(bool(pub), expand_use(tree)) for pub, tree in _USE.findall(self.text)]

    def child_dir(self, src: pathlib.Path) -> pathlib.Path:
        if self.file.name in ("mod.rs", "lib.rs", "main.rs"):
            return self.file.parent
        return self.file.with_suffix("")

    def defines(self, name: str) -> bool:
        return re.search(_ITEM_DEF.format(re.escape(name)), self.text) is not None


def rust_modules(src: pathlib.Path = RUST_SRC) -> dict[tuple[str, ...], RustModule]:
    """Module path (``()`` for the crate root) -> module, found from ``lib.rs`` by its declarations."""
    modules, todo = {}, [((), src / "lib.rs")]
    while todo:
        path, file = todo.pop()
        mod = modules[path] = RustModule(path, file, src)
        base = mod.child_dir(src)
        for child in sorted(mod.children):
            for candidate in (base / f"{child}.rs", base / child / "mod.rs"):
                if candidate.is_file():
                    todo.append((path + (child,), candidate))
                    break
    return modules


class RustResolver:
    def __init__(self, modules: dict[tuple[str, ...], RustModule]):
        self.modules = modules

    def item(self, module: tuple[str, ...], name: str, depth: int = 0) -> tuple[str, ...]:
        """The module that defines ``name`` as seen from ``module`` (following its ``use`` re-exports)."""
        mod = self.modules[module]
        if name in mod.children:
            return module + (name,)
        if depth > 8 or mod.defines(name):
            return module
        for _, leaves in mod.uses:
            for path, bound in leaves:
                if bound == name:
                    return self.path(module, path, depth + 1) or module
        for _, leaves in mod.uses:
            for path, bound in leaves:
                if bound is None and path and path[-1] == "*":
                    target = self.path(module, path[:-1], depth + 1)
                    if target is not None and target != module:
                        found = self.item(target, name, depth + 1)
                        if found != target or self.modules[target].defines(name):
                            return found
        return module

    def path(self, module: tuple[str, ...], segs: tuple[str, ...], depth: int = 0) -> tuple[str, ...] | None:
        """The file-module a path names from ``module`` (None: outside the crate)."""
        if not segs:
            return None
        head, rest = segs[0], list(segs[1:])
        if head == "crate":
            cur = ()
        elif head == "self":
            cur = module
        elif head == "super":
            cur = module[:-1]
            while rest and rest[0] == "super":
                cur, rest = cur[:-1], rest[1:]
        elif head in self.modules[module].children:
            cur, rest = module + (head,), rest
        else:
            return None  # another crate (std, rayon, ...) or a local name
        for seg in rest:
            if seg in ("*", "self"):
                break
            nxt = self.item(cur, seg, depth)
            if nxt == cur:
                break
            child, cur = nxt == cur + (seg,), nxt
            if not child:  # an item re-exported from elsewhere: the walk ends at its module
                break
        return cur


def rust_graph(src: pathlib.Path = RUST_SRC) -> tuple[dict[str, set[str]], dict[tuple[str, ...], RustModule]]:
    modules = rust_modules(src)
    resolver = RustResolver(modules)
    graph: dict[str, set[str]] = {m.name: set() for m in modules.values()}
    for key, mod in modules.items():
        targets = set()
        for _, leaves in mod.uses:
            for path, _ in leaves:
                targets.add(resolver.path(key, path))
        body = _USE.sub(" ", mod.text)
        for m in _PATH.finditer(body):
            targets.add(resolver.path(key, (m.group(1), *re.findall(r"\w+", m.group(2)))))
        for child in mod.children:  # paths through a child module: `goa::f()`
            for m in re.finditer(rf"(?<![\w:]){child}((?:\s*::\s*\w+)+)", body):
                targets.add(resolver.path(key, (child, *re.findall(r"\w+", m.group(1)))))
        graph[mod.name] = {modules[t].name for t in targets if t is not None and t != key}
    return graph, modules


def layer_of(path: tuple[str, ...]) -> str:
    """A module's layer (one of LAYERS), "root" for lib.rs, or "helper" for the crate-level modules."""
    if not path:
        return "root"
    return path[0] if path[0] in LAYERS else "helper"


def check_rust(src: pathlib.Path = RUST_SRC) -> tuple[list[str], str]:
    graph, modules = rust_graph(src)
    by_name = {m.name: key for key, m in modules.items()}
    failures = []
    for a in sorted(graph):
        la = layer_of(by_name[a])
        for b in sorted(graph[a]):
            lb = layer_of(by_name[b])
            if la in LAYERS and lb in LAYERS and LAYERS.index(la) < LAYERS.index(lb):
                failures.append(f"Rust layering: {a} -> {b} ({la} imports the higher layer {lb})")
            elif la == "helper" and lb in LAYERS:
                failures.append(f"Rust layering: {a} -> {b} (crate-level helper imports the layer {lb})")
    # A folder is one module to the rest of the crate: its files may use what its mod.rs defines (the
    # type whose methods they hold), so an edge from a file to its own folder's mod.rs closes no cycle.
    # Cycles among sibling files, and across folders, still fail.
    acyclic = {a: {b for b in bs if by_name[b] != by_name[a][:-1]} for a, bs in graph.items()}
    failures += ["Rust import cycle: " + " -> ".join(c) for c in find_cycles(acyclic)]
    summary = f"Rust {_shown(src)}: {len(graph)} modules, {edge_count(graph)} edges"
    return failures, summary


# --------------------------------------------------------------------------------------------- sizes

#: Issue 42's room sizes: lines of code before a Rust file's unit tests, lines in all, and lines of a
#: binding file.
MAX_CODE_LINES, MAX_FILE_LINES, MAX_BINDING_LINES = 1000, 1500, 450


def code_lines(path: pathlib.Path) -> tuple[int, int]:
    """(lines before the file's first ``#[cfg(test)]`` item, 0 for a ``tests.rs``; lines in all)."""
    lines = path.read_text().splitlines()
    if path.name == "tests.rs":
        return 0, len(lines)
    end = next((i for i, ln in enumerate(lines) if ln.startswith("#[cfg(test)]")), len(lines))
    return end, len(lines)


def check_sizes(root: pathlib.Path = ROOT) -> tuple[list[str], str]:
    """Every Rust source file of the workspace within the limits above; the largest ones in the summary."""
    failures, sizes = [], []
    for path in sorted((root / "rust").rglob("*.rs")):
        code, total = code_lines(path)
        rel = _shown(path)
        sizes.append((code, total, rel))
        if code > MAX_CODE_LINES or total > MAX_FILE_LINES:
            failures.append(f"size: {rel} has {code} lines of code before its tests and {total} in all "
                            f"(at most {MAX_CODE_LINES} / {MAX_FILE_LINES})")
        if "motes-py" in path.parts and total > MAX_BINDING_LINES:
            failures.append(f"size: binding file {rel} has {total} lines (at most {MAX_BINDING_LINES})")
    top = ", ".join(f"{rel} {c}/{t}" for c, t, rel in sorted(sizes, reverse=True)[:3])
    return failures, f"Rust files: {len(sizes)}, largest (code before tests / all): {top}"


# ---------------------------------------------------------------------------------------------- main

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--python-only", action="store_true", help="check the Python package alone")
    which.add_argument("--rust-only", action="store_true", help="check the Rust core alone")
    ap.add_argument("--edges", action="store_true", help="print every edge too")
    ap.add_argument("--sizes", action="store_true", help="also check the Rust files' sizes (issue 42's limits)")
    args = ap.parse_args(argv)
    checks = []
    if args.sizes:
        checks.append((check_sizes, lambda: {}))
    if not args.rust_only:
        checks.append((check_python, python_graph))
    if not args.python_only:
        checks.append((check_rust, lambda: rust_graph()[0]))
    failed = False
    for check, graph in checks:
        failures, summary = check()
        if args.edges:
            for a, targets in sorted(graph().items()):
                for b in sorted(targets):
                    print(f"  {a} -> {b}")
        if failures:
            failed = True
            print(f"FAIL {summary}")
            for f in failures:
                print(f"  {f}")
        else:
            tail = {check_python: ", no cycles", check_rust: ", no cycles, layers in order"}.get(check, ", within limits")
            print(f"ok   {summary}{tail}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
