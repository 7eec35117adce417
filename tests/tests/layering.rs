//! How `protocol` and the firmware are layered, read from their source (issue 21):
//!
//! - no import circle between modules of the same parent in `protocol/src` (`plc::gateway` ->
//!   `plc::axis_unit` -> `plc::gateway` would be one; so would `engine` -> `plc` -> `engine`
//!   between the top-level modules);
//! - the firmware (`src/`) asks the `Node`, never reaches through `Node::gateway()`.
//!
//! The module graph is built from the source text, not from rustc: a small lexer drops
//! comments, strings and `#[cfg(test)]` items (a test module may use whatever it tests), then
//! every path is resolved as rustc would for these forms: `use crate::a::b`, `use super::x`,
//! `use self::x`, groups (`use super::{a, b::c, self}`), renames, globs, and paths written in
//! the code (`crate::engine::Engine::new`, `super::gateway::Reason::Busy`, `map::MAP`). A path
//! is followed through the `use` declarations of the modules it passes, so `super::Gateway`
//! written in `plc/sync.rs` is a reference to `plc/gateway.rs` when `plc/mod.rs` re-exports it
//! from there. A reference from module `a::b::c` to `a::d::e` is an edge `b -> d` between the
//! children of `a`, their common parent; a reference to an ancestor's own items is no edge.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A module path from the crate root (`[]` is `lib.rs`).
type ModPath = Vec<String>;

// ---------------------------------------------------------------------------------------------
// Lexing

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    /// `::`
    PathSep,
    Punct(char),
    /// A literal or anything else that is not a path.
    Other,
}

#[derive(Clone, Debug)]
struct Token {
    tok: Tok,
    line: usize,
}

fn is_ident_start(c: char) -> bool {
    c == '_' || c.is_alphabetic()
}

fn is_ident_char(c: char) -> bool {
    c == '_' || c.is_alphanumeric()
}

