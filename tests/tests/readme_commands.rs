//! Every command and path that README.md, CONTRIBUTING.md and docs/*.md show exists: each `scripts/...` path (a
//! `.sh` one executable), each `cargo <alias>`, each `--bin NAME`, each relative link and its
//! anchor, and each long flag shown for one of the host binaries (or a script) in a code block.
//! Not a shell parser: it looks for these patterns in the text, which is all the documents use.

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// README.md, CONTRIBUTING.md and every docs/*.md, with their paths relative to the repository.
fn documents() -> Vec<(PathBuf, String)> {
    let root = repo();
    let mut docs = vec![PathBuf::from("README.md"), PathBuf::from("CONTRIBUTING.md")];
    let mut extra: Vec<PathBuf> = fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .map(|p| p.strip_prefix(&root).unwrap().to_path_buf())
        .collect();
    extra.sort();
    docs.extend(extra);
    docs.into_iter()
        .map(|p| {
            let text = fs::read_to_string(root.join(&p)).unwrap();
            (p, text)
        })
        .collect()
}

fn is_word(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/')
}

/// Every `prefix` followed by a word (letters, digits, `_-./`), the word without trailing dots.
fn words_after<'a>(text: &'a str, prefix: &str) -> Vec<&'a str> {
    text.match_indices(prefix)
        .filter(|(i, _)| {
            // Not in the middle of another word (`tests/scripts/...` would not be ours).
            text[..*i]
                .chars()
                .next_back()
                .is_none_or(|c| !is_word(c) || c == '/' && prefix.starts_with('/'))
        })
        .map(|(i, _)| {
            let rest = &text[i + prefix.len()..];
            let end = rest.find(|c: char| !is_word(c)).unwrap_or(rest.len());
            rest[..end].trim_end_matches(['.', '/'])
        })
        .filter(|w| !w.is_empty())
        .collect()
}

/// The code blocks (between ``` fences) of a document, as lines.
fn code_blocks(text: &str) -> Vec<Vec<&str>> {
    let mut blocks = Vec::new();
    let mut current: Option<Vec<&str>> = None;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            match current.take() {
                Some(block) => blocks.push(block),
                None => current = Some(Vec::new()),
            }
        } else if let Some(block) = current.as_mut() {
            block.push(line);
        }
    }
    blocks
}

/// The text outside code blocks.
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

#[test]
fn every_script_shown_exists_and_is_executable() {
    use std::os::unix::fs::PermissionsExt;
    let mut problems = Vec::new();
    let mut seen = 0;
    for (doc, text) in documents() {
        for path in words_after(&text, "scripts/") {
            seen += 1;
            let file = repo().join("scripts").join(path);
            match fs::metadata(&file) {
                Err(_) => {
                    problems.push(format!("{}: scripts/{path} does not exist", doc.display()))
                }
                Ok(m) if path.ends_with(".sh") && m.permissions().mode() & 0o111 == 0 => problems
                    .push(format!(
                        "{}: scripts/{path} is not executable",
                        doc.display()
                    )),
                Ok(_) => {}
            }
        }
    }
    assert!(
        seen > 10,
        "found only {seen} script paths: the scan is broken"
    );
    assert!(problems.is_empty(), "{problems:#?}");
}

/// The aliases of `.cargo/config.toml`'s `[alias]` table.
fn cargo_aliases() -> BTreeSet<String> {
    let config = fs::read_to_string(repo().join(".cargo/config.toml")).unwrap();
    let table: toml::Table = config.parse().unwrap();
    table["alias"].as_table().unwrap().keys().cloned().collect()
}

/// Cargo's own commands (and `+toolchain`), which need no alias.
const CARGO_COMMANDS: &[&str] = &[
    "build", "run", "test", "check", "clippy", "fmt", "doc", "install", "rustc", "bench", "fuzz",
    "tree", "update", "metadata", "clean",
];

#[test]
fn every_cargo_alias_shown_is_defined() {
    let aliases = cargo_aliases();
    for needed in ["fw", "fw-run", "fw-f103", "fw-run-f103"] {
        assert!(aliases.contains(needed), "alias {needed} missing");
    }
    let mut problems = Vec::new();
    let mut used = BTreeSet::new();
    for (doc, text) in documents() {
        for word in words_after(&text, "cargo ") {
            if word.starts_with('+') || CARGO_COMMANDS.contains(&word) {
                continue;
            }
            used.insert(word.to_string());
            if !aliases.contains(word) {
                problems.push(format!("{}: `cargo {word}` is not an alias", doc.display()));
            }
        }
    }
    assert!(
        used.contains("fw-run"),
        "no alias found: the scan is broken"
    );
    assert!(problems.is_empty(), "{problems:#?}");
}

