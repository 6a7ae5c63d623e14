//! The code's shape, checked on its source (issue 25): no module of a crate imports, through a
//! chain of others, a module that imports it; and every function of every crate, its tests and
//! the examples stays short (unless a comment above it says why it is one piece).
//!
//! A module's imports are the `crate::…`, `super::…` and `self::…` paths in its file (outside
//! `#[cfg(test)]` and comments), each resolved to the longest module path it names. A module's
//! use of its own ancestors is not counted: a parent declares its children, and a child may use
//! the types its parent holds.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Longest function body allowed anywhere in the workspace, lines (the "about 80").
const LONGEST_FUNCTION: usize = 85;

/// Every `.rs` file under `dir`, recursively.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("source folder readable") {
        let path = entry.expect("folder entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The module path of a source file relative to its crate's `src`: `a/b.rs` and `a/b/mod.rs`
/// are `a::b`, `lib.rs` is the root (empty).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).expect("file under src");
    let mut parts: Vec<String> = rel
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// The file's code before its unit tests, without line comments.
fn code_of(text: &str) -> String {
    let body = text.split("#[cfg(test)]").next().unwrap_or("");
    body.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The paths after each `crate::`, `super::` or `self::` in `code`, resolved against `module`,
/// including the names inside `crate::{…}` groups.
fn referenced_paths(module: &[String], code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    for (i, _) in code.match_indices("::") {
        let head_start = code[..i]
            .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
            .map_or(0, |p| p + 1);
        let head = &code[head_start..i];
        let base: Vec<String> = match head {
            "crate" => Vec::new(),
            "super" => module[..module.len().saturating_sub(1)].to_vec(),
            "self" => module.to_vec(),
            _ => continue,
        };
        // skip `super::super` and the like: the inner `super` is resolved on its own
        if head_start >= 2 && &code[head_start - 2..head_start] == "::" {
            continue;
        }
        let rest = &code[i + 2..];
        if bytes.get(i + 2) == Some(&b'{') {
            let group = rest[1..].split('}').next().unwrap_or("");
            for item in group.split(',') {
                let mut path = base.clone();
                path.extend(item.trim().split("::").map(|s| s.trim().to_string()));
                out.push(path);
            }
            continue;
        }
        let tail: String = rest
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
            .collect();
        let mut path = base;
        path.extend(
            tail.split("::")
                .filter(|s| !s.is_empty())
                .map(str::to_string),
        );
        out.push(path);
    }
    out
}

/// The import graph of the crate whose sources are in `src`.
fn import_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeMap<Vec<String>, PathBuf> =
        files.into_iter().map(|f| (module_of(src, &f), f)).collect();
    let mut graph = BTreeMap::new();
    for (module, file) in &modules {
        let code = code_of(&std::fs::read_to_string(file).expect("source readable"));
        let mut deps = BTreeSet::new();
        for path in referenced_paths(module, &code) {
            let target = (1..=path.len())
                .rev()
                .map(|k| &path[..k])
                .find(|p| modules.contains_key(*p));
            if let Some(t) = target {
                // its own ancestors (and itself) are not imports
                if !module.starts_with(t) {
                    deps.insert(t.join("::"));
                }
            }
        }
        graph.insert(module.join("::"), deps);
    }
    graph
}

/// A cycle of `graph`, if it has one (depth-first search with colours).
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(node.to_string(), 1);
        stack.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            match state.get(next.as_str()).copied().unwrap_or(0) {
                0 => {
                    if let Some(c) = visit(next, graph, state, stack) {
                        return Some(c);
                    }
                }
                1 => {
                    let from = stack.iter().position(|s| s == next).unwrap_or(0);
                    let mut cycle = stack[from..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(node.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for node in graph.keys() {
        if state.get(node.as_str()).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(node, graph, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn no_crate_has_an_import_cycle_among_its_modules() {
    for krate in ["solver/src", "residuals/src", "slam/src", "apps/src", "src"] {
        let graph = import_graph(&workspace().join(krate));
        assert!(
            graph.len() > 1 || krate == "src",
            "{krate}: no modules found"
        );
        if let Some(cycle) = find_cycle(&graph) {
            panic!("{krate}: import cycle {}", cycle.join(" -> "));
        }
    }
}

#[test]
fn the_cycle_check_finds_a_cycle() {
    let a = vec!["a".to_string()];
    let b = vec!["b".to_string()];
    let mut graph = BTreeMap::new();
    for (module, code) in [(&a, "use crate::b::Thing;"), (&b, "use super::a;")] {
        let deps: BTreeSet<String> = referenced_paths(module, code)
            .into_iter()
            .map(|p| p[0].clone())
            .collect();
        graph.insert(module.join("::"), deps);
    }
    assert_eq!(graph["a"], BTreeSet::from(["b".to_string()]));
    assert_eq!(graph["b"], BTreeSet::from(["a".to_string()]));
    assert!(find_cycle(&graph).is_some());
    graph.insert("b".into(), BTreeSet::new());
    assert!(find_cycle(&graph).is_none());
}

/// (file, line, name, length) of each function in `text` longer than `limit` lines, from its
/// `fn` line to the closing brace at the same indentation. A function whose comment above says
/// it is "one piece" (and why) is exempt.
fn long_functions(file: &str, text: &str, limit: usize) -> Vec<(String, usize, String, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let trimmed = line.trim_start();
        let indent = line.len() - trimmed.len();
        let signature = trimmed
            .trim_start_matches("pub(crate) ")
            .trim_start_matches("pub(super) ")
            .trim_start_matches("pub ")
            .trim_start_matches("unsafe ");
        // `fn a => b(...)` inside a macro's invocation is not a function body
        if !signature.starts_with("fn ")
            || line.trim_end().ends_with(';')
            || signature.contains("=>")
        {
            continue;
        }
        let close = format!("{}}}", " ".repeat(indent));
        let Some(end) = lines[i..].iter().position(|l| l.trim_end() == close) else {
            continue;
        };
        let exempt = lines[..i]
            .iter()
            .rev()
            .take_while(|l| l.trim_start().starts_with("//") || l.trim_start().starts_with("#["))
            .any(|l| l.contains("one piece"));
        if end + 1 > limit && !exempt {
            let name: String = signature[3..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            out.push((file.to_string(), i + 1, name, end + 1));
        }
    }
    out
}

#[test]
fn every_function_is_short() {
    let mut files = Vec::new();
    rust_files(&workspace().join("solver/src"), &mut files);
    for dir in [
        "residuals/src",
        "slam/src",
        "apps/src",
        "apps/tests",
        "src",
        "tests",
        "examples",
    ] {
        rust_files(&workspace().join(dir), &mut files);
    }
    let mut long = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).expect("source readable");
        long.extend(long_functions(
            &f.display().to_string(),
            &text,
            LONGEST_FUNCTION,
        ));
    }
    assert!(
        long.is_empty(),
        "functions over {LONGEST_FUNCTION} lines: {long:?}"
    );
    let sample = "fn short() {\n    1\n}\n\nfn long() {\n".to_string()
        + &"    x;\n".repeat(LONGEST_FUNCTION)
        + "}\n";
    let found = long_functions("sample", &sample, LONGEST_FUNCTION);
    assert_eq!(found.len(), 1, "the check finds a long function");
    assert_eq!(found[0].2, "long");
}