/// Rust source as tokens, without comments (doc comments included) and string contents.
fn lex(source: &str) -> Vec<Token> {
    let chars: Vec<char> = source.chars().collect();
    let at = |i: usize| chars.get(i).copied().unwrap_or('\0');
    let mut tokens = Vec::new();
    let mut line = 1;
    let mut i = 0;
    while i < chars.len() {
        let (c, start_line) = (chars[i], line);
        let tok = if c == '\n' {
            line += 1;
            i += 1;
            continue;
        } else if c.is_whitespace() {
            i += 1;
            continue;
        } else if c == '/' && at(i + 1) == '/' {
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
            continue;
        } else if c == '/' && at(i + 1) == '*' {
            let mut depth = 0;
            while i < chars.len() {
                if chars[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    i += 2;
                } else if chars[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    line += usize::from(chars[i] == '\n');
                    i += 1;
                }
            }
            continue;
        } else if c == '"' {
            i = skip_string(&chars, i + 1, &mut line);
            Tok::Other
        } else if c == '\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a).
            if at(i + 1) == '\\' {
                i += 3; // the quote, the backslash and the character after it
                while i < chars.len() && chars[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if at(i + 2) == '\'' {
                i += 3;
            } else {
                i += 1;
                while i < chars.len() && is_ident_char(chars[i]) {
                    i += 1;
                }
            }
            Tok::Other
        } else if is_ident_start(c) {
            let start = i;
            while i < chars.len() && is_ident_char(chars[i]) {
                i += 1;
            }
            let word: String = chars[start..i].iter().collect();
            let hashes = (i..).take_while(|&j| at(j) == '#').count();
            if matches!(word.as_str(), "r" | "br" | "cr") && at(i + hashes) == '"' {
                // A raw string: r"..", r#".."#.
                i += hashes + 1;
                while i < chars.len()
                    && !(chars[i] == '"' && (1..=hashes).all(|k| at(i + k) == '#'))
                {
                    line += usize::from(chars[i] == '\n');
                    i += 1;
                }
                i += 1 + hashes;
                Tok::Other
            } else if word == "r" && hashes == 1 && is_ident_start(at(i + 1)) {
                // A raw identifier: r#name.
                let start = i + 1;
                i = start;
                while i < chars.len() && is_ident_char(chars[i]) {
                    i += 1;
                }
                Tok::Ident(chars[start..i].iter().collect())
            } else if matches!(word.as_str(), "b" | "c") && at(i) == '"' {
                i = skip_string(&chars, i + 1, &mut line);
                Tok::Other
            } else if word == "b" && at(i) == '\'' {
                i += 1;
                while i < chars.len() && chars[i] != '\'' {
                    i += if chars[i] == '\\' { 2 } else { 1 };
                }
                i += 1;
                Tok::Other
            } else {
                Tok::Ident(word)
            }
        } else if c.is_ascii_digit() {
            while i < chars.len() && is_ident_char(chars[i]) {
                i += 1;
            }
            Tok::Other
        } else if c == ':' && at(i + 1) == ':' {
            i += 2;
            Tok::PathSep
        } else {
            i += 1;
            Tok::Punct(c)
        };
        tokens.push(Token {
            tok,
            line: start_line,
        });
    }
    tokens
}

/// Skips a (byte) string's contents from just after its opening quote; returns the index after
/// the closing quote.
fn skip_string(chars: &[char], mut i: usize, line: &mut usize) -> usize {
    while i < chars.len() {
        match chars[i] {
            '\\' => i += 2,
            '"' => return i + 1,
            '\n' => {
                *line += 1;
                i += 1;
            }
            _ => i += 1,
        }
    }
    i
}

// ---------------------------------------------------------------------------------------------
// Reading a file: its `use` declarations, inline modules and paths

/// A name brought into a module by `use` (or, for a glob, every public name of a module).
#[derive(Clone, Debug)]
struct Import {
    /// The path as written (relative to the module it is written in).
    path: Vec<String>,
    glob: bool,
}

/// A path written in a module.
#[derive(Clone, Debug)]
struct Reference {
    /// The module it is written in (an inline module's path goes on from its file's).
    module: ModPath,
    path: Vec<String>,
    line: usize,
}

/// What the source says about the modules: children, imports, and every path written.
#[derive(Default, Debug)]
struct Crate {
    /// Modules with a file of their own.
    files: BTreeMap<ModPath, PathBuf>,
    /// Every module (file or inline) and its children.
    children: BTreeMap<ModPath, BTreeSet<String>>,
    /// Name -> what it stands for, per module.
    imports: BTreeMap<ModPath, BTreeMap<String, Import>>,
    /// Glob imports per module.
    globs: BTreeMap<ModPath, Vec<Import>>,
    references: Vec<(ModPath, Reference)>,
}

fn ident(t: Option<&Token>) -> Option<&str> {
    match t {
        Some(Token {
            tok: Tok::Ident(s), ..
        }) => Some(s),
        _ => None,
    }
}

fn is(t: Option<&Token>, tok: &Tok) -> bool {
    t.map(|t| &t.tok) == Some(tok)
}

impl Crate {
    /// Reads the module in `file` (module path `module`).
    fn read(&mut self, module: &ModPath, file: &Path, source: &str) {
        self.files.insert(module.clone(), file.to_owned());
        self.children.entry(module.clone()).or_default();
        let tokens = lex(source);
        // The inline modules open around the current token: (path, brace depth inside it).
        let mut scopes: Vec<(ModPath, usize)> = vec![(module.clone(), 0)];
        let mut depth = 0;
        let mut i = 0;
        while i < tokens.len() {
            let here = scopes.last().map(|s| s.0.clone()).unwrap_or_default();
            let tok = &tokens[i].tok;
            match tok {
                Tok::Punct('#') if is(tokens.get(i + 1), &Tok::Punct('[')) => {
                    let end = matching(&tokens, i + 1);
                    if is_cfg_test(&tokens[i + 2..end]) {
                        i = skip_item(&tokens, end + 1);
                    } else {
                        // Paths in attributes (derives) are other crates': nothing to resolve.
                        i = end + 1;
                    }
                    continue;
                }
                Tok::Punct('{') => depth += 1,
                Tok::Punct('}') => {
                    if scopes.len() > 1 && scopes.last().map(|s| s.1) == Some(depth) {
                        scopes.pop();
                    }
                    depth -= 1;
                }
                Tok::Ident(word) if word == "mod" => {
                    if let Some(name) = ident(tokens.get(i + 1)) {
                        self.children
                            .entry(here.clone())
                            .or_default()
                            .insert(name.to_owned());
                        if is(tokens.get(i + 2), &Tok::Punct('{')) {
                            let mut inner = here.clone();
                            inner.push(name.to_owned());
                            self.children.entry(inner.clone()).or_default();
                            depth += 1;
                            scopes.push((inner, depth));
                            i += 3;
                            continue;
                        }
                    }
                }
                Tok::Ident(word) if word == "use" => {
                    let mut j = i + 1;
                    let mut found = Vec::new();
                    use_tree(&tokens, &mut j, &mut Vec::new(), &mut found);
                    for (path, binding, line) in found {
                        let glob = binding.is_none();
                        let import = Import {
                            path: path.clone(),
                            glob,
                        };
                        match binding {
                            Some(name) if name != "_" => {
                                self.imports
                                    .entry(here.clone())
                                    .or_default()
                                    .insert(name, import);
                            }
                            Some(_) => {}
                            None => self.globs.entry(here.clone()).or_default().push(import),
                        }
                        self.references.push((
                            module.clone(),
                            Reference {
                                module: here.clone(),
                                path,
                                line,
                            },
                        ));
                    }
                    // Up to the `;`.
                    while j < tokens.len() && !is(tokens.get(j), &Tok::Punct(';')) {
                        j += 1;
                    }
                    i = j + 1;
                    continue;
                }
                Tok::Ident(first)
                    if is(tokens.get(i + 1), &Tok::PathSep)
                        && !(i > 0 && is(tokens.get(i - 1), &Tok::PathSep)) =>
                {
                    let line = tokens[i].line;
                    let mut path = vec![first.clone()];
                    let mut j = i + 1;
                    while is(tokens.get(j), &Tok::PathSep) {
                        match ident(tokens.get(j + 1)) {
                            Some(next) => {
                                path.push(next.to_owned());
                                j += 2;
                            }
                            None => break, // a turbofish `::<`
                        }
                    }
                    self.references.push((
                        module.clone(),
                        Reference {
                            module: here.clone(),
                            path,
                            line,
                        },
                    ));
                    i = j;
                    continue;
                }
                _ => {}
            }
            i += 1;
        }
    }

    fn parent(module: &[String]) -> ModPath {
        module[..module.len().saturating_sub(1)].to_vec()
    }

    /// Where `path`, written in `module`, leads: the module it names (`true`) or the module of
    /// the item it names (`false`); `None` for other crates and the prelude.
    fn resolve(&self, module: &[String], path: &[String], hops: usize) -> Option<(ModPath, bool)> {
        if hops > 32 {
            return None;
        }
        let (first, rest) = path.split_first()?;
        let mut rest = rest;
        let mut at: ModPath = match first.as_str() {
            "crate" => Vec::new(),
            "self" => module.to_vec(),
            "super" => {
                let mut at = Crate::parent(module);
                while rest.first().map(String::as_str) == Some("super") {
                    at = Crate::parent(&at);
                    rest = &rest[1..];
                }
                at
            }
            name => {
                if self.has_child(module, name) {
                    let mut at = module.to_vec();
                    at.push(name.to_owned());
                    at
                } else if let Some(import) = self.import(module, name) {
                    let (target, is_module) = self.resolve(module, &import.path, hops + 1)?;
                    if !is_module {
                        return Some((target, false));
                    }
                    target
                } else {
                    return None;
                }
            }
        };
        for name in rest {
            if self.has_child(&at, name) {
                at.push(name.clone());
            } else if let Some(import) = self.import(&at, name) {
                let (target, is_module) = self.resolve(&at, &import.path, hops + 1)?;
                if !is_module {
                    return Some((target, false));
                }
                at = target;
            } else if let Some(found) = self.through_globs(&at, name, hops) {
                return Some(found);
            } else {
                return Some((at, false));
            }
        }
        Some((at, true))
    }

    fn has_child(&self, module: &[String], name: &str) -> bool {
        self.children
            .get(module)
            .is_some_and(|children| children.contains(name))
    }

    fn import(&self, module: &[String], name: &str) -> Option<&Import> {
        self.imports
            .get(module)
            .and_then(|names| names.get(name))
            .filter(|import| !import.glob)
    }

    /// `name` in `module`, found through one of its glob imports (`pub use a::*`).
    fn through_globs(&self, module: &[String], name: &str, hops: usize) -> Option<(ModPath, bool)> {
        for glob in self.globs.get(module)? {
            let Some((source, true)) = self.resolve(module, &glob.path, hops + 1) else {
                continue;
            };
            if self.has_child(&source, name) || self.import(&source, name).is_some() {
                return self.resolve(&source, &[name.to_owned()], hops + 1);
            }
        }
        None
    }

    /// The module with a file that holds `module` (an inline module is part of its file's).
    fn file_of(&self, module: &[String]) -> ModPath {
        let mut module = module.to_vec();
        while !self.files.contains_key(&module) && !module.is_empty() {
            module.pop();
        }
        module
    }

    /// The edges between siblings: parent -> (from -> to -> where written).
    fn graph(&self) -> Graph {
        let mut graph = Graph::new();
        for (file_module, reference) in &self.references {
            let Some((target, _)) = self.resolve(&reference.module, &reference.path, 0) else {
                continue;
            };
            let target = self.file_of(&target);
            let common = file_module
                .iter()
                .zip(&target)
                .take_while(|(a, b)| a == b)
                .count();
            let (Some(from), Some(to)) = (file_module.get(common), target.get(common)) else {
                continue; // the same module, or one is the other's ancestor
            };
            let file = self.files.get(file_module).cloned().unwrap_or_default();
            let evidence = format!(
                "{}:{} `{}`",
                file.display(),
                reference.line,
                reference.path.join("::")
            );
            graph
                .entry(file_module[..common].to_vec())
                .or_default()
                .entry(from.clone())
                .or_default()
                .entry(to.clone())
                .or_default()
                .push(evidence);
        }
        graph
    }
}

/// parent module -> (child -> (sibling it refers to -> where)).
type Graph = BTreeMap<ModPath, BTreeMap<String, BTreeMap<String, Vec<String>>>>;

/// The index of the bracket closing the one at `open`.
fn matching(tokens: &[Token], open: usize) -> usize {
    let mut depth = 0usize;
    for (j, token) in tokens.iter().enumerate().skip(open) {
        match token.tok {
            Tok::Punct('(' | '[' | '{') => depth += 1,
            Tok::Punct(')' | ']' | '}') => {
                depth -= 1;
                if depth == 0 {
                    return j;
                }
            }
            _ => {}
        }
    }
    tokens.len()
}

/// Whether an attribute's contents are `cfg(test)`.
fn is_cfg_test(attribute: &[Token]) -> bool {
    let words: Vec<&Tok> = attribute.iter().map(|t| &t.tok).collect();
    words
        == [
            &Tok::Ident("cfg".into()),
            &Tok::Punct('('),
            &Tok::Ident("test".into()),
            &Tok::Punct(')'),
        ]
}

/// The index after the item starting at `start` (after its attributes): after its `;`, or its
/// closing brace.
fn skip_item(tokens: &[Token], start: usize) -> usize {
    let mut j = start;
    while is(tokens.get(j), &Tok::Punct('#')) {
        j = matching(tokens, j + 1) + 1;
    }
    while j < tokens.len() {
        match tokens[j].tok {
            Tok::Punct(';') => return j + 1,
            Tok::Punct('{') => return matching(tokens, j) + 1,
            Tok::Punct('(' | '[') => j = matching(tokens, j) + 1,
            _ => j += 1,
        }
    }
    j
}

/// Reads a use tree from `tokens[*j]`: every path it imports, with the name it binds (`None`
/// for a glob) and its line.
fn use_tree(
    tokens: &[Token],
    j: &mut usize,
    prefix: &mut Vec<String>,
    found: &mut Vec<(Vec<String>, Option<String>, usize)>,
) {
    let depth = prefix.len();
    if is(tokens.get(*j), &Tok::PathSep) {
        *j += 1; // `use ::core::..`: another crate
        prefix.push("::".into());
    }
    loop {
        let line = tokens.get(*j).map_or(0, |t| t.line);
        match tokens.get(*j).map(|t| &t.tok) {
            Some(Tok::Ident(name)) => {
                prefix.push(name.clone());
                *j += 1;
                if is(tokens.get(*j), &Tok::PathSep) {
                    *j += 1;
                    continue;
                }
                let mut path = prefix.clone();
                let mut binding = name.clone();
                if name == "self" {
                    path.pop();
                    binding = path.last().cloned().unwrap_or_default();
                }
                if ident(tokens.get(*j)) == Some("as") {
                    binding = ident(tokens.get(*j + 1)).unwrap_or("_").to_owned();
                    *j += 2;
                }
                if !path.is_empty() && path[0] != "::" {
                    found.push((path, Some(binding), line));
                }
                break;
            }
            Some(Tok::Punct('*')) => {
                *j += 1;
                if !prefix.is_empty() && prefix[0] != "::" {
                    found.push((prefix.clone(), None, line));
                }
                break;
            }
            Some(Tok::Punct('{')) => {
                *j += 1;
                loop {
                    match tokens.get(*j).map(|t| &t.tok) {
                        Some(Tok::Punct('}')) | None => {
                            *j += 1;
                            break;
                        }
                        Some(Tok::Punct(',')) => *j += 1,
                        _ => use_tree(tokens, j, prefix, found),
                    }
                }
                break;
            }
            _ => break,
        }
    }
    prefix.truncate(depth);
}

// ---------------------------------------------------------------------------------------------
// Cycles

/// The strongly connected components of more than one module (Tarjan), each sorted.
fn cycles(edges: &BTreeMap<String, BTreeMap<String, Vec<String>>>) -> Vec<Vec<String>> {
    let nodes: BTreeSet<&String> = edges
        .iter()
        .flat_map(|(from, to)| std::iter::once(from).chain(to.keys()))
        .collect();
    let nodes: Vec<&String> = nodes.into_iter().collect();
    let index_of = |name: &String| nodes.iter().position(|n| *n == name);
    let next: Vec<Vec<usize>> = nodes
        .iter()
        .map(|n| {
            edges
                .get(*n)
                .map(|to| to.keys().filter_map(index_of).collect())
                .unwrap_or_default()
        })
        .collect();

    struct Tarjan<'a> {
        next: &'a [Vec<usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        counter: usize,
        found: Vec<Vec<usize>>,
    }
    impl Tarjan<'_> {
        fn visit(&mut self, v: usize) {
            self.index[v] = Some(self.counter);
            self.low[v] = self.counter;
            self.counter += 1;
            self.stack.push(v);
            self.on_stack[v] = true;
            for &w in &self.next[v] {
                match self.index[w] {
                    None => {
                        self.visit(w);
                        self.low[v] = self.low[v].min(self.low[w]);
                    }
                    Some(iw) if self.on_stack[w] => self.low[v] = self.low[v].min(iw),
                    Some(_) => {}
                }
            }
            if Some(self.low[v]) == self.index[v] {
                let mut component = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on_stack[w] = false;
                    component.push(w);
                    if w == v {
                        break;
                    }
                }
                if component.len() > 1 {
                    self.found.push(component);
                }
            }
        }
    }
    let mut tarjan = Tarjan {
        next: &next,
        index: vec![None; nodes.len()],
        low: vec![0; nodes.len()],
        on_stack: vec![false; nodes.len()],
        stack: Vec::new(),
        counter: 0,
        found: Vec::new(),
    };
    for v in 0..nodes.len() {
        if tarjan.index[v].is_none() {
            tarjan.visit(v);
        }
    }
    let mut found: Vec<Vec<String>> = tarjan
        .found
        .into_iter()
        .map(|c| {
            let mut names: Vec<String> = c.into_iter().map(|v| nodes[v].clone()).collect();
            names.sort();
            names
        })
        .collect();
    found.sort();
    found
}

