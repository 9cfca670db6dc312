//! The crate's modules depend one way: no module uses one that uses it back (burn's examples'
//! data → model → training → inference layering), and the data and loader modules do not use
//! burn, so crops, targets and batching can be reused and tested without a backend.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Each module of `src/` (by file stem) and the crate modules it names (`crate::name`).
fn module_graph() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut graph = BTreeMap::new();
    for entry in std::fs::read_dir(&src).expect("read src/") {
        let path = entry.expect("a directory entry").path();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        if name == "lib" {
            continue;
        }
        let text = std::fs::read_to_string(&path).expect("read a module");
        let uses = text
            .match_indices("crate::")
            .map(|(at, _)| {
                text[at + "crate::".len()..]
                    .chars()
                    .take_while(|c| c.is_ascii_lowercase() || *c == '_')
                    .collect::<String>()
            })
            .filter(|used| !used.is_empty() && *used != name)
            .collect();
        graph.insert(name, uses);
    }
    graph
}

#[test]
fn the_module_graph_has_no_cycle() {
    let graph = module_graph();
    assert!(graph.len() >= 10, "{graph:?}");
    // Depth-first search; a module met again while it is on the path closes a cycle.
    fn visit<'a>(
        module: &'a str,
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<&'a str>,
        done: &mut BTreeSet<&'a str>,
    ) {
        if done.contains(module) {
            return;
        }
        if let Some(start) = path.iter().position(|m| *m == module) {
            panic!("module cycle: {} → {module}", path[start..].join(" → "));
        }
        path.push(module);
        for used in graph.get(module).into_iter().flatten() {
            visit(used, graph, path, done);
        }
        path.pop();
        done.insert(module);
    }
    let mut done = BTreeSet::new();
    for module in graph.keys() {
        visit(module, &graph, &mut Vec::new(), &mut done);
    }
}

#[test]
fn crops_targets_and_batching_do_not_use_burn() {
    for module in ["data", "loader"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("src")
            .join(format!("{module}.rs"));
        let text = std::fs::read_to_string(path).expect("read a module");
        assert!(!text.contains("burn::"), "{module}.rs uses burn");
        assert!(
            !text.contains("crate::training"),
            "{module}.rs uses training"
        );
    }
}
