//! Embeds `MOTES_CORE_HASH`: an FNV-1a 64 hash of every file under `rust/motes-core/src` and
//! `rust/motes-py/src` (in the order of their paths relative to `rust/`, each as path, 0, length as
//! u64 little-endian, content), so that caches of computed physics (`motes.ensemble`'s disk cache) are
//! keyed by the code that computed them. `tests/test_ensemble.py` recomputes it from the sources.

use std::fs;
use std::path::{Path, PathBuf};

fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            files_under(&p, out);
        } else if p.is_file() {
            out.push(p);
        }
    }
}

fn fnv1a(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let rust = manifest.parent().expect("rust/").to_path_buf();
    let mut files = Vec::new();
    for dir in [rust.join("motes-core").join("src"), manifest.join("src")] {
        println!("cargo:rerun-if-changed={}", dir.display());
        files_under(&dir, &mut files);
    }
    let mut named: Vec<(String, PathBuf)> = files
        .into_iter()
        .map(|f| {
            let rel = f
                .strip_prefix(&rust)
                .expect("under rust/")
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join("/");
            (rel, f)
        })
        .collect();
    named.sort();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for (rel, f) in &named {
        println!("cargo:rerun-if-changed={}", f.display());
        let content = fs::read(f).expect("readable source");
        h = fnv1a(h, rel.as_bytes());
        h = fnv1a(h, &[0]);
        h = fnv1a(h, &(content.len() as u64).to_le_bytes());
        h = fnv1a(h, &content);
    }
    println!("cargo:rustc-env=MOTES_CORE_HASH={h:016x}");
}
