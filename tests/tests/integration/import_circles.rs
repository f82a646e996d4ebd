//! No import circle between the files of any crate: if `a.rs` uses something of `b.rs`
//! (directly or through other files), `b.rs` uses nothing of `a.rs`. A circle means neither
//! file can be read, tested or changed without the other.
//!
//! The check reads every crate's sources as text: each path that starts with `crate::`,
//! `super::` or `self::` (in `use` declarations and inline paths, comments and `#[cfg(test)]`
//! modules left out) is resolved to the deepest file module it names. An edge between a module
//! and one of its ancestors is not counted: a parent declares and re-exports its children, and
//! a child may use what its parent defines (so a path through a parent's re-export is counted
//! at the parent, not at the file that defines the item).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The source roots checked, relative to the repository.
const CRATE_SOURCES: &[&str] = &[
    "protocol/src",
    "task-table/src",
    "timebase/src",
    "board-support/src",
    "stereo-board/src",
    "autopilot/src",
    "sim-host/src",
    "xtask/src",
    "xtask/insns-firmware/src",
    "virtual-board/src",
];

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A file's module path within its crate (`[]` for the crate root).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).expect("file under its source root");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().expect("a file name");
    let stem = last.trim_end_matches(".rs");
    if !(stem == "mod" || (parts.is_empty() && (stem == "lib" || stem == "main"))) {
        parts.push(stem.to_owned());
    }
    parts
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            // A binary's own tree (src/bin) is a crate of its own; the firmware's `firmware/`
            // modules belong to the crate.
            if p.file_name().is_some_and(|n| n == "bin") {
                continue;
            }
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The source without comments, string literals and `#[cfg(test)]` items.
fn code_of(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if b[i] == b'\'' && b.get(i + 1) == Some(&b'\\') {
            // An escaped character literal: past the escaped character, up to its closing quote.
            i += 3;
            while i < b.len() && b[i] != b'\'' {
                i += 1;
            }
            i += 1;
        } else if b[i] == b'\'' && b.get(i + 2) == Some(&b'\'') {
            i += 3;
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i..].starts_with(b"#[cfg(test)]") {
            // Skip the attribute and the item it guards: up to its `;` or its matching `}`.
            i += "#[cfg(test)]".len();
            let mut depth = 0;
            while i < b.len() {
                match b[i] {
                    b'{' => depth += 1,
                    b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            i += 1;
                            break;
                        }
                    }
                    b';' if depth == 0 => {
                        i += 1;
                        break;
                    }
                    _ => {}
                }
                i += 1;
            }
        } else {
            out.push(b[i] as char);
            i += 1;
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Every module path a file's code names, expanded from `use` groups, relative paths resolved
/// against the file's module `here`.
fn referenced_paths(code: &str, here: &[String]) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let starts = ["crate::", "super::", "self::"]
            .into_iter()
            .find(|p| chars[i..].starts_with(&p.chars().collect::<Vec<_>>()[..]));
        let boundary = i == 0 || !(is_ident(chars[i - 1]) || chars[i - 1] == ':');
        if let (Some(_), true) = (starts, boundary) {
            let (paths, end) = parse_path(&chars, i);
            for p in paths {
                if let Some(abs) = absolute(&p, here) {
                    found.push(abs);
                }
            }
            i = end;
        } else {
            i += 1;
        }
    }
    found
}

/// Parses a path starting at `i` (`a::b::{c, d::e}` expands to `a::b::c`, `a::b::d::e`);
/// returns the paths and the index after it.
fn parse_path(chars: &[char], mut i: usize) -> (Vec<Vec<String>>, usize) {
    let mut prefix = Vec::new();
    loop {
        while i < chars.len() && chars[i].is_whitespace() {
            i += 1;
        }
        if i < chars.len() && chars[i] == '{' {
            let mut out = Vec::new();
            i += 1;
            loop {
                while i < chars.len() && (chars[i].is_whitespace() || chars[i] == ',') {
                    i += 1;
                }
                if i >= chars.len() || chars[i] == '}' {
                    i += 1;
                    break;
                }
                let (inner, end) = parse_path(chars, i);
                for p in inner {
                    out.push(prefix.iter().cloned().chain(p).collect());
                }
                // Skip `as name` and anything else up to the next item of the group.
                i = end;
                while i < chars.len() && chars[i] != ',' && chars[i] != '}' {
                    i += 1;
                }
            }
            return (out, i);
        }
        let start = i;
        while i < chars.len() && (is_ident(chars[i]) || chars[i] == '*') {
            i += 1;
        }
        if i == start {
            return (vec![prefix], i);
        }
        prefix.push(chars[start..i].iter().collect());
        if chars[i..].starts_with(&[':', ':']) {
            i += 2;
        } else {
            return (vec![prefix], i);
        }
    }
}

/// `crate::a::b`, `super::c`, `self::d` as a path from the crate root.
fn absolute(path: &[String], here: &[String]) -> Option<Vec<String>> {
    let mut out: Vec<String> = Vec::new();
    let mut rest = path;
    match rest.first().map(String::as_str) {
        Some("crate") => rest = &rest[1..],
        Some("self") => {
            out = here.to_vec();
            rest = &rest[1..];
        }
        Some("super") => {
            out = here.to_vec();
            while rest.first().map(String::as_str) == Some("super") {
                out.pop()?;
                rest = &rest[1..];
            }
        }
        _ => return None,
    }
    out.extend(rest.iter().cloned());
    Some(out)
}

