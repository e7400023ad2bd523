//! The server's modules form no import circle, and no handler imports another.
//!
//! Reads every `src/*.rs` (and `src/*/` folder module) and collects the modules each names through `crate::` or
//! `super::` (in `use` lines and inline paths alike, test modules excluded); a name
//! that is no module is something the crate root defines, so an edge to `lib`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The route handlers: each stands alone on the shared modules.
const HANDLERS: [&str; 6] = ["discovery", "ops", "queries", "render", "tiles", "web"];

/// Every module's code by name: `src/NAME.rs`, or for a folder module `src/NAME/` its
/// `mod.rs` followed by its submodules, whose `super::` paths name the folder module
/// itself (so they are left out) and whose `crate::` paths count as the folder's.
fn sources() -> BTreeMap<String, String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let read = |p: &Path| code(&std::fs::read_to_string(p).expect("a source file"));
    let mut out = BTreeMap::new();
    for path in std::fs::read_dir(&dir)
        .expect("src/ is readable")
        .map(|e| e.expect("a directory entry").path())
    {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        if path.extension().is_some_and(|e| e == "rs") {
            out.insert(name, read(&path));
        } else if path.join("mod.rs").is_file() {
            let mut text = read(&path.join("mod.rs"));
            let mut subs: Vec<_> = std::fs::read_dir(&path)
                .expect("a module folder is readable")
                .map(|e| e.expect("a directory entry").path())
                .filter(|p| p.extension().is_some_and(|e| e == "rs") && p.file_name().is_some_and(|f| f != "mod.rs"))
                .collect();
            subs.sort();
            for sub in subs {
                text.push('\n');
                text.push_str(&read(&sub).replace("super::", "parent_module::"));
            }
            out.insert(name, text);
        }
    }
    out
}

/// The code of a file without its test module and comment lines.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

fn identifier(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// The first path segment after every `crate::` and `super::` of `code`, with each
/// member of a `{…}` group.
fn named(code: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    for prefix in ["crate::", "super::"] {
        for (i, _) in code.match_indices(prefix) {
            let rest = &code[i + prefix.len()..];
            if let Some(group) = rest.strip_prefix('{') {
                let mut depth = 0;
                let mut item_start = true;
                for (j, c) in group.char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' if depth == 0 => break,
                        '}' => depth -= 1,
                        ',' if depth == 0 => item_start = true,
                        c if c.is_whitespace() => {}
                        _ if item_start && depth == 0 => {
                            names.insert(identifier(&group[j..]).to_string());
                            item_start = false;
                        }
                        _ => {}
                    }
                }
            } else {
                names.insert(identifier(rest).to_string());
            }
        }
    }
    names.retain(|n| !n.is_empty() && n != "self");
    names
}

fn graph() -> BTreeMap<String, BTreeSet<String>> {
    let sources = sources();
    let modules: BTreeSet<String> = sources.keys().cloned().collect();
    sources
        .iter()
        .map(|(module, text)| {
            let targets = named(text)
                .into_iter()
                .map(|n| if modules.contains(&n) { n } else { "lib".to_string() })
                .filter(|n| n != module)
                .collect();
            (module.clone(), targets)
        })
        .collect()
}

/// A circle of imports, if any, as the modules along it.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|n| n == node) {
            let mut cycle = path[i..].to_vec();
            cycle.push(node.to_string());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(cycle) = visit(next, graph, path, done) {
                return Some(cycle);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|start| visit(start, graph, &mut Vec::new(), &mut done))
}

#[test]
fn the_module_graph_has_no_circle() {
    let graph = graph();
    assert!(graph.len() > 10, "found the sources: {:?}", graph.keys());
    if let Some(cycle) = find_cycle(&graph) {
        panic!("modules import each other in a circle: {}", cycle.join(" -> "));
    }
}

#[test]
fn no_module_imports_the_crate_root() {
    let into_root: Vec<_> = graph()
        .into_iter()
        .filter(|(m, targets)| m != "lib" && targets.contains("lib"))
        .map(|(m, _)| m)
        .collect();
    assert!(
        into_root.is_empty(),
        "these modules name items of lib.rs rather than of the module defining them: {into_root:?}"
    );
}

#[test]
fn no_handler_imports_another_handler() {
    let graph = graph();
    for h in HANDLERS {
        let others: Vec<_> = graph[h].iter().filter(|t| HANDLERS.contains(&t.as_str())).collect();
        assert!(others.is_empty(), "handler {h} imports handlers {others:?}");
    }
}

#[test]
fn the_scanner_sees_groups_and_inline_paths() {
    let names = named("use crate::{a, b::{c, d}, e};\nlet x = super::f::g(); crate::h::I");
    let names: Vec<_> = names.iter().map(String::as_str).collect();
    assert_eq!(names, ["a", "b", "e", "f", "h"]);
    let mut g = BTreeMap::new();
    g.insert("x".to_string(), BTreeSet::from(["y".to_string()]));
    g.insert("y".to_string(), BTreeSet::from(["x".to_string()]));
    assert!(find_cycle(&g).is_some());
    g.insert("y".to_string(), BTreeSet::new());
    assert!(find_cycle(&g).is_none());
}
