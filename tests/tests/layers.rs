//! The structure ARCHITECTURE.md draws, checked: each crate depends only on the crates below
//! it, the crates below the gateways on no network or async runtime (but the node and the
//! client), and no module of any crate imports from a module that imports from it (parent and
//! child modules apart: a child implements part of its parent).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use zmotor_tests::environment::repo_root;

/// Every crate, its folder, and the workspace crates it may depend on (normal dependencies).
const LAYERS: &[(&str, &str, &[&str])] = &[
    ("zmotor-msgs", "msgs", &[]),
    ("zmotor-bridge", "bridge", &[]),
    ("zmotor-core", "node/core", &["zmotor-msgs"]),
    // The emulators are witnesses: they owe nothing to the drivers (and the test below says so
    // of their dev-dependencies too); the drivers' test bench (`testing`) uses them.
    ("zmotor-emulators", "node/emulators", &["zmotor-msgs", "zmotor-core"]),
    ("zmotor-controllers", "node/controllers", &["zmotor-msgs", "zmotor-core", "zmotor-emulators"]),
    ("zmotor-ca-proto", "node/ca-proto", &["zmotor-msgs"]),
    ("zmotor-ros2-proto", "node/ros2-proto", &["zmotor-msgs"]),
    ("zmotor-inbox", "node/inbox", &[]),
    (
        "zmotor-deploy",
        "node/deploy",
        &["zmotor-msgs", "zmotor-bridge", "zmotor-core", "zmotor-controllers", "zmotor-ros2-proto"],
    ),
    (
        "zmotor-node",
        "node/node",
        &["zmotor-msgs", "zmotor-bridge", "zmotor-core", "zmotor-controllers", "zmotor-deploy", "zmotor-inbox"],
    ),
    ("zmotor-client", "node/client", &["zmotor-msgs", "zmotor-deploy"]),
    ("zmotor-ca", "node/ca", &["zmotor-msgs", "zmotor-ca-proto", "zmotor-client", "zmotor-deploy"]),
    ("zmotor-web", "node/web", &["zmotor-msgs", "zmotor-client", "zmotor-deploy"]),
    ("zmotor-ros2", "node/ros2", &["zmotor-msgs", "zmotor-ros2-proto", "zmotor-client", "zmotor-deploy"]),
    ("zmotor-sim-controller", "node/sim-controller", &["zmotor-core", "zmotor-emulators"]),
    (
        "zmotor",
        "node/cli",
        &[
            "zmotor-msgs",
            "zmotor-controllers",
            "zmotor-deploy",
            "zmotor-node",
            "zmotor-client",
            "zmotor-ca",
            "zmotor-web",
            "zmotor-ros2",
            "zmotor-emulators",
            "zmotor-sim-controller",
        ],
    ),
    (
        "zmotor-bench",
        "node/bench",
        &[
            "zmotor-msgs",
            "zmotor-core",
            "zmotor-controllers",
            "zmotor-deploy",
            "zmotor-client",
            "zmotor-ca-proto",
            "zmotor-ros2-proto",
            "zmotor-emulators",
            "zmotor-sim-controller",
        ],
    ),
    (
        "zmotor-fuzz",
        "tests/fuzz",
        &["zmotor-msgs", "zmotor-bridge", "zmotor-core", "zmotor-controllers", "zmotor-deploy", "zmotor-ros2-proto"],
    ),
];

/// Crates that move bytes on networks, sockets or an async runtime: below the gateways, only
/// the node and the client may use them.
const RUNTIME: &[&str] = &["zenoh", "zenoh-ext", "tokio", "tokio-serial", "axum", "socket2"];
const BELOW_THE_GATEWAYS: &[&str] = &[
    "zmotor-msgs",
    "zmotor-bridge",
    "zmotor-core",
    "zmotor-emulators",
    "zmotor-controllers",
    "zmotor-ca-proto",
    "zmotor-ros2-proto",
    "zmotor-inbox",
    "zmotor-deploy",
];

/// The names under `[dependencies]` of a Cargo.toml.
fn dependencies(manifest: &Path) -> BTreeSet<String> {
    let text = std::fs::read_to_string(manifest).unwrap();
    let toml: toml::Table = toml::from_str(&text).unwrap();
    toml.get("dependencies").and_then(|d| d.as_table()).map(|d| d.keys().cloned().collect()).unwrap_or_default()
}

