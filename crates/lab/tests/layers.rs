//! The library's rooms and their order, read from its sources: one room per job, each using
//! only the rooms below it; no module that imports a module that imports it; no function of
//! the diagnosis over 120 lines; no decision number in the diagnosis outside the rules table.
//!
//! The module graph is read from the sources as text: a module is a file, and it depends on
//! every module it names by path (`crate::a::b`, `super::c`, `use` groups), resolved to the
//! deepest module that exists. A parent's `pub use` of its children (its interface) is not a
//! dependency; a child naming an item of its parent is.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The rooms, bottom first: each may use the rooms before it in this list.
const ROOMS: [&str; 12] = [
    "record",
    "rules",
    "signal",
    "model",
    "fit",
    "mimo",
    "diagnose",
    "identify",
    "design",
    "experiments",
    "report",
    "fixtures",
];

/// A source file: its module path and its text (comments and tests removed).
struct Source {
    module: String,
    code: String,
    path: PathBuf,
}

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("read src") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `crate::a::b` of `src/a/b.rs` and `src/a/b/mod.rs`; `crate` of `src/lib.rs`.
fn module_of(src: &Path, p: &Path) -> String {
    let rel = p.strip_prefix(src).expect("under src").with_extension("");
    let mut parts: Vec<String> = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
    if parts.last().is_some_and(|l| l == "mod" || l == "lib") {
        parts.pop();
    }
    std::iter::once("crate".to_string()).chain(parts).collect::<Vec<_>>().join("::")
}

/// The code without line comments, doc comments and `#[cfg(test)] mod tests { … }`.
fn code_of(text: &str) -> String {
    let cut = text.find("#[cfg(test)]\nmod tests").unwrap_or(text.len());
    text[..cut]
        .lines()
        .map(|l| match l.find("//") {
            Some(i) if !l[..i].contains('"') => &l[..i],
            _ => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn sources(crate_dir: &str) -> Vec<Source> {
    let src = Path::new(crate_dir).join("src");
    let mut paths = vec![];
    files(&src, &mut paths);
    paths
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).expect("read source");
            Source { module: module_of(&src, &p), code: code_of(&text), path: p }
        })
        .collect()
}

/// Every path a module names: `crate::…`, `super::…` and `self::…` in paths and `use`
/// groups, made absolute; `pub use` lines of a parent naming its own children are left out.
fn named_paths(s: &Source) -> Vec<String> {
    let parent = |m: &str| m.rsplit_once("::").map_or("crate".to_string(), |(p, _)| p.to_string());
    let is_dir_module = s.path.ends_with("mod.rs") || s.path.ends_with("lib.rs");
    let base_self = s.module.clone();
    let base_super = parent(&s.module);
    let mut out = vec![];
    for stmt in s.code.split(';') {
        let stmt = stmt.trim();
        let reexport = stmt.starts_with("pub use ") && !stmt.contains("crate::") && !stmt.contains("super::");
        if reexport {
            continue;
        }
        // Expand `use a::{b, c::d}` into `a::b`, `a::c::d` (one level of braces is enough here).
        let mut text = stmt.to_string();
        while let (Some(open), Some(close)) = (text.find('{'), text.rfind('}')) {
            if close < open {
                break;
            }
            let head = &text[..open];
            let prefix_start = head
                .char_indices()
                .rev()
                .find(|&(_, c)| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .map_or(0, |(i, c)| i + c.len_utf8());
            let prefix = &head[prefix_start..];
            if !prefix.ends_with("::") {
                break;
            }
            let inner = &text[open + 1..close];
            let expanded: Vec<String> = inner.split(',').map(|x| format!("{prefix}{}", x.trim())).collect();
            text = format!("{} {} {}", &head[..prefix_start], expanded.join(" "), &text[close + 1..]);
        }
        for word in text.split(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':')) {
            let abs = if let Some(rest) = word.strip_prefix("crate::") {
                format!("crate::{rest}")
            } else if let Some(rest) = word.strip_prefix("super::") {
                let sup = if is_dir_module { parent(&base_self) } else { base_super.clone() };
                format!("{sup}::{rest}")
            } else if let Some(rest) = word.strip_prefix("self::") {
                let me = if is_dir_module { base_self.clone() } else { base_super.clone() };
                format!("{me}::{rest}")
            } else {
                continue;
            };
            out.push(abs.trim_end_matches("::").to_string());
        }
    }
    out
}