/// The host packages: each one's name and folder.
const HOST_PACKAGES: &[(&str, &str)] = &[("rc-tools", "tools"), ("rc-host", "tests")];

/// The host packages' binaries, from their manifests, each checked to have its source: the
/// binary's name and its package's.
fn binaries_by_package() -> Vec<(String, &'static str)> {
    let mut out = Vec::new();
    for (package, folder) in HOST_PACKAGES {
        let manifest = fs::read_to_string(repo().join(folder).join("Cargo.toml")).unwrap();
        let table: toml::Table = manifest.parse().unwrap();
        assert_eq!(table["package"]["name"].as_str(), Some(*package));
        for bin in table["bin"].as_array().unwrap() {
            let path = bin["path"].as_str().unwrap();
            assert!(
                repo().join(folder).join(path).is_file(),
                "{folder}/{path} missing"
            );
            out.push((bin["name"].as_str().unwrap().to_string(), *package));
        }
    }
    out
}

/// The host packages' binaries.
fn binaries() -> BTreeSet<String> {
    binaries_by_package()
        .into_iter()
        .map(|(bin, _)| bin)
        .collect()
}

/// Each `--bin NAME` is a binary, and of the package the same line names with `-p`, if any
/// (`cargo run -p rc-tools --bin rcgw`).
#[test]
fn every_binary_shown_exists() {
    let bins = binaries_by_package();
    let mut problems = Vec::new();
    let mut seen = 0;
    for (doc, text) in documents() {
        for line in text.lines() {
            let packages = words_after(line, "-p ");
            for name in words_after(line, "--bin ") {
                seen += 1;
                match bins.iter().find(|(bin, _)| bin == name) {
                    None => {
                        problems.push(format!("{}: --bin {name} is not a binary", doc.display()))
                    }
                    Some((_, package)) if !packages.is_empty() && !packages.contains(package) => {
                        problems.push(format!(
                            "{}: --bin {name} is a binary of {package}, not of {packages:?}",
                            doc.display()
                        ))
                    }
                    Some(_) => {}
                }
            }
        }
    }
    assert!(seen >= 3, "found only {seen} --bin: the scan is broken");
    assert!(problems.is_empty(), "{problems:#?}");
}

/// A heading's anchor as GitHub makes it.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The anchors of a document: its headings' and explicit `<a id="...">`.
fn anchors(text: &str) -> BTreeSet<String> {
    let mut out: BTreeSet<String> = prose(text)
        .lines()
        .filter(|l| l.starts_with('#'))
        .map(|l| slug(l.trim_start_matches('#')))
        .collect();
    out.extend(
        words_after(text, "<a id=\"")
            .into_iter()
            .map(str::to_string),
    );
    out
}

#[test]
fn every_relative_link_points_at_a_file_and_anchor() {
    let root = repo();
    let mut problems = Vec::new();
    let mut seen = 0;
    for (doc, text) in documents() {
        let prose = prose(&text);
        for (i, _) in prose.match_indices("](") {
            let rest = &prose[i + 2..];
            let target = &rest[..rest.find(')').unwrap_or(rest.len())];
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            seen += 1;
            let (path, anchor) = target.split_once('#').unwrap_or((target, ""));
            let file = if path.is_empty() {
                root.join(&doc)
            } else {
                root.join(doc.parent().unwrap()).join(path)
            };
            if !file.exists() {
                problems.push(format!("{}: link {target}: no such file", doc.display()));
                continue;
            }
            if !anchor.is_empty() {
                let linked = fs::read_to_string(&file).unwrap_or_default();
                if !anchors(&linked).contains(anchor) {
                    problems.push(format!("{}: link {target}: no such anchor", doc.display()));
                }
            }
        }
    }
    assert!(seen > 10, "found only {seen} links: the scan is broken");
    assert!(problems.is_empty(), "{problems:#?}");
}

/// Where each host binary's command line is defined (its flags are clap fields or `long`s), from
/// the repository's root.
fn binary_sources(bin: &str) -> Vec<&'static str> {
    match bin {
        "rcframe" => vec!["tools/src/bin/rcframe.rs", "tools/src/rcframe"],
        // Its actuator flags (--lead, --home, --twos, --ppr) are rcframe's `ScaleArgs`.
        "rc-commission" => vec!["tools/src/bin/rc-commission", "tools/src/rcframe"],
        "rc-sim" => vec!["tools/src/bin/rc-sim.rs", "tools/src/sim"],
        "rc-gateway-host" => vec!["tools/src/bin/rc-gateway-host.rs", "tools/src/host"],
        "rcgw" => vec!["tools/src/bin/rcgw"],
        "bench" => vec!["tests/src/bin/bench"],
        "demo" => vec!["tests/src/bin/demo.rs"],
        "regmap" => vec!["tests/src/bin/regmap.rs"],
        other => panic!("binary {other}: add where its flags are defined"),
    }
}

