"""Issue 42's layering, checked by ``scripts/check_layers.py``: no import cycle among the Python package's modules
(function-local imports included); in the Rust core, the layers optics < ensemble < space < render import only
downwards, the crate-level helpers (error, rng, cancel, simd, ...) none of them, and no file imports itself through
others. The checker itself is tested on small made-up trees (a cycle hidden in a function, folders with and without
``mod.rs``, unit-test modules, paths in comments and strings, re-exports)."""

from __future__ import annotations

import importlib.util
import pathlib
import subprocess
import sys
import textwrap


ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "check_layers.py"


def _load():
    spec = importlib.util.spec_from_file_location("check_layers", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


L = _load()

def _tree(root: pathlib.Path, files: dict[str, str]) -> pathlib.Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return root


def test_python_package_has_no_import_cycle():
    failures, summary = L.check_python()
    assert failures == [], "\n".join(failures)
    assert "modules" in summary


def test_rust_core_layers_point_down_and_have_no_cycles():
    failures, _ = L.check_rust()
    assert failures == [], "\n".join(failures)


def test_rust_rooms_stay_within_their_sizes():
    """No Rust file over 1,000 lines of code before its unit tests or 1,500 in all; no binding file over 450."""
    failures, summary = L.check_sizes()
    assert failures == [], "\n".join(failures)
    assert "largest" in summary


def test_sizes_are_counted_before_the_tests(tmp_path):
    code = "fn f() {}\n" * 1200
    big = _tree(tmp_path, {"rust/a/src/big.rs": code, "rust/a/src/ok.rs": "fn f() {}\n#[cfg(test)]\nmod tests {}\n" + code,
                           "rust/a/src/x/tests.rs": code, "rust/motes-py/src/b.rs": "fn f() {}\n" * 451})
    failures, _ = L.check_sizes(big)
    assert len(failures) == 2 and "big.rs has 1200 lines" in failures[0] and "binding file" in failures[1], failures


def test_the_script_runs_and_names_what_it_checked():
    res = subprocess.run([sys.executable, str(SCRIPT), "--python-only"], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "no cycles" in res.stdout and "mitsuba_plugin/motes" in res.stdout


def test_python_cycles_through_function_local_imports_are_found(tmp_path):
    pkg = _tree(tmp_path / "pkg", {
        "__init__.py": "from . import a\n",
        "a.py": "import os\n\ndef f():\n    from .b import g\n    return g\n",
        "b.py": "from . import a\n\ndef g():\n    return a\n",
        "c.py": "from .sub import d\nfrom .sub.d import h\nimport pkg.a\n",
        "sub/__init__.py": "",
        "sub/d.py": "from .. import c\n\ndef h():\n    pass\n",
    })
    graph = L.python_graph(pkg)
    assert graph["pkg.a"] == {"pkg.b"} and graph["pkg.b"] == {"pkg.a"}
    assert graph["pkg.c"] == {"pkg.sub.d", "pkg.a"} and graph["pkg.sub.d"] == {"pkg.c"}
    failures, _ = L.check_python(pkg)
    assert sorted(failures) == ["Python import cycle: pkg.a -> pkg.b -> pkg.a",
                                "Python import cycle: pkg.c -> pkg.sub.d -> pkg.c"]


_RUST = {
    "lib.rs": """
        pub mod error;
        pub mod simd;
        pub mod optics;
        pub mod space;
        pub mod render;
        pub use error::Err;

        #[cfg(test)]
        pub(crate) mod test_rng {
            use crate::render::discrete::d;
        }
        """,
    "error.rs": "pub struct Err;\n",
    "simd.rs": "use crate::error::Err;\npub fn lanes() -> Option<Err> { None }\n",
    "optics/mod.rs": "pub mod mie;\npub use mie::*;\n",
    "optics/mie.rs": """
        use crate::Err;
        /// See [`crate::render::discrete`] and `super::super::render`.
        pub fn mie() -> Option<Err> {
            let _s = "crate::render::discrete::d";
            let _c = '"';
            /* crate::space::grid::cells() /* nested */ crate::render::discrete::d() */
            None
        }
        pub fn life<'a>(x: &'a str) -> &'a str { x }

        #[cfg(test)]
        mod tests {
            use crate::render::discrete::d;
        }
        """,
    "space/mod.rs": "pub mod grid;\n",
    "space/grid/mod.rs": "mod walk;\npub use walk::Walk;\npub fn cells() {}\n",
    "space/grid/walk.rs": "pub struct Walk;\nimpl Walk {\n    pub fn go(&self) -> Option<crate::Err> {\n        None\n    }\n}\n",
    "render/mod.rs": "pub mod discrete;\n",
    "render/discrete.rs": """
        mod flight;
        #[cfg(test)]
        mod tests;
        use crate::{optics::{self, mie}, space::grid::{self as g, Walk}};
        pub fn d() {
            flight::go();
            crate::optics::mie();
        }
        """,
    "render/discrete/flight.rs": "use crate::space::grid::Walk;\npub fn go() {}\n",
    "render/discrete/tests.rs": "use crate::render::discrete::flight;\nuse super::d;\nuse crate::render::discrete::d as e;\n",
}


def test_rust_edges_of_files_folders_re_exports_and_tests(tmp_path):
    src = _tree(tmp_path / "src", _RUST)
    graph, _ = L.rust_graph(src)
    assert graph == {
        "lib.rs": {"error.rs"},
        "error.rs": set(),
        "simd.rs": {"error.rs"},
        "optics/mod.rs": {"optics/mie.rs"},
        "optics/mie.rs": {"error.rs"},
        "space/mod.rs": set(),
        "space/grid/mod.rs": {"space/grid/walk.rs"},
        "space/grid/walk.rs": {"error.rs"},
        "render/mod.rs": set(),
        "render/discrete.rs": {"optics/mod.rs", "optics/mie.rs", "space/grid/mod.rs", "space/grid/walk.rs",
                               "render/discrete/flight.rs"},
        "render/discrete/flight.rs": {"space/grid/walk.rs"},
    }
    assert L.check_rust(src)[0] == []


def test_rust_layering_and_cycles_are_named(tmp_path):
    files = dict(_RUST)
    files["simd.rs"] += "use crate::optics::mie;\n"
    files["optics/mie.rs"] += "pub fn up() { crate::space::grid::cells(); }\n"
    # A file may use its own folder's module (a folder is one module): no cycle. Two sibling files that
    # use each other are one.
    files["render/discrete/flight.rs"] += "pub fn back() { super::d(); super::phase::p(); }\n"
    files["render/discrete.rs"] = files["render/discrete.rs"].replace("mod flight;", "mod flight;\nmod phase;")
    files["render/discrete/phase.rs"] = "pub fn p() { super::flight::go(); }\n"
    src = _tree(tmp_path / "src", files)
    failures, _ = L.check_rust(src)
    assert sorted(failures) == sorted([
        "Rust layering: simd.rs -> optics/mie.rs (crate-level helper imports the layer optics)",
        "Rust layering: optics/mie.rs -> space/grid/mod.rs (optics imports the higher layer space)",
        "Rust import cycle: render/discrete/flight.rs -> render/discrete/phase.rs -> render/discrete/flight.rs",
    ])
