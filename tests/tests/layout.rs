//! The workspace's layout holds (issue 32): one job per crate, imports going one way.
//!
//! * Inside each crate, the `use crate::...` and `crate::...` paths between its top-level modules form no circle
//!   (a module may name its own submodules; comments and test code do not count).
//! * Between crates: the learning core (cabc-learning) depends, directly or not, on no plotting, GIF, TensorBoard,
//!   progress bar, arrow/parquet, bus or analysis crate; the processes of a run (`learner`, `actor`,
//!   `expert-server`) on no arrow/parquet; the tools' crates on no run process's binary crate.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The top-level module a source file belongs to (`src/a.rs` and `src/a/b.rs`: `a`); None for lib.rs and main.rs.
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).ok()?;
    let first = rel.components().next()?.as_os_str().to_str()?;
    let name = first.trim_end_matches(".rs");
    (!matches!(name, "lib" | "main")).then(|| name.to_string())
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The modules each top-level module of `src` names through `crate::` outside comments.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeSet<String> = files.iter().filter_map(|f| module_of(src, f)).collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in &files {
        let Some(from) = module_of(src, file) else {
            continue;
        };
        // A module's tests may use any other module: the test code (files named tests.rs, and what follows
        // `#[cfg(test)]`) does not count.
        if file.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        let text = std::fs::read_to_string(file).unwrap();
        let edges = graph.entry(from.clone()).or_default();
        for line in text.lines().take_while(|l| l.trim() != "#[cfg(test)]") {
            let code = line.split("//").next().unwrap_or("");
            for (i, _) in code.match_indices("crate::") {
                // `cabc_crate::` and the like are other crates' paths.
                let before = code[..i].chars().last();
                if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                    continue;
                }
                let name: String = code[i + "crate::".len()..]
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if name != from && modules.contains(&name) {
                    edges.insert(name);
                }
            }
        }
    }
    graph
}

/// A circle of `graph`, if it has one.
fn circle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        state: &mut HashMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        match state.get(node) {
            Some(1) => {
                let at = path.iter().position(|n| n == node).unwrap();
                let mut found = path[at..].to_vec();
                found.push(node.to_string());
                return Some(found);
            }
            Some(_) => return None,
            None => {}
        }
        state.insert(node.to_string(), 1);
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(found) = visit(next, graph, state, path) {
                return Some(found);
            }
        }
        path.pop();
        state.insert(node.to_string(), 2);
        None
    }
    let mut state = HashMap::new();
    graph
        .keys()
        .find_map(|n| visit(n, graph, &mut state, &mut Vec::new()))
}

#[test]
fn the_circle_finder_finds_a_circle() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec![]),
    ]
    .into_iter()
    .map(|(k, v)| (k.into(), v.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(circle(&graph).unwrap(), ["a", "b", "c", "a"]);
    let mut open = graph.clone();
    open.get_mut("c").unwrap().clear();
    assert_eq!(circle(&open), None);
}

#[test]
fn no_crate_has_an_import_circle_between_its_modules() {
    let crates = [
        "proto",
        "sim",
        "models",
        "bus",
        "expert-server",
        "actor",
        "learning",
        "outputs",
        "analysis",
        "bench",
        "robust",
        "learner",
        "export",
        "cli",
    ];
    for krate in crates {
        let graph = module_graph(&root().join(krate).join("src"));
        assert!(
            graph.len() > 1 || ["learner", "cli", "robust"].contains(&krate),
            "{krate}: no modules read"
        );
        if let Some(found) = circle(&graph) {
            panic!("{krate}: modules import each other: {}", found.join(" -> "));
        }
    }
}

/// The triple of the machine that builds (`cargo -vV`'s `host:`).
fn host_triple() -> String {
    let out = std::process::Command::new(env!("CARGO"))
        .arg("-vV")
        .output()
        .expect("cargo -vV");
    let text = String::from_utf8_lossy(&out.stdout);
    text.lines()
        .find_map(|line| line.strip_prefix("host: "))
        .unwrap_or_else(|| panic!("cargo -vV names no host:\n{text}"))
        .to_string()
}

/// Each workspace package's dependencies, direct and not, by package name (`cargo metadata`, offline), on the
/// machine's own platform: a fresh machine's registry holds only the packages its build downloaded, and offline
/// `cargo metadata` over every platform wants the others' too (android_system_properties, windows-sys...).
fn dependency_closure() -> HashMap<String, BTreeSet<String>> {
    let out = std::process::Command::new(env!("CARGO"))
        .args(["metadata", "--format-version", "1", "--offline"])
        .args(["--filter-platform", &host_triple()])
        .arg("--manifest-path")
        .arg(root().join("Cargo.toml"))
        .output()
        .expect("cargo metadata");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let names: HashMap<&str, &str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), p["name"].as_str().unwrap()))
        .collect();
    // Normal (non-dev) dependencies only: what a crate's library and binaries link.
    let direct: HashMap<&str, Vec<&str>> = meta["resolve"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|node| {
            let deps = node["deps"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| {
                    d["dep_kinds"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .any(|k| k["kind"].is_null())
                })
                .map(|d| d["pkg"].as_str().unwrap())
                .collect();
            (node["id"].as_str().unwrap(), deps)
        })
        .collect();
    let mut closure = HashMap::new();
    for member in meta["workspace_members"].as_array().unwrap() {
        let id = member.as_str().unwrap();
        let mut seen = BTreeSet::new();
        let mut todo = vec![id];
        while let Some(next) = todo.pop() {
            for &dep in direct.get(next).into_iter().flatten() {
                if seen.insert(names[dep].to_string()) {
                    todo.push(dep);
                }
            }
        }
        closure.insert(names[id].to_string(), seen);
    }
    closure
}

#[test]
fn the_learning_core_and_the_processes_depend_on_no_tool() {
    let closure = dependency_closure();
    let reaches = |krate: &str, dep: &str| closure[krate].contains(dep);
    for dep in [
        // (png is not here: the simulator's camera writes its frames with it.)
        "plotters",
        "gif",
        "indicatif",
        "arrow-array",
        "parquet",
        "zenoh",
        "tokio",
        "cabc-outputs",
        "cabc-analysis",
        "cabc-export",
        "cabc-bus",
    ] {
        assert!(
            !reaches("cabc-learning", dep),
            "cabc-learning depends on {dep}"
        );
    }
    for process in ["cabc-learner", "cabc-actor", "cabc-expert"] {
        for dep in [
            "arrow-array",
            "parquet",
            "cabc-export",
            "cabc-analysis",
            "cabc-bench",
            "cabc-robust",
        ] {
            assert!(!reaches(process, dep), "{process} depends on {dep}");
        }
    }
    // The sinks know the core, the core knows no sink; the analysis reads run folders without the core's training.
    assert!(reaches("cabc-outputs", "cabc-learning"));
    assert!(!reaches("cabc-analysis", "cabc-bench") && !reaches("cabc-analysis", "cabc-learner"));
    // The sanity of the closure itself: the learner process does reach zenoh and the core.
    assert!(reaches("cabc-learner", "zenoh") && reaches("cabc-learner", "cabc-learning"));
}
