//! How `protocol` and the firmware are layered, read from their source with `syn` (issues 21, 36):
//! a reference from one top-level module of `protocol` to another points to the same layer of
//! [`LAYERS`] or a lower one; modules of the same parent never refer to each other in a circle,
//! at any level; the firmware (`src/`) asks the `Node`, never reaches through `Node::gateway()`.
//!
//! A reference is a `use` or a path of two segments or more (`crate::engine::Engine`,
//! `super::Gateway`, `map::MAP`, in macro calls too) outside `#[cfg(test)]` items, followed
//! through the `use` declarations and globs of the modules it passes (`super::Gateway` in
//! `plc/sync.rs` leads to `plc/gateway.rs` through `plc/mod.rs`'s `pub use`). A reference from
//! `a::b::c` to `a::d::e` is an edge `b -> d` between the children of `a`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use proc_macro2::{Delimiter, TokenStream, TokenTree};
use syn::visit::{self, Visit};
use syn::UseTree;

/// The layers of `protocol`'s top-level modules, lowest first, as `layer: modules`. A module may
/// refer to modules of its own layer (without a circle) and of the layers below, never above.
/// `values` know no protocol; `wire` is what the bytes on either side mean (`rc`, the Robo
/// Cylinder codec: frames, commands, replies, the memory map, the line; Modbus PDUs and framing,
/// the network settings). A new top-level module must be placed here: the test fails until it is.
const LAYERS: &str = "
    values: div time hex error bits types units axes
    wire:   rc net modbus
    engine: engine
    pio:    pio
    plc:    plc
    node:   node
";

type Mod = Vec<String>;

/// (from, to) -> where written: the edges between the children of one parent.
type Edges = BTreeMap<(String, String), Vec<String>>;

/// What the source says: its modules, what each imports, every reference and where it is; and,
/// while a file is read, the (inline) module being read and whether that is in a `#[cfg(test)]`
/// item (syn visits an item's attributes first).
#[derive(Default)]
struct Crate {
    files: BTreeMap<Mod, String>,
    modules: BTreeSet<Mod>,
    /// Per module: (the name bound, `*` for a glob; the path it stands for).
    imports: BTreeMap<Mod, Vec<(String, Mod)>>,
    /// (the module it is written in, the path, its line).
    refs: Vec<(Mod, Mod, usize)>,
    scope: Mod,
    test: bool,
}

impl<'ast> Visit<'ast> for Crate {
    fn visit_attribute(&mut self, attr: &'ast syn::Attribute) {
        let test = |a: &syn::Attribute| a.parse_args::<syn::Ident>().is_ok_and(|i| i == "test");
        self.test |= attr.path().is_ident("cfg") && test(attr);
    }
    fn visit_item(&mut self, item: &'ast syn::Item) {
        let test = self.test;
        visit::visit_item(self, item);
        self.test = test;
    }
    fn visit_impl_item(&mut self, item: &'ast syn::ImplItem) {
        let test = self.test;
        visit::visit_impl_item(self, item);
        self.test = test;
    }
    fn visit_item_mod(&mut self, item: &'ast syn::ItemMod) {
        item.attrs.iter().for_each(|a| self.visit_attribute(a));
        let inner = [self.scope.clone(), vec![item.ident.to_string()]].concat();
        if !self.test {
            self.modules.insert(inner.clone());
            let outer = std::mem::replace(&mut self.scope, inner);
            let items = item.content.iter().flat_map(|(_, items)| items);
            items.for_each(|i| self.visit_item(i));
            self.scope = outer;
        }
    }
    fn visit_item_use(&mut self, item: &'ast syn::ItemUse) {
        item.attrs.iter().for_each(|a| self.visit_attribute(a));
        if item.leading_colon.is_none() {
            self.use_tree(&item.tree, &[]);
        }
    }
    fn visit_path(&mut self, path: &'ast syn::Path) {
        if path.leading_colon.is_none() && path.segments.len() > 1 {
            let names = path.segments.iter().map(|s| s.ident.to_string()).collect();
            self.reference(names, path.segments[0].ident.span().start().line);
        }
        visit::visit_path(self, path);
    }
    /// A macro's arguments are tokens: a path is a token, then `::` and an identifier, repeated.
    fn visit_macro(&mut self, mac: &'ast syn::Macro) {
        let tokens = flat(mac.tokens.clone());
        for (i, first) in tokens.iter().enumerate() {
            let mut path = vec![first.to_string()];
            while let Some(TokenTree::Ident(next)) = path_step(&tokens, i + 3 * path.len() - 2) {
                path.push(next.to_string());
            }
            if path.len() > 1 && (i < 2 || path_step(&tokens, i - 2).is_none()) {
                self.reference(path, first.span().start().line);
            }
        }
    }
}