fn read_tree(path: &Path, out: &mut String) {
    if path.is_dir() {
        for entry in fs::read_dir(path).unwrap() {
            read_tree(&entry.unwrap().path(), out);
        }
    } else if path.extension().is_some_and(|x| x == "rs" || x == "sh") {
        out.push_str(&fs::read_to_string(path).unwrap());
    }
}

/// Whether `source` defines the long flag `flag` (without its dashes): as the literal
/// `"flag"` (a `long = "..."`), or as a whole identifier `flag` with `_` for `-` (a clap field).
fn defines(source: &str, flag: &str) -> bool {
    if source.contains(&format!("\"{flag}\"")) || source.contains(&format!("\"--{flag}")) {
        return true;
    }
    let ident = flag.replace('-', "_");
    source.match_indices(&ident).any(|(i, _)| {
        let before = source[..i].chars().next_back();
        let after = source[i + ident.len()..].chars().next();
        let boundary = |c: Option<char>| c.is_none_or(|c| !(c.is_alphanumeric() || c == '_'));
        boundary(before) && boundary(after)
    })
}

/// The long flags of a command line's part that belongs to the program (after cargo's ` -- `).
fn flags(line: &str) -> Vec<&str> {
    let line = line.split(" #").next().unwrap_or(line);
    let part = match line.find("cargo ") {
        Some(_) => match line.split_once(" -- ") {
            Some((_, program)) => program,
            None => return Vec::new(),
        },
        None => line,
    };
    part.split(|c: char| c.is_whitespace() || c == '"')
        .filter(|w| w.starts_with("--") && w.len() > 2)
        .map(|w| {
            w.trim_start_matches('-')
                .split('=')
                .next()
                .unwrap()
                .trim_end_matches(|c: char| !c.is_ascii_alphanumeric())
        })
        .filter(|w| !w.is_empty())
        .collect()
}

#[test]
fn every_flag_shown_in_a_code_block_is_defined() {
    let bins = binaries();
    let root = repo();
    let mut problems = Vec::new();
    let mut checked = 0;
    for (doc, text) in documents() {
        for block in code_blocks(&text) {
            // The binary a block is about: the one it names (a `P=...` line of flags belongs to
            // the block's binary).
            let named: BTreeSet<&str> = bins
                .iter()
                .map(String::as_str)
                .filter(|b| block.iter().any(|l| l.contains(&format!("{b} "))))
                .collect();
            for line in &block {
                let script = line
                    .split_whitespace()
                    .next()
                    .filter(|w| w.starts_with("scripts/"));
                let source = if let Some(script) = script {
                    let mut s = String::new();
                    read_tree(&root.join(script), &mut s);
                    (script.to_string(), s)
                } else {
                    let on_line: Vec<&str> = named
                        .iter()
                        .copied()
                        .filter(|b| line.contains(&format!("{b} ")))
                        .collect();
                    let bin = match (on_line.as_slice(), named.len()) {
                        ([bin], _) => *bin,
                        ([], 1) => *named.iter().next().unwrap(),
                        _ => continue,
                    };
                    let mut s = String::new();
                    for path in binary_sources(bin) {
                        let path = root.join(path);
                        assert!(path.exists(), "{} missing", path.display());
                        read_tree(&path, &mut s);
                    }
                    (bin.to_string(), s)
                };
                for flag in flags(line) {
                    checked += 1;
                    if !defines(&source.1, flag) {
                        problems.push(format!(
                            "{}: `--{flag}` is not a flag of {} ({line})",
                            doc.display(),
                            source.0
                        ));
                    }
                }
            }
        }
    }
    assert!(
        checked > 20,
        "checked only {checked} flags: the scan is broken"
    );
    assert!(problems.is_empty(), "{problems:#?}");
}

/// The paths of docs/development.md's Layout table, in order: a name with a `/` is from the
/// repository's root (and sets the folder of the names after it: a file's folder, or itself), a
/// bare name is in that folder ("`protocol/src/frame.rs`, `deframer.rs`", "`src/` (`main.rs`)").
fn layout_paths(doc: &str) -> Vec<String> {
    let start = doc.find("## Layout").expect("a Layout section");
    let table = doc[start..]
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2);
    let mut out = Vec::new();
    for row in table {
        let first = row.trim_matches('|').split('|').next().unwrap_or("");
        let mut folder = String::new();
        for (i, token) in first.split('`').enumerate() {
            if i % 2 == 0 || token.is_empty() {
                continue;
            }
            let path = if token.contains('/') {
                folder = match token.rfind('/') {
                    Some(at) if at + 1 == token.len() => token.to_string(),
                    Some(at) => token[..=at].to_string(),
                    None => String::new(),
                };
                token.to_string()
            } else {
                format!("{folder}{token}")
            };
            out.push(path);
        }
    }
    out
}