/// The names of the items a file's code declares public (`pub`, `pub(crate)`, ...): structs,
/// enums, traits, functions, constants, statics, types and unions.
fn public_items(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in code.lines() {
        let mut rest = line.trim_start();
        let Some(after) = rest.strip_prefix("pub") else {
            continue;
        };
        rest = after;
        if let Some(after) = rest.strip_prefix('(') {
            rest = after.split_once(')').map_or("", |(_, r)| r);
        }
        let mut words = rest.split_whitespace();
        let mut kind = words.next().unwrap_or("");
        while matches!(kind, "const" | "unsafe" | "async" | "extern") {
            match words.clone().next() {
                Some(next) if ["fn", "unsafe", "async", "extern"].contains(&next) => {
                    kind = words.next().unwrap_or("");
                }
                _ => break,
            }
        }
        let kinds = [
            "struct", "enum", "trait", "fn", "const", "static", "type", "union",
        ];
        if kinds.contains(&kind) {
            if let Some(word) = words.next() {
                let ident: String = word.chars().take_while(|&c| is_ident(c)).collect();
                if !ident.is_empty() && ident != "mut" {
                    out.push(ident);
                }
            }
        }
    }
    out
}

/// Finds the strongly connected components with more than one file (Tarjan).
fn circles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct State<'a> {
        edges: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on_stack: BTreeSet<&'a str>,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a str) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in s.edges.get(v).into_iter().flatten() {
            let w = w.as_str();
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).expect("visited");
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).expect("visited");
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            loop {
                let w = s.stack.pop().expect("on the stack");
                s.on_stack.remove(w);
                comp.push(w.to_owned());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                s.out.push(comp);
            }
        }
    }
    let mut s = State {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !s.index.contains_key(v.as_str()) {
            visit(&mut s, v);
        }
    }
    s.out
}

/// The file-to-file uses of one crate, by file path relative to the repository.
fn crate_edges(src_rel: &str) -> BTreeMap<String, BTreeSet<String>> {
    let src = repo().join(src_rel);
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let modules: BTreeMap<Vec<String>, String> = files
        .iter()
        .map(|f| {
            (
                module_of(&src, f),
                format!("{src_rel}/{}", f.strip_prefix(&src).unwrap().display()),
            )
        })
        .collect();
    let codes: Vec<String> = files
        .iter()
        .map(|f| {
            code_of(&std::fs::read_to_string(f).unwrap_or_else(|e| panic!("{}: {e}", f.display())))
        })
        .collect();
    // Which files define each public item, to follow a path through a parent's re-export.
    let mut definers: BTreeMap<String, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (f, code) in files.iter().zip(&codes) {
        for name in public_items(code) {
            definers.entry(name).or_default().insert(module_of(&src, f));
        }
    }
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (f, code) in files.iter().zip(&codes) {
        let here = module_of(&src, f);
        let name = &modules[&here];
        let entry = edges.entry(name.clone()).or_default();
        for path in referenced_paths(code, &here) {
            // The deepest file module the path names.
            let Some(mut target) = (0..=path.len())
                .rev()
                .find(|&n| modules.contains_key(&path[..n]))
                .map(|n| path[..n].to_vec())
            else {
                continue;
            };
            // An item named through an ancestor's re-export: the one descendant defining it.
            if here.starts_with(&target) {
                if let Some(owners) = path.get(target.len()).and_then(|item| definers.get(item)) {
                    let mut below = owners.iter().filter(|m| m.starts_with(&target));
                    if let (Some(owner), None) = (below.next(), below.next()) {
                        target = owner.clone();
                    }
                }
            }
            let related = target.starts_with(&here) || here.starts_with(&target);
            if !related {
                entry.insert(modules[&target].clone());
            }
        }
    }
    edges
}

#[test]
fn no_file_uses_a_file_that_uses_it() {
    let mut found = Vec::new();
    for src in CRATE_SOURCES {
        let edges = crate_edges(src);
        assert!(!edges.is_empty(), "{src}: no source files found");
        for c in circles(&edges) {
            let detail: Vec<String> = c
                .iter()
                .map(|f| {
                    let uses: Vec<&String> = edges[f].iter().filter(|g| c.contains(g)).collect();
                    format!("    {f} uses {uses:?}")
                })
                .collect();
            found.push(format!("  circle:\n{}", detail.join("\n")));
        }
    }
    assert!(
        found.is_empty(),
        "import circles between files:\n{}",
        found.join("\n")
    );
}

#[test]
fn the_checker_sees_a_circle_and_resolves_groups() {
    let code = code_of(
        "use crate::a::{B, c::D as E, self};\n// crate::z::Y\nfn f() { super::g::h(); }\n\
         #[cfg(test)]\nmod tests { use crate::t::X; }\n",
    );
    let here = vec!["m".to_owned(), "n".to_owned()];
    let paths = referenced_paths(&code, &here);
    let want: Vec<Vec<String>> = [
        vec!["a", "B"],
        vec!["a", "c", "D"],
        vec!["a", "self"],
        vec!["m", "g", "h"],
    ]
    .iter()
    .map(|p| p.iter().map(|s| s.to_string()).collect())
    .collect();
    assert_eq!(paths, want);
    let edge = |a: &str, b: &[&str]| (a.to_owned(), b.iter().map(|s| s.to_string()).collect());
    let edges: BTreeMap<String, BTreeSet<String>> = [
        edge("x", &["y"]),
        edge("y", &["z"]),
        edge("z", &["x"]),
        edge("w", &["x"]),
    ]
    .into_iter()
    .collect();
    assert_eq!(
        circles(&edges),
        vec![vec!["x".to_owned(), "y".to_owned(), "z".to_owned()]]
    );
}