/// Tokens, each group followed by its own tokens.
fn flat(tokens: TokenStream) -> Vec<TokenTree> {
    let mut out = Vec::new();
    for token in tokens {
        let inner = match &token {
            TokenTree::Group(group) => flat(group.stream()),
            _ => Vec::new(),
        };
        out.push(token);
        out.extend(inner);
    }
    out
}

/// The token after a `::` at `at`.
fn path_step(tokens: &[TokenTree], at: usize) -> Option<&TokenTree> {
    let colon = |k: usize| matches!(tokens.get(k), Some(TokenTree::Punct(p)) if p.as_char() == ':');
    tokens.get(at + 2).filter(|_| colon(at) && colon(at + 1))
}

impl Crate {
    /// A crate from its files: (path, source), the paths under `src`.
    fn read(src: &str, files: &[(String, String)]) -> Crate {
        let mut krate = Crate::default();
        for (file, source) in files {
            let relative = file.strip_prefix(src).unwrap().trim_end_matches(".rs");
            let mut module: Mod = relative.split('/').map(str::to_owned).collect();
            if module.last().is_some_and(|m| m == "mod") || module == ["lib"] {
                module.pop();
            }
            let ast = syn::parse_file(source).unwrap_or_else(|e| panic!("{file}: {e}"));
            krate.files.insert(module.clone(), file.clone());
            krate.modules.insert(module.clone());
            (krate.scope, krate.test) = (module, false);
            krate.visit_file(&ast);
        }
        krate
    }

    fn reference(&mut self, path: Mod, line: usize) {
        if !self.test {
            self.refs.push((self.scope.clone(), path, line));
        }
    }

    fn use_tree(&mut self, tree: &UseTree, prefix: &[String]) {
        let join = |name: &syn::Ident| [prefix, &[name.to_string()]].concat();
        let (path, bound, span) = match tree {
            UseTree::Path(p) => return self.use_tree(&p.tree, &join(&p.ident)),
            UseTree::Group(g) => return g.items.iter().for_each(|t| self.use_tree(t, prefix)),
            UseTree::Glob(g) => (prefix.to_vec(), Some("*".into()), g.star_token.span),
            UseTree::Name(n) => (join(&n.ident), None, n.ident.span()),
            UseTree::Rename(r) => (join(&r.ident), Some(r.rename.to_string()), r.ident.span()),
        };
        let path: Mod = path.into_iter().filter(|name| name != "self").collect();
        let bound = bound.or_else(|| path.last().cloned()).unwrap_or_default();
        let imports = self.imports.entry(self.scope.clone()).or_default();
        imports.push((bound, path.clone()));
        self.reference(path, span.start().line);
    }

    /// `name` in module `at`: the module it is (`true`), or the module of the item it is.
    fn lookup(&self, at: &[String], name: &str, hops: usize) -> Option<(Mod, bool)> {
        let child = [at, &[name.to_owned()]].concat();
        if hops > 32 || self.modules.contains(&child) {
            return (hops <= 32).then_some((child, true));
        }
        let imports = self.imports.get(at).map(Vec::as_slice).unwrap_or_default();
        if let Some((_, path)) = imports.iter().find(|(bound, _)| bound == name) {
            return self.resolve(at, path, hops + 1);
        }
        let globs = imports.iter().filter(|(bound, _)| bound == "*");
        let sources = globs.filter_map(|(_, path)| self.resolve(at, path, hops + 1));
        let mut found = sources.filter(|(_, is_module)| *is_module);
        found.find_map(|(source, _)| self.lookup(&source, name, hops + 1))
    }

    /// Where `path`, written in `scope`, leads, as [`Crate::lookup`]; `None` outside the crate.
    fn resolve(&self, scope: &[String], path: &[String], hops: usize) -> Option<(Mod, bool)> {
        let mut at = scope.to_vec();
        for (i, name) in path.iter().enumerate() {
            match (i, name.as_str()) {
                (0, "crate") => at.clear(),
                (0, "self") => {}
                (_, "super") => drop(at.pop()?),
                _ => match self.lookup(&at, name, hops) {
                    Some((module, true)) => at = module,
                    Some(item) => return Some(item),
                    None if i == 0 => return None, // another crate, the prelude, a local name
                    None => return Some((at, false)),
                },
            }
        }
        Some((at, true))
    }