/// The module graph: each module and the modules it depends on.
fn graph(srcs: &[Source]) -> BTreeMap<String, BTreeSet<String>> {
    let modules: BTreeSet<String> = srcs.iter().map(|s| s.module.clone()).collect();
    let mut g = BTreeMap::new();
    for s in srcs {
        let mut deps = BTreeSet::new();
        for p in named_paths(s) {
            // The deepest module the path names.
            let parts: Vec<&str> = p.split("::").collect();
            let target = (1..=parts.len()).rev().map(|n| parts[..n].join("::")).find(|m| modules.contains(m));
            if let Some(t) = target {
                if t != s.module && t != "crate" {
                    deps.insert(t);
                }
            }
        }
        g.insert(s.module.clone(), deps);
    }
    g
}

/// A cycle of the graph, if it has one.
fn cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        g: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(n.to_string(), 1);
        stack.push(n.to_string());
        for d in g.get(n).into_iter().flatten() {
            match state.get(d.as_str()).copied().unwrap_or(0) {
                1 => {
                    let from = stack.iter().position(|s| s == d).unwrap_or(0);
                    let mut c = stack[from..].to_vec();
                    c.push(d.clone());
                    return Some(c);
                }
                0 => {
                    if let Some(c) = visit(d, g, state, stack) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in g.keys() {
        if state.get(n.as_str()).copied().unwrap_or(0) == 0 {
            let mut stack = vec![];
            if let Some(c) = visit(n, g, &mut state, &mut stack) {
                return Some(c);
            }
        }
    }
    None
}

fn room(module: &str) -> Option<&str> {
    module.split("::").nth(1)
}

#[test]
fn each_room_uses_only_the_rooms_below_it() {
    let srcs = sources(env!("CARGO_MANIFEST_DIR"));
    let g = graph(&srcs);
    let mut wrong = vec![];
    for (m, deps) in &g {
        let Some(from) = room(m).and_then(|r| ROOMS.iter().position(|x| *x == r)) else { continue };
        for d in deps {
            let Some(to) = room(d).and_then(|r| ROOMS.iter().position(|x| *x == r)) else { continue };
            if to > from {
                wrong.push(format!("{m} uses {d}"));
            }
        }
    }
    assert!(wrong.is_empty(), "rooms used from below (order {ROOMS:?}):\n{}", wrong.join("\n"));
    // Every room of the list exists, and no other.
    let found: BTreeSet<&str> = g.keys().filter_map(|m| room(m)).collect();
    assert_eq!(found, ROOMS.iter().copied().collect(), "the rooms of src/ and of ROOMS");
}

#[test]
fn no_module_imports_a_module_that_imports_it() {
    let g = graph(&sources(env!("CARGO_MANIFEST_DIR")));
    assert_eq!(cycle(&g), None, "an import cycle");
}

/// Every `fn` of the files under `dir` with its length in lines (from its signature to its
/// closing brace at the same indentation).
fn function_lengths(dir: &Path) -> Vec<(String, usize)> {
    let mut paths = vec![];
    files(dir, &mut paths);
    let mut out = vec![];
    for p in paths {
        let text = std::fs::read_to_string(&p).expect("read");
        let code = code_of(&text);
        let lines: Vec<&str> = code.lines().collect();
        for (i, l) in lines.iter().enumerate() {
            let t = l.trim_start();
            let is_fn =
                ["fn ", "pub fn ", "pub(crate) fn ", "pub(super) fn "].iter().any(|k| t.starts_with(k));
            if !is_fn {
                continue;
            }
            let indent = l.len() - t.len();
            let end = (i..lines.len()).find(|&j| {
                let u = lines[j];
                u.len() > indent && u[..indent].trim().is_empty() && u[indent..].starts_with('}')
            });
            if let Some(e) = end {
                let name = t.split('(').next().unwrap_or(t).to_string();
                out.push((format!("{}: {name}", p.display()), e - i + 1));
            }
        }
    }
    out
}

#[test]
fn no_function_of_the_diagnosis_is_longer_than_120_lines() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src").join("diagnose");
    let long: Vec<String> = function_lengths(&dir)
        .into_iter()
        .filter(|(_, n)| *n > 120)
        .map(|(f, n)| format!("{f}: {n} lines"))
        .collect();
    assert!(long.is_empty(), "{}", long.join("\n"));
}

/// Numbers the diagnosis may write inline: no decision rests on them. Units (`1e3` ms per
/// s, `100.0` percent), the small integers of indices and of the powers that define a term
/// (a quadratic's 2, a cubic's 3), halves and doubles of the formulas, and guards against
/// dividing by zero.
const NOT_DECISIONS: [&str; 11] = ["0", "1", "2", "3", "0.0", "0.5", "1.0", "2.0", "100.0", "1e-300", "1e-9"];

#[test]
fn the_diagnosis_decides_by_the_rules_table_only() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src").join("diagnose");
    let mut paths = vec![];
    files(&dir, &mut paths);
    let mut inline = vec![];
    for p in paths {
        let code = code_of(&std::fs::read_to_string(&p).expect("read"));
        for (i, l) in code.lines().enumerate() {
            let t = l.trim_start();
            if t.starts_with("const ") || t.starts_with("pub const ") || t.starts_with('#') {
                continue;
            }
            // Strings (messages) are not decisions.
            let mut bare = String::new();
            let mut in_str = false;
            let mut prev = ' ';
            for c in l.chars() {
                if c == '"' && prev != '\\' {
                    in_str = !in_str;
                } else if !in_str {
                    bare.push(c);
                }
                prev = c;
            }
            // A range `1..n` is two words.
            let bare = bare.replace("..", " ");
            let mut word = String::new();
            for c in bare.chars().chain(std::iter::once(' ')) {
                if c.is_ascii_alphanumeric() || c == '_' || c == '.' || (c == '-' && word.ends_with('e')) {
                    word.push(c);
                    continue;
                }
                let w = word.trim_end_matches('.').to_string();
                word.clear();
                let starts_digit = w.chars().next().is_some_and(|c| c.is_ascii_digit());
                if !starts_digit {
                    continue;
                }
                let number = w
                    .trim_end_matches("usize")
                    .trim_end_matches("u32")
                    .trim_end_matches("u64")
                    .trim_end_matches("f64")
                    .trim_end_matches('_');
                if !NOT_DECISIONS.contains(&number) {
                    inline.push(format!("{}:{}: {number} in `{}`", p.display(), i + 1, l.trim()));
                }
            }
        }
    }
    assert!(
        inline.is_empty(),
        "numbers the diagnosis decides by outside the rules table:\n{}",
        inline.join("\n")
    );
}

#[test]
fn the_link_has_no_import_cycle() {
    // The board's crate, read the same way: the wire protocol (frames, messages and their
    // parameters, the limits every value is checked against) below the board's state
    // machine (its excitation, on-chip plant, analog front end and device), none of them
    // importing a module that imports it.
    let link = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("link");
    let g = graph(&sources(link.to_str().expect("a UTF-8 path")));
    assert!(g.contains_key("crate::device") && g.contains_key("crate::message"), "{g:?}");
    assert_eq!(cycle(&g), None, "an import cycle in boucwen-link");
}
