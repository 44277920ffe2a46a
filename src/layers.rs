//! The crate's layering, checked: ARCHITECTURE.md's *Layers* table (read from the file
//! itself, so the document cannot drift from the code) against every `use` and every
//! `crate::`, `super::` and `self::` path in `src/`. A module may use its own layer and
//! those below, never one above, and no two modules may import each other, directly or
//! around a loop.
//!
//! A name is followed to the module that defines it: `use super::Frame` in
//! `correction::tca`, where `correction` only re-exports `lensfun::Frame`, is a use of
//! `correction::lensfun`. Without that, every loop that runs through a parent's
//! re-exports (or a private `use` in the parent, which its children see too) would be
//! invisible, since a module's use of its own parent is not counted.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each module of `src/` (as `a::b`) and its code up to its tests (see [`code_only`]).
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
        out.insert(parts.join("::"), code_only(&text));
    }
    out
}

/// Rust source without its comments and with every string and character literal
/// emptied, so that neither a `use` in a doc comment nor a `::` in a message is read as
/// a path.
fn code_only(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let at = |i: usize, s: &str| {
        s.chars()
            .enumerate()
            .all(|(k, ch)| c.get(i + k) == Some(&ch))
    };
    while i < c.len() {
        let after_ident = i > 0 && is_ident(c[i - 1]);
        if at(i, "//") {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if at(i, "/*") {
            let mut depth = 0;
            while i < c.len() {
                if at(i, "/*") {
                    depth += 1;
                    i += 2;
                } else if at(i, "*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            out.push(' ');
        } else if !after_ident && (at(i, "r\"") || at(i, "r#") || at(i, "br\"") || at(i, "br#")) {
            // A raw string: r"…", r#"…"#, …
            i += if c[i] == 'b' { 2 } else { 1 };
            let hashes = c[i..].iter().take_while(|&&ch| ch == '#').count();
            i += hashes + 1;
            let close: String = std::iter::once('"')
                .chain(std::iter::repeat_n('#', hashes))
                .collect();
            while i < c.len() && !at(i, &close) {
                i += 1;
            }
            i += close.chars().count();
            out.push_str("\"\"");
        } else if c[i] == '"' {
            i += 1;
            while i < c.len() && c[i] != '"' {
                i += if c[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if c[i] == '\'' && c.get(i + 1) == Some(&'\\') {
            // An escaped character literal: '\'', '\n', '\u{…}'.
            i += 3;
            while i < c.len() && c[i] != '\'' {
                i += 1;
            }
            i += 1;
            out.push_str("' '");
        } else if c[i] == '\'' && c.get(i + 2) == Some(&'\'') {
            i += 3;
            out.push_str("' '");
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Where a word starts a token: not inside an identifier or after a `::`.
fn starts_token(code: &str, i: usize) -> bool {
    i == 0 || {
        let before = code.as_bytes()[i - 1];
        !(before.is_ascii_alphanumeric() || before == b'_' || before == b':')
    }
}

/// One name a `use` binds: the path it names (as written), the name it binds (the
/// last segment or its `as` alias), or a glob.
#[derive(Clone, Debug, PartialEq)]
struct UseItem {
    path: Vec<String>,
    /// `None` for a glob (`use a::*`).
    binds: Option<String>,
}

/// Every `use` declaration of a module's code, its trees flattened.
fn use_items(code: &str) -> Vec<UseItem> {
    let mut out = Vec::new();
    for (i, _) in code.match_indices("use ") {
        if !starts_token(code, i) {
            continue;
        }
        let Some(end) = code[i..].find(';') else {
            continue;
        };
        let tree: String = code[i + 4..i + end]
            .chars()
            .map(|c| if c.is_whitespace() { ' ' } else { c })
            .collect();
        flatten_tree(&tree, &[], &mut out);
    }
    out
}

/// `a::{b, c::d as e, f::*}` under `prefix`, into `out`.
fn flatten_tree(tree: &str, prefix: &[String], out: &mut Vec<UseItem>) {
    let tree = tree.trim().trim_start_matches("::");
    if let Some(open) = tree.find('{') {
        let head: Vec<String> = tree[..open]
            .split("::")
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(str::to_owned)
            .collect();
        let close = tree.rfind('}').unwrap_or(tree.len());
        let mut base = prefix.to_vec();
        base.extend(head);
        // Split the group at its top-level commas.
        let inner = &tree[open + 1..close];
        let (mut depth, mut from) = (0, 0);
        for (j, c) in inner.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    flatten_tree(&inner[from..j], &base, out);
                    from = j + 1;
                }
                _ => {}
            }
        }
        flatten_tree(&inner[from..], &base, out);
        return;
    }
    let (path, alias) = match tree.split_once(" as ") {
        Some((p, a)) => (p.trim(), Some(a.trim().to_owned())),
        None => (tree, None),
    };
    if path.is_empty() {
        return;
    }
    let mut full = prefix.to_vec();
    full.extend(path.split("::").map(|s| s.trim().to_owned()));
    if full.last().is_some_and(|s| s == "*") {
        full.pop();
        out.push(UseItem {
            path: full,
            binds: None,
        });
    } else if full.last().is_some_and(|s| s == "self") {
        full.pop();
        let binds = alias.or_else(|| full.last().cloned());
        out.push(UseItem { path: full, binds });
    } else {
        let binds = alias.or_else(|| full.last().cloned());
        out.push(UseItem { path: full, binds });
    }
}

/// Every path written inline with `crate::`, `super::` or `self::`, as written.
fn inline_paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for start in ["crate::", "super::", "self::"] {
        for (i, _) in code.match_indices(start) {
            if !starts_token(code, i) {
                continue;
            }
            let path: Vec<String> = code[i..]
                .split(|c: char| !(is_ident(c) || c == ':'))
                .next()
                .unwrap_or("")
                .split("::")
                .filter(|s| !s.is_empty())
                .map(str::to_owned)
                .collect();
            out.push(path);
        }
    }
    out
}

/// The crate's modules with what each binds, so a path can be followed to the module
/// that defines the item it names.
struct Crate<'a> {
    modules: &'a BTreeMap<String, String>,
    uses: BTreeMap<&'a str, Vec<UseItem>>,
}

impl<'a> Crate<'a> {
    fn new(modules: &'a BTreeMap<String, String>) -> Self {
        let uses = modules
            .iter()
            .map(|(m, code)| (m.as_str(), use_items(code)))
            .collect();
        Self { modules, uses }
    }

    /// A path as written in module `m`, made absolute (segments from the crate root);
    /// `None` for a path into another crate.
    fn absolute(&self, m: &str, path: &[String]) -> Option<Vec<String>> {
        let mut here: Vec<String> = m.split("::").map(str::to_owned).collect();
        let mut rest = path;
        match rest.first().map(String::as_str) {
            Some("crate") => {
                here.clear();
                rest = &rest[1..];
            }
            Some("self") => rest = &rest[1..],
            Some("super") => {
                while rest.first().is_some_and(|s| s == "super") {
                    here.pop();
                    rest = &rest[1..];
                }
            }
            // Edition 2018 and later: a plain path starts at a child module, or it
            // names another crate.
            Some(first) => {
                let child = format!("{m}::{first}");
                if !self.modules.contains_key(&child) {
                    return None;
                }
            }
            None => return None,
        }
        here.extend(rest.iter().cloned());
        Some(here)
    }

    /// The longest module named by a path's leading segments, and the segments after it.
    fn split<'p>(&self, segments: &'p [String]) -> Option<(&'a str, &'p [String])> {
        (1..=segments.len()).rev().find_map(|n| {
            self.modules
                .get_key_value(&segments[..n].join("::"))
                .map(|(k, _)| (k.as_str(), &segments[n..]))
        })
    }

    /// Whether module `m` itself defines an item called `name`.
    fn defines(&self, m: &str, name: &str) -> bool {
        let code = &self.modules[m];
        [
            "fn",
            "struct",
            "enum",
            "trait",
            "type",
            "const",
            "static",
            "union",
            "macro_rules!",
        ]
        .iter()
        .any(|kw| {
            let needle = format!("{kw} {name}");
            code.match_indices(&needle).any(|(i, _)| {
                starts_token(code, i) && !code[i + needle.len()..].starts_with(is_ident)
            })
        })
    }

    /// The module that defines what `m::name` names, following `use` bindings and
    /// glob re-exports; `m` itself where it is not found elsewhere.
    fn defining(&self, m: &'a str, name: &str, depth: usize) -> &'a str {
        if depth > 16 || self.defines(m, name) {
            return m;
        }
        let items = &self.uses[m];
        if let Some(item) = items.iter().find(|u| u.binds.as_deref() == Some(name)) {
            return match self.absolute(m, &item.path) {
                Some(abs) => self.target(&abs, depth + 1).unwrap_or(m),
                None => m,
            };
        }
        for glob in items.iter().filter(|u| u.binds.is_none()) {
            if let Some(g) = self.absolute(m, &glob.path).and_then(|abs| {
                self.split(&abs)
                    .filter(|(_, r)| r.is_empty())
                    .map(|(g, _)| g)
            }) && g != m
                && (self.defines(g, name)
                    || self.uses[g]
                        .iter()
                        .any(|u| u.binds.as_deref() == Some(name)))
            {
                return self.defining(g, name, depth + 1);
            }
        }
        m
    }

    /// The module an absolute path lands in: the module it names, or the one that
    /// defines the item it names.
    fn target(&self, abs: &[String], depth: usize) -> Option<&'a str> {
        let (module, rest) = self.split(abs)?;
        Some(match rest.first() {
            Some(name) => self.defining(module, name, depth),
            None => module,
        })
    }
}

/// Module → the modules it uses (not its own children or parents).
fn imports(modules: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let krate = Crate::new(modules);
    let mut edges = BTreeMap::new();
    for (m, code) in modules {
        let related = |t: &str| {
            t == m || t.starts_with(&format!("{m}::")) || m.starts_with(&format!("{t}::"))
        };
        let mut used = BTreeSet::new();
        let written = krate.uses[m.as_str()]
            .iter()
            .map(|u| u.path.clone())
            .chain(inline_paths(code));
        for path in written {
            let Some(abs) = krate.absolute(m, &path) else {
                continue;
            };
            // The module the path names, and the one that defines the item: a use
            // through a re-export depends on both.
            let named = krate.split(&abs).map(|(t, _)| t);
            let defining = krate.target(&abs, 0);
            for t in [named, defining].into_iter().flatten() {
                if !related(t) {
                    used.insert(t.to_owned());
                }
            }
        }
        edges.insert(m.clone(), used);
    }
    edges
}

/// ARCHITECTURE.md's layers, bottom first: the backquoted module names in the second
/// cell of each table row under the `## Layers` heading whose first cell is a number (the
/// third cell, which says what the layer is for, may quote names too).
fn layers(architecture: &str) -> Vec<Vec<String>> {
    let section = architecture
        .split("\n## ")
        .find(|s| s.starts_with("Layers"))
        .expect("ARCHITECTURE.md has a `## Layers` section");
    section
        .lines()
        .filter_map(|l| {
            let mut cells = l.strip_prefix('|')?.split('|').map(str::trim);
            let n = cells.next()?;
            if n.is_empty() || !n.chars().all(|c| c.is_ascii_digit()) {
                return None;
            }
            let names = cells.next()?;
            Some(
                names
                    .split('`')
                    .skip(1)
                    .step_by(2)
                    .map(str::to_owned)
                    .collect(),
            )
        })
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

/// The imports between sibling modules: an import from `a::x::p` of `a::y::q` is one of
/// `a::y` by `a::x`. A folder's modules import each other when any module inside one
/// imports any inside the other, so a loop between two folders shows even where no
/// single file closes it (`app::command` uses `app::view_data`, whose `geometry` uses
/// `app::command`).
fn between_siblings(
    edges: &BTreeMap<String, BTreeSet<String>>,
) -> BTreeMap<String, BTreeSet<String>> {
    let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (m, used) in edges {
        for t in used {
            let (ms, ts): (Vec<&str>, Vec<&str>) =
                (m.split("::").collect(), t.split("::").collect());
            let common = ms.iter().zip(&ts).take_while(|(a, b)| a == b).count();
            if common >= ms.len() || common >= ts.len() {
                continue;
            }
            out.entry(ms[..=common].join("::"))
                .or_default()
                .insert(ts[..=common].join("::"));
        }
    }
    out
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
    // Each of the studio's modules is named: one that is not would take `app`'s layer,
    // the top, and could import any other.
    for m in modules.keys().filter(|m| m.matches("::").count() == 1) {
        if m.starts_with("app::") && !layers.iter().flatten().any(|n| n == m) {
            wrong.push(format!(
                "{m}: a studio module in no layer of ARCHITECTURE.md"
            ));
        }
    }
    for c in cycles(&between_siblings(&edges)) {
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
    let l = layers(
        "x\n## Layers\n\n| layer | modules |\n|---|---|\n| 1 | `low` | below `high` |\n| 2 | `high`, `high::part` |\n\n## Next\n| 3 | `no` |",
    );
    assert_eq!(l.len(), 2);
    assert_eq!(layer_of(&l, "high::part::deep"), Some(1));
    assert_eq!(layer_of(&l, "low"), Some(0));
    assert_eq!(layer_of(&l, "nowhere"), None);
}

#[test]
fn a_loop_through_a_parents_re_exports_is_found() {
    // `fit` and `xml` each reach the other only through names their parent binds:
    // a re-export, a private `use` (children see it too), and a glob re-export.
    let mut m = BTreeMap::new();
    m.insert(
        "corr".to_owned(),
        "pub mod fit; pub mod xml; mod frame;\npub use fit::{Model as FitModel, Other};\nuse xml::Frame;\npub use frame::*;".to_owned(),
    );
    m.insert(
        "corr::fit".to_owned(),
        "use super::Frame;\npub struct Model;\npub enum Other {}".to_owned(),
    );
    m.insert(
        "corr::xml".to_owned(),
        "use super::{FitModel, Norm};\npub struct Frame;".to_owned(),
    );
    m.insert("corr::frame".to_owned(), "pub fn Norm() {}".to_owned());
    let edges = imports(&m);
    assert_eq!(edges["corr::fit"], BTreeSet::from(["corr::xml".to_owned()]));
    assert_eq!(
        edges["corr::xml"],
        BTreeSet::from(["corr::fit".to_owned(), "corr::frame".to_owned()])
    );
    assert_eq!(
        cycles(&edges),
        vec![vec!["corr::fit".to_owned(), "corr::xml".to_owned()]]
    );
    // An inline path through the parent is followed too; a parent's own item is not
    // a dependency of its child.
    m.insert(
        "corr::fit".to_owned(),
        "pub struct Model; fn f(_: &super::Whole) { let _ = super::Frame::default(); }".to_owned(),
    );
    m.insert(
        "corr".to_owned(),
        "use xml::Frame; pub struct Whole;".to_owned(),
    );
    let edges = imports(&m);
    assert_eq!(edges["corr::fit"], BTreeSet::from(["corr::xml".to_owned()]));
}

#[test]
fn use_trees_are_flattened() {
    let items = use_items("pub(crate) use a::{b, c::{d as e, f::*}, self};\nuse super::g;");
    let paths: Vec<(String, Option<&str>)> = items
        .iter()
        .map(|u| (u.path.join("::"), u.binds.as_deref()))
        .collect();
    assert_eq!(
        paths,
        vec![
            ("a::b".to_owned(), Some("b")),
            ("a::c::d".to_owned(), Some("e")),
            ("a::c::f".to_owned(), None),
            ("a".to_owned(), Some("a")),
            ("super::g".to_owned(), Some("g")),
        ]
    );
}

#[test]
fn comments_and_literals_are_not_code() {
    let code = code_only(
        "use a::b; // use c::d;\n/* use e::f; /* nested */ */ let s = \"use g::h;\";\nlet r = r#\"use i::j; \"quoted\"\"#; let q = '\"'; let e = '\\''; fn f<'a>(x: &'a str) { crate::k::l(); }",
    );
    let paths: Vec<String> = use_items(&code).iter().map(|u| u.path.join("::")).collect();
    assert_eq!(paths, vec!["a::b".to_owned()]);
    assert!(
        code.contains("fn f<'a>(x: &'a str) { crate::k::l(); }"),
        "{code}"
    );
}

#[test]
fn a_loop_between_two_folders_is_found() {
    // No one file closes the loop: `command` uses `view`, and a module inside `view`
    // uses `command`.
    let mut m = BTreeMap::new();
    m.insert("app".to_owned(), String::new());
    m.insert(
        "app::command".to_owned(),
        "use super::view::Options;".to_owned(),
    );
    m.insert("app::view".to_owned(), "pub struct Options;".to_owned());
    m.insert(
        "app::view::geometry".to_owned(),
        "fn f(_: crate::app::command::Command) {}".to_owned(),
    );
    m.insert("app::command::more".to_owned(), String::new());
    let edges = imports(&m);
    assert!(
        cycles(&edges).is_empty(),
        "no file imports its own importer"
    );
    let siblings = between_siblings(&edges);
    assert_eq!(
        siblings["app::view"],
        BTreeSet::from(["app::command".to_owned()])
    );
    assert_eq!(
        cycles(&siblings),
        vec![vec!["app::command".to_owned(), "app::view".to_owned()]]
    );
}