/// docs/development.md's Layout table is the tree's: every path it names exists, and it names
/// every folder at the repository's root, every crate of the workspace, every file and folder of
/// `src/`, `protocol/src/`, `tools/src/` and `tests/src/`, every board module and every host
/// program.
#[test]
fn the_layout_table_matches_the_tree() {
    let root = repo();
    let doc = fs::read_to_string(root.join("docs/development.md")).unwrap();
    let paths = layout_paths(&doc);
    assert!(
        paths.len() > 20,
        "found only {} paths: the scan is broken",
        paths.len()
    );
    let mut problems: Vec<String> = paths
        .iter()
        .filter(|p| !root.join(p).exists())
        .map(|p| format!("{p}: no such path"))
        .collect();
    let named = |p: &str| paths.iter().any(|q| q == p || q.starts_with(p));
    let manifest = fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let members = manifest
        .lines()
        .find(|l| l.starts_with("members"))
        .expect("workspace members");
    for member in members.split('"').skip(1).step_by(2) {
        if !named(&format!("{member}/")) {
            problems.push(format!("workspace member {member}/ not in the table"));
        }
    }
    let mut expected = Vec::new();
    for entry in fs::read_dir(root.join("src/board")).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        expected.push(format!("src/board/{name}"));
    }
    for entry in fs::read_dir(&root).unwrap() {
        let entry = entry.unwrap();
        let name = entry.file_name().into_string().unwrap();
        // Not git's, cargo's or an editor's, nor the build's output.
        if entry.path().is_dir() && !name.starts_with('.') && name != "target" {
            expected.push(format!("{name}/"));
        }
    }
    for folder in ["protocol/src", "src", "tools/src", "tests/src"] {
        for entry in fs::read_dir(root.join(folder)).unwrap() {
            let entry = entry.unwrap();
            let name = entry.file_name().into_string().unwrap();
            if entry.path().is_dir() {
                expected.push(format!("{folder}/{name}/"));
            } else {
                expected.push(format!("{folder}/{name}"));
            }
        }
    }
    for path in expected {
        if !named(&path) {
            problems.push(format!("{path} not in the table"));
        }
    }
    // Every host program, by name.
    let table = &doc[doc.find("## Layout").unwrap()..];
    for folder in ["tools/src/bin", "tests/src/bin"] {
        for entry in fs::read_dir(root.join(folder)).unwrap() {
            let name = entry.unwrap().file_name().into_string().unwrap();
            let name = name.trim_end_matches(".rs");
            if !table.contains(&format!("`{name}`")) {
                problems.push(format!("{folder}/{name} not in the table"));
            }
        }
    }
    assert!(problems.is_empty(), "{problems:#?}");
}

/// docs/development.md's fuzzing section names every target of `protocol/fuzz` (in its text and
/// in its table of long runs), and no target that is gone.
#[test]
fn the_fuzzing_section_names_every_target() {
    let root = repo();
    let manifest = fs::read_to_string(root.join("protocol/fuzz/Cargo.toml")).unwrap();
    let targets: Vec<&str> = manifest
        .split("[[bin]]")
        .skip(1)
        .filter_map(|bin| bin.lines().find(|l| l.trim_start().starts_with("name")))
        .filter_map(|l| l.split('"').nth(1))
        .collect();
    assert!(
        targets.len() >= 4,
        "found only {targets:?}: the scan is broken"
    );
    let doc = fs::read_to_string(root.join("docs/development.md")).unwrap();
    let section = &doc[doc.find("## Fuzzing").expect("a Fuzzing section")..];
    let section = &section[..section[3..]
        .find("\n## ")
        .map_or(section.len(), |at| at + 3)];
    let mut problems = Vec::new();
    for target in &targets {
        if !section.contains(&format!("| `{target}` |")) {
            problems.push(format!("{target}: no row in the table of long runs"));
        }
    }
    for row in section.lines().filter(|l| l.starts_with("| `")) {
        let name = row.split('`').nth(1).unwrap_or("");
        if !targets.contains(&name) {
            problems.push(format!("the table names {name}, not a target"));
        }
    }
    assert!(problems.is_empty(), "{problems:#?}");
}
