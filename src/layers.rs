//! The crate's layering, checked: ARCHITECTURE.md's *Layers* list (read from the file
//! itself, so the document cannot drift from the code) against every `crate::` and
//! `super::` path in `src/`. A module may use its own layer and those below, never one
//! above, and no two modules may import each other, directly or around a loop.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each module of `src/` (as `a::b`) and the text of its file up to its tests.
fn modules(src: &Path) -> BTreeMap<String, String> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let p = entry.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(src, &mut files);
    let mut out = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(src).unwrap().with_extension("");
        let mut parts: Vec<String> = rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        if parts.last().is_some_and(|p| p == "mod") {
            parts.pop();
        }
        if parts == ["lib"] || parts == ["main"] || parts == ["layers"] {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        let text = match text.find("#[cfg(test)]") {
            Some(i) => text[..i].to_owned(),
            None => text,
        };
        let code: String = text
            .lines()
            .map(|l| l.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        out.insert(parts.join("::"), code);
    }
    out
}

/// The longest module named by a path's leading segments.
fn resolve<'a>(modules: &'a BTreeMap<String, String>, segments: &[&str]) -> Option<&'a str> {
    (1..=segments.len())
        .rev()
        .find_map(|n| modules.get_key_value(&segments[..n].join("::")))
        .map(|(k, _)| k.as_str())
}

/// Module → the modules it uses (not its own children or parents).
fn imports(modules: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let mut edges = BTreeMap::new();
    for (m, code) in modules {
        let mut used = BTreeSet::new();
        for (kind, start) in [("crate", "crate::"), ("super", "super::")] {
            for (i, _) in code.match_indices(start) {
                if i > 0 {
                    let before = code.as_bytes()[i - 1];
                    if before.is_ascii_alphanumeric() || before == b'_' || before == b':' {
                        continue;
                    }
                }
                let rest = &code[i + start.len()..];
                let path: Vec<&str> = rest
                    .split(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                    .next()
                    .unwrap_or("")
                    .split("::")
                    .filter(|s| !s.is_empty())
                    .collect();
                let full: Vec<&str> = if kind == "crate" {
                    path
                } else {
                    let mut parent: Vec<&str> = m.split("::").collect();
                    parent.pop();
                    parent.extend(path);
                    parent
                };
                if let Some(t) = resolve(modules, &full)
                    && t != m
                    && !t.starts_with(&format!("{m}::"))
                    && !m.starts_with(&format!("{t}::"))
                {
                    used.insert(t.to_owned());
                }
            }
        }
        edges.insert(m.clone(), used);
    }
    edges
}

/// ARCHITECTURE.md's layers, bottom first: the backquoted module names of each
/// numbered line under the `## Layers` heading.
fn layers(architecture: &str) -> Vec<Vec<String>> {
    let section = architecture
        .split("\n## ")
        .find(|s| s.starts_with("Layers"))
        .expect("ARCHITECTURE.md has a `## Layers` section");
    section
        .lines()
        .filter(|l| {
            l.split_once(". ")
                .is_some_and(|(n, _)| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()))
        })
        .map(|l| l.split('`').skip(1).step_by(2).map(str::to_owned).collect())
        .collect()
}

fn layer_of(layers: &[Vec<String>], module: &str) -> Option<usize> {
    // The most specific name listed: `simulate::demo` over `simulate`.
    let mut best: Option<(usize, usize)> = None;
    for (i, names) in layers.iter().enumerate() {
        for n in names {
            if (module == n || module.starts_with(&format!("{n}::")))
                && best.is_none_or(|(len, _)| n.len() > len)
            {
                best = Some((n.len(), i));
            }
        }
    }
    best.map(|(_, i)| i)
}

/// The modules on a cycle of imports, each cycle once.
fn cycles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    // Reachability is enough at this size: a and b are on one cycle when each reaches
    // the other.
    let reach = |from: &str| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.to_owned()];
        while let Some(v) = stack.pop() {
            for w in edges.get(&v).into_iter().flatten() {
                if seen.insert(w.clone()) {
                    stack.push(w.clone());
                }
            }
        }
        seen
    };
    let reaches: BTreeMap<&String, BTreeSet<String>> =
        edges.keys().map(|k| (k, reach(k))).collect();
    let mut out: Vec<Vec<String>> = Vec::new();
    for (m, r) in &reaches {
        if !r.contains(*m) || out.iter().any(|c| c.contains(m)) {
            continue;
        }
        let comp: Vec<String> = reaches
            .iter()
            .filter(|(o, ro)| r.contains(**o) && ro.contains(*m))
            .map(|(o, _)| (*o).clone())
            .collect();
        out.push(comp);
    }
    out
}

#[test]
fn no_module_imports_a_layer_above_it_or_itself_round_a_loop() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let modules = modules(&root.join("src"));
    let edges = imports(&modules);
    let layers = layers(&std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap());
    assert!(layers.len() >= 5, "ARCHITECTURE.md lists too few layers");
    let mut wrong = Vec::new();
    for (m, used) in &edges {
        let Some(lm) = layer_of(&layers, m) else {
            wrong.push(format!("{m}: in no layer of ARCHITECTURE.md"));
            continue;
        };
        for t in used {
            if let Some(lt) = layer_of(&layers, t)
                && lt > lm
            {
                wrong.push(format!(
                    "{m} (layer {}) uses {t} (layer {})",
                    lm + 1,
                    lt + 1
                ));
            }
        }
    }
    for c in cycles(&edges) {
        wrong.push(format!("cycle: {}", c.join(" <-> ")));
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn the_check_finds_what_it_looks_for() {
    // The checker itself, on a made-up crate: an upward import and a loop are found.
    let mut m = BTreeMap::new();
    m.insert("low".to_owned(), "use crate::high::X;".to_owned());
    m.insert("high".to_owned(), "fn f() { crate::low::y(); }".to_owned());
    m.insert(
        "high::part".to_owned(),
        "use super::Thing; use crate::low;".to_owned(),
    );
    let edges = imports(&m);
    assert_eq!(edges["low"], BTreeSet::from(["high".to_owned()]));
    assert_eq!(edges["high::part"], BTreeSet::from(["low".to_owned()]));
    assert_eq!(
        cycles(&edges),
        vec![vec!["high".to_owned(), "low".to_owned()]]
    );
    let l = layers("x\n## Layers\n\n1. `low`\n2. `high`, `high::part`\n\n## Next\n3. `no`");
    assert_eq!(l.len(), 2);
    assert_eq!(layer_of(&l, "high::part::deep"), Some(1));
    assert_eq!(layer_of(&l, "low"), Some(0));
    assert_eq!(layer_of(&l, "nowhere"), None);
}