    /// The edges between the children of each parent, from the file that holds each reference
    /// to the file that holds what it names.
    fn edges(&self) -> BTreeMap<Mod, Edges> {
        let mut edges: BTreeMap<Mod, Edges> = BTreeMap::new();
        let file_of = |mut m: Mod| {
            while !self.files.contains_key(&m) && m.pop().is_some() {}
            m
        };
        for (scope, path, line) in &self.refs {
            let file = &file_of(scope.clone());
            let to = self.resolve(scope, path, 0).map(|(to, _)| to);
            let to = file_of(to.unwrap_or_else(|| file.clone()));
            let common = file.iter().zip(&to).take_while(|(a, b)| a == b).count();
            if let (Some(from), Some(to)) = (file.get(common), to.get(common)) {
                let at = format!("{}:{line} `{}`", self.files[file], path.join("::"));
                let siblings = edges.entry(file[..common].to_vec()).or_default();
                let key = (from.clone(), to.clone());
                siblings.entry(key).or_default().push(at);
            }
        }
        edges
    }
}

/// Every rule broken: an edge up the layers, a circle between siblings, a module in no layer.
fn violations(krate: &Crate, text: &str) -> Vec<String> {
    let mut layers = Vec::new();
    for (name, modules) in text.lines().filter_map(|line| line.split_once(':')) {
        layers.push((name.trim(), modules.split_whitespace().collect::<Vec<_>>()));
    }
    let layer = |m: &str| layers.iter().position(|(_, ms)| ms.contains(&m));
    let mut found = Vec::new();
    for m in krate.modules.iter().filter(|m| m.len() == 1) {
        if layer(&m[0]).is_none() {
            found.push(format!("`{}` is in no layer", m[0]));
        }
    }
    for (parent, edges) in krate.edges() {
        let name = |m: &String| {
            [parent.as_slice(), std::slice::from_ref(m)]
                .concat()
                .join("::")
        };
        for ((from, to), written) in &edges {
            let at = match written.len() {
                1 => written[0].clone(),
                n => format!("{} and {} more", written[0], n - 1),
            };
            if let (true, Some(f), Some(t)) = (parent.is_empty(), layer(from), layer(to)) {
                let (lf, lt) = (layers[f].0, layers[t].0);
                let up = format!("{at}: points up the layers, {from} ({lf}) -> {to} ({lt})");
                found.extend((f < t).then_some(up));
            }
            if let Some(back) = way(&edges, to, from, &mut BTreeSet::new()) {
                let circle: Vec<String> = [from].into_iter().chain(&back).map(name).collect();
                found.push(format!("{at}: circle, {}", circle.join(" -> ")));
            }
        }
    }
    found
}

/// A way from `from` to `to` along `edges`, if there is one.
fn way(edges: &Edges, from: &String, to: &String, seen: &mut BTreeSet<String>) -> Option<Mod> {
    if from == to {
        return Some(vec![to.clone()]);
    }
    for (_, next) in edges.keys().filter(|(f, _)| f == from) {
        if seen.insert(next.clone()) {
            if let Some(rest) = way(edges, next, to, seen) {
                return Some([vec![from.clone()], rest].concat());
            }
        }
    }
    None
}

/// The lines where `source` calls `.gateway(..)` or `Node::gateway(..)`.
fn gateway_calls(source: &str) -> Vec<usize> {
    let tokens = flat(source.parse().unwrap());
    let mut lines = Vec::new();
    for (i, token) in tokens.iter().enumerate().skip(1) {
        let paren = Delimiter::Parenthesis;
        let call = matches!(tokens.get(i + 1), Some(TokenTree::Group(g)) if g.delimiter() == paren);
        let dot = tokens[i - 1].to_string() == ".";
        let node = i >= 3 && tokens[i - 3].to_string() == "Node";
        let node = node && path_step(&tokens, i - 2).is_some();
        if token.to_string() == "gateway" && call && (dot || node) {
            lines.push(token.span().start().line);
        }
    }
    lines
}