#[test]
fn each_crate_uses_only_the_crates_below_it_and_the_core_no_runtime() {
    let root = repo_root();
    let workspace: toml::Table = toml::from_str(&std::fs::read_to_string(root.join("Cargo.toml")).unwrap()).unwrap();
    let members: BTreeSet<&str> =
        workspace["workspace"]["members"].as_array().unwrap().iter().map(|m| m.as_str().unwrap()).collect();
    for (name, folder, allowed) in LAYERS {
        let deps = dependencies(&root.join(folder).join("Cargo.toml"));
        for dep in deps.iter().filter(|d| d.starts_with("zmotor")) {
            assert!(
                allowed.contains(&dep.as_str()),
                "{name} depends on {dep}, which is not below it (ARCHITECTURE.md)"
            );
        }
        if BELOW_THE_GATEWAYS.contains(name) {
            let runtime: Vec<&String> = deps.iter().filter(|d| RUNTIME.contains(&d.as_str())).collect();
            assert!(runtime.is_empty(), "{name} is below the gateways and depends on {runtime:?}");
        }
        assert!(members.contains(folder), "{folder} is a workspace member");
    }
    let listed: BTreeSet<&str> = LAYERS.iter().map(|(_, folder, _)| *folder).collect();
    for member in members.iter().filter(|m| m.starts_with("node/") || ["msgs", "bridge"].contains(m)) {
        assert!(listed.contains(member), "{member} has no place in the layers (this test and ARCHITECTURE.md)");
    }
}

#[test]
fn the_emulators_owe_nothing_to_the_drivers() {
    let manifest = std::fs::read_to_string(repo_root().join("node/emulators/Cargo.toml")).unwrap();
    let toml: toml::Table = toml::from_str(&manifest).unwrap();
    for section in ["dependencies", "dev-dependencies", "build-dependencies"] {
        let names = toml.get(section).and_then(|d| d.as_table()).map(|d| d.keys().cloned().collect::<Vec<_>>());
        for name in names.unwrap_or_default() {
            assert!(
                ["zmotor-msgs", "zmotor-core"].contains(&name.as_str()) || !name.starts_with("zmotor"),
                "zmotor-emulators' {section} name {name}: a witness may not lean on what it witnesses"
            );
        }
    }
}

/// A module's path (`["engine", "record"]`) from its file, relative to `src`.
fn module_of(file: &Path) -> Vec<String> {
    let mut parts: Vec<String> = file.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    let last = parts.pop().unwrap();
    match last.as_str() {
        "lib.rs" | "main.rs" | "mod.rs" => {}
        other => parts.push(other.trim_end_matches(".rs").to_string()),
    }
    parts
}

/// Every `.rs` file under `dir`, relative to it.
fn sources(dir: &Path, under: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir.join(under)).unwrap() {
        let path = entry.unwrap().path();
        let relative = path.strip_prefix(dir).unwrap().to_path_buf();
        if path.is_dir() {
            sources(dir, &relative, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(relative);
        }
    }
}

/// The paths a file names with `crate::` or `super::`, made absolute (from the crate root).
fn named_paths(text: &str, module: &[String]) -> Vec<Vec<String>> {
    let mut paths = Vec::new();
    // Code only: comments and the file's tests say nothing of its imports.
    let code: String = text
        .split("#[cfg(test)]")
        .next()
        .unwrap_or("")
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n");
    for start in ["crate::", "super::"] {
        for (at, _) in code.match_indices(start) {
            if at > 0 && code[..at].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let rest = &code[at..];
            let end = rest.find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':')).unwrap_or(rest.len());
            let segments: Vec<String> = rest[..end].split("::").filter(|s| !s.is_empty()).map(str::to_string).collect();
            let mut absolute: Vec<String> = Vec::new();
            let mut base = module.to_vec();
            for segment in segments {
                match segment.as_str() {
                    "crate" => base.clear(),
                    "super" => {
                        base.pop();
                    }
                    _ => absolute.push(segment),
                }
            }
            paths.push(base.into_iter().chain(absolute).collect());
        }
    }
    paths
}

#[test]
fn no_module_imports_from_one_that_imports_from_it() {
    let root = repo_root();
    let mut cycles = Vec::new();
    for (name, folder, _) in LAYERS {
        let src = root.join(folder).join("src");
        let mut files = Vec::new();
        sources(&src, Path::new(""), &mut files);
        let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_of(f)).collect();
        let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
        for file in &files {
            let from = module_of(file);
            let text = std::fs::read_to_string(src.join(file)).unwrap();
            for path in named_paths(&text, &from) {
                // The deepest module the path names.
                let Some(to) = (0..=path.len()).rev().map(|n| path[..n].to_vec()).find(|m| modules.contains(m)) else {
                    continue;
                };
                let related = to.starts_with(&from) || from.starts_with(&to);
                if !related {
                    edges.entry(from.clone()).or_default().insert(to);
                }
            }
        }
        for (from, tos) in &edges {
            for to in tos {
                if reaches(&edges, to, from, &mut BTreeSet::new()) {
                    cycles.push(format!("{name}: {} → {} → … → {}", from.join("::"), to.join("::"), from.join("::")));
                }
            }
        }
    }
    assert!(cycles.is_empty(), "modules importing from each other:\n{}", cycles.join("\n"));
}

/// Whether `to` is reachable from `from`.
fn reaches(
    edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
    from: &Vec<String>,
    to: &Vec<String>,
    seen: &mut BTreeSet<Vec<String>>,
) -> bool {
    if from == to {
        return true;
    }
    if !seen.insert(from.clone()) {
        return false;
    }
    edges.get(from).is_some_and(|next| next.iter().any(|n| reaches(edges, n, to, seen)))
}