/// A shortest way round a component, from its first module back to it.
fn shortest_loop(
    edges: &BTreeMap<String, BTreeMap<String, Vec<String>>>,
    component: &[String],
) -> Vec<String> {
    let start = &component[0];
    let next = |at: &String| -> Vec<&String> {
        let to = edges.get(at).into_iter().flat_map(|t| t.keys());
        to.filter(|to| component.contains(to)).collect()
    };
    let mut came_from: BTreeMap<&String, &String> = BTreeMap::new();
    let mut queue = VecDeque::from([start]);
    while let Some(at) = queue.pop_front() {
        for to in next(at) {
            if to == start {
                let mut path = vec![at.clone()];
                let mut back = at;
                while let Some(&before) = came_from.get(back) {
                    path.push(before.clone());
                    back = before;
                }
                path.reverse();
                path.push(start.clone());
                return path;
            }
            if !came_from.contains_key(to) {
                came_from.insert(to, at);
                queue.push_back(to);
            }
        }
    }
    component.to_vec()
}

/// The cycles among the children of each parent, described: the modules, a way round, and
/// where each edge between them is written.
fn describe_cycles(graph: &Graph, parents: impl Fn(&ModPath) -> bool) -> Vec<String> {
    let mut out = Vec::new();
    for (parent, edges) in graph {
        if !parents(parent) {
            continue;
        }
        let name = if parent.is_empty() {
            "crate (top level)".to_owned()
        } else {
            parent.join("::")
        };
        for component in cycles(edges) {
            let mut text = format!(
                "in {name}: {{{}}}, e.g. {}\n",
                component.join(", "),
                shortest_loop(edges, &component).join(" -> ")
            );
            for from in &component {
                for (to, evidence) in edges.get(from).into_iter().flatten() {
                    if component.contains(to) {
                        let _ = writeln!(
                            text,
                            "    {from} -> {to}: {}{}",
                            evidence[0],
                            if evidence.len() > 1 {
                                format!(" (and {} more)", evidence.len() - 1)
                            } else {
                                String::new()
                            }
                        );
                    }
                }
            }
            out.push(text);
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// The source trees

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Every `.rs` file under `dir`, sorted.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mut dirs = vec![dir.to_owned()];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

/// `protocol/src`, read.
fn protocol() -> Crate {
    let src = root().join("protocol/src");
    let mut krate = Crate::default();
    let files = rust_files(&src);
    assert!(
        files.len() > 20,
        "{} has {} files?",
        src.display(),
        files.len()
    );
    for file in files {
        let relative = file.strip_prefix(&src).unwrap();
        let mut module: ModPath = relative
            .with_extension("")
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        if matches!(module.last().map(String::as_str), Some("mod" | "lib")) {
            module.pop();
        }
        let source = std::fs::read_to_string(&file).unwrap();
        krate.read(&module, relative, &source);
    }
    krate
}

// ---------------------------------------------------------------------------------------------
// The tests

/// Modules of the same parent do not import each other in a circle, in any directory of
/// `protocol/src` (the top level is checked below).
#[test]
fn protocol_has_no_import_circle_between_sibling_modules() {
    let graph = protocol().graph();
    let found = describe_cycles(&graph, |parent| !parent.is_empty());
    assert!(
        found.is_empty(),
        "import circles in protocol/src:\n{}",
        found.join("\n")
    );
}

/// The top-level modules of `protocol` (`engine`, `plc`, `modbus`, `node`, ...) do not import
/// each other in a circle either; a module's references count for its top-level ancestor
/// (`plc::gateway` using `crate::engine::Engine` is `plc -> engine`).
#[test]
fn protocol_top_level_modules_have_no_import_circle() {
    let graph = protocol().graph();
    let found = describe_cycles(&graph, |parent| parent.is_empty());
    assert!(
        found.is_empty(),
        "import circles between protocol's top-level modules:\n{}",
        found.join("\n")
    );
}

/// The firmware asks the `Node` what it needs; it does not reach through it to the gateway
/// (`node.gateway()...`, issue 21).
#[test]
fn firmware_never_calls_node_gateway() {
    let mut calls = Vec::new();
    for file in rust_files(&root().join("src")) {
        let tokens = lex(&std::fs::read_to_string(&file).unwrap());
        for (i, token) in tokens.iter().enumerate() {
            if token.tok != Tok::Ident("gateway".into()) || !is(tokens.get(i + 1), &Tok::Punct('('))
            {
                continue;
            }
            let before = |back: usize| i.checked_sub(back).and_then(|b| tokens.get(b));
            // `node.gateway()`, or `Node::gateway(&node)` (not a `gateway(..)` of the firmware's).
            let method = is(before(1), &Tok::Punct('.'));
            let path = is(before(1), &Tok::PathSep) && ident(before(2)) == Some("Node");
            if method || path {
                let relative = file.strip_prefix(root()).unwrap_or(&file).to_owned();
                calls.push(format!("{}:{}", relative.display(), token.line));
            }
        }
    }
    assert!(
        calls.is_empty(),
        "src/ calls Node::gateway() at:\n    {}",
        calls.join("\n    ")
    );
}

// The reader itself, on small sources.

/// A crate from `(module path, source)` pairs.
fn crate_of(modules: &[(&str, &str)]) -> Crate {
    let mut krate = Crate::default();
    for (path, source) in modules {
        let module: ModPath = if path.is_empty() {
            Vec::new()
        } else {
            path.split("::").map(str::to_owned).collect()
        };
        let file = PathBuf::from(format!("{}.rs", module.join("/")));
        krate.read(&module, &file, source);
    }
    krate
}

/// The edges of `parent`'s children, as `from -> to` strings.
fn edges(krate: &Crate, parent: &str) -> Vec<String> {
    let parent: ModPath = if parent.is_empty() {
        Vec::new()
    } else {
        parent.split("::").map(str::to_owned).collect()
    };
    let graph = krate.graph();
    let mut out = Vec::new();
    for (from, to) in graph.get(&parent).into_iter().flatten() {
        for to in to.keys() {
            out.push(format!("{from} -> {to}"));
        }
    }
    out
}

#[test]
fn reader_sees_every_form_of_path() {
    let krate = crate_of(&[
        ("", "pub mod engine; pub mod plc; pub mod time;"),
        ("engine", "pub struct Engine; pub mod config;"),
        ("engine::config", "pub struct Config;"),
        ("time", "pub struct Instant;"),
        (
            "plc",
            "mod a; mod b; mod c; mod d; mod e; mod f; mod g; mod h;\n\
             pub use g::{Thing as Renamed, Other};",
        ),
        // Grouped, nested, with self.
        ("plc::a", "use super::{b::{self, X}, c};"),
        // An in-path reference in code, through a turbofish.
        (
            "plc::b",
            "fn f() { let _ = super::d::make::<u8>(); crate::time::Instant; }",
        ),
        // `super` from an inline module is its file's module; a module's own inline child is no
        // edge.
        (
            "plc::c",
            "mod inner { pub fn f() { super::super::e::g(); } } use self::inner::f;",
        ),
        // Through the parent's re-export, renamed.
        ("plc::d", "fn f() -> super::Renamed { todo!() }"),
        // Globs, and a reference to an ancestor's own item (no edge).
        ("plc::e", "use crate::plc::f::*; use super::super::Top;"),
        // Test modules, strings and comments are not references.
        (
            "plc::f",
            "#[cfg(test)] mod tests { use super::super::a::X; }\n\
             fn s() { let _ = \"super::a::X\"; } // super::a::X\n\
             /* crate::plc::a::X */",
        ),
        (
            "plc::g",
            "pub struct Thing; pub struct Other; use crate::engine::config::Config;",
        ),
        // Lifetimes, raw strings, quotes in char literals: the lexer gets past them.
        (
            "plc::h",
            "fn f<'a>(x: &'a str) -> char { let _ = r#\"super::a::X\"#; let _ = b'\"';\n\
             let _ = '\\''; let _ = \"\\\"crate::plc::a\"; super::b::g(); '\"' }",
        ),
    ]);
    assert_eq!(
        edges(&krate, "plc"),
        ["a -> b", "a -> c", "b -> d", "c -> e", "d -> g", "e -> f", "h -> b"]
    );
    assert_eq!(edges(&krate, ""), ["plc -> engine", "plc -> time"]);
}

#[test]
fn cycles_are_found_and_described() {
    let krate = crate_of(&[
        ("", "mod m; mod n; mod o;"),
        (
            "m",
            "mod a; mod b; mod c; mod d; pub use a::A; pub use d::D;",
        ),
        ("m::a", "pub struct A; use super::b::B;"),
        ("m::b", "pub struct B; fn f() { super::c::g() }"),
        ("m::c", "pub fn g() {} use super::A;"),
        ("m::d", "pub struct D; use super::a::A;"),
        ("n", "use crate::o::X;"),
        ("o", "pub struct X; fn f() { crate::n::g() }"),
    ]);
    let graph = krate.graph();
    let inner = describe_cycles(&graph, |p| !p.is_empty());
    assert_eq!(inner.len(), 1, "{inner:?}");
    assert!(
        inner[0].starts_with("in m: {a, b, c}, e.g. a -> b -> c -> a\n"),
        "{}",
        inner[0]
    );
    assert!(
        inner[0].contains("    c -> a: m/c.rs:1 `super::A`"),
        "{}",
        inner[0]
    );
    let top = describe_cycles(&graph, |p| p.is_empty());
    assert_eq!(top.len(), 1, "{top:?}");
    assert!(top[0].starts_with("in crate (top level): {n, o}, e.g. n -> o -> n\n"));
}