/// Every `.rs` file under `dir` (paths from the repository's root) and its text.
fn rust_files(dir: &str, out: &mut Vec<(String, String)>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for entry in std::fs::read_dir(root.join(dir)).unwrap() {
        let path = format!("{dir}/{}", entry.unwrap().file_name().to_string_lossy());
        if root.join(&path).is_dir() {
            rust_files(&path, out);
        } else if path.ends_with(".rs") {
            let source = std::fs::read_to_string(root.join(&path)).unwrap();
            out.push((path, source));
        }
    }
}

#[test]
fn protocol_is_layered_without_circles() {
    let mut files = Vec::new();
    rust_files("protocol/src", &mut files);
    assert!(files.len() > 20, "protocol/src has {} files?", files.len());
    let found = violations(&Crate::read("protocol/src/", &files), LAYERS);
    let report = found.join("\n");
    assert!(found.is_empty(), "protocol/src's layers:\n{report}");
}

/// The firmware asks the `Node` what it needs; it does not reach through it to the gateway.
#[test]
fn firmware_never_calls_node_gateway() {
    let (mut files, mut calls) = (Vec::new(), Vec::new());
    rust_files("src", &mut files);
    for (file, source) in files {
        for line in gateway_calls(&source) {
            calls.push(format!("{file}:{line}"));
        }
    }
    let report = calls.join("\n");
    assert!(calls.is_empty(), "src/ calls Node::gateway() at:\n{report}");
}

// The checks themselves, on small crates: each file after a `//- path` line.

fn toy(text: &str) -> Vec<String> {
    let mut files = Vec::new();
    for file in text.split("//- ").skip(1) {
        let (path, source) = file.split_once('\n').unwrap();
        files.push((path.to_owned(), source.to_owned()));
    }
    violations(
        &Crate::read("", &files),
        "low: time frame\nhigh: engine plc",
    )
}

/// Only code counts: not a test module, a comment, a string, documentation or another crate.
#[test]
fn an_upward_reference_and_a_module_in_no_layer_are_reported() {
    let found = toy(r#"
//- lib.rs
mod time; mod frame; mod engine; mod plc; mod stray;
//- time.rs
use core::fmt; use ::core::mem; fn f() { fmt::Debug; }
#[cfg(test)] mod tests { use crate::plc::Plc; }
// crate::plc::Plc
/// [`Plc`](crate::plc::Plc)
fn g() { let _ = "crate::plc::Plc"; }
//- frame.rs
fn f() {
    crate::engine::Engine::new();
}
//- engine.rs
pub struct Engine; use crate::time::Instant;
//- plc.rs
pub struct Plc; use crate::{engine::Engine, frame};
//- stray.rs
"#);
    let up = "frame.rs:2 `crate::engine::Engine::new`: points up the layers, frame (low) -> engine (high)";
    assert_eq!(found, ["`stray` is in no layer", up]);
}

/// Through a re-export, a rename, a macro's arguments, a glob and an inline module.
#[test]
fn circles_are_reported_at_every_level() {
    let found = toy("
//- lib.rs
mod time; mod frame; mod engine; mod plc;
//- time.rs
pub struct Instant; fn f() -> crate::frame::Frame { todo!() }
//- frame.rs
pub struct Frame; use crate::time::Instant;
//- engine.rs
//- plc/mod.rs
mod a; mod b; mod c; pub use b::{self, B as Bee};
//- plc/a.rs
pub struct A; use super::Bee;
//- plc/b.rs
pub struct B; fn f() { assert!(super::c::g::<u8>()); }
//- plc/c.rs
pub fn g<T>() -> bool { true }
mod inner { use super::super::a::*; }
");
    let expected = [
        "frame.rs:1 `crate::time::Instant`: circle, frame -> time -> frame",
        "time.rs:1 `crate::frame::Frame`: circle, time -> frame -> time",
        "plc/a.rs:1 `super::Bee`: circle, plc::a -> plc::b -> plc::c -> plc::a",
        "plc/b.rs:1 `super::c::g`: circle, plc::b -> plc::c -> plc::a -> plc::b",
        "plc/c.rs:2 `super::super::a`: circle, plc::c -> plc::a -> plc::b -> plc::c",
    ];
    assert_eq!(found, expected);
}

#[test]
fn gateway_calls_are_found_in_code_and_macros() {
    let source = r#"fn f(node: &Node) {
        node.gateway().x();
        log!("{}", Node::gateway(node));
        gateway(1); // node.gateway()
    }"#;
    assert_eq!(gateway_calls(source), [2, 3]);
}
