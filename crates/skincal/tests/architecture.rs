//! The map of ARCHITECTURE.md against the territory: the library's modules import exactly what the
//! map's import rules say (read from every `crate::` path of the non-test code), every module of
//! `lib.rs` is on the map, and the rules have no cycle.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The library's source directory.
fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The import rules of ARCHITECTURE.md: the lines `module: a b c` of its ```` ```imports ```` block.
fn rules() -> BTreeMap<String, BTreeSet<String>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../ARCHITECTURE.md");
    let text = std::fs::read_to_string(&path).unwrap();
    let block = text
        .split("```imports\n")
        .nth(1)
        .and_then(|rest| rest.split("```").next())
        .expect("ARCHITECTURE.md has an ```imports block");
    let mut rules = BTreeMap::new();
    for line in block.lines().filter(|l| !l.trim().is_empty()) {
        let (module, uses) = line
            .split_once(':')
            .unwrap_or_else(|| panic!("ARCHITECTURE.md: `{line}` is not `module: uses`"));
        let uses = uses.split_whitespace().map(str::to_string).collect();
        assert!(
            rules.insert(module.trim().to_string(), uses).is_none(),
            "ARCHITECTURE.md lists `{module}` twice"
        );
    }
    rules
}

/// The modules `lib.rs` declares.
fn declared_modules() -> BTreeSet<String> {
    std::fs::read_to_string(src().join("lib.rs"))
        .unwrap()
        .lines()
        .filter_map(|l| {
            let l = l.trim_start_matches("pub ").trim();
            l.strip_prefix("mod ")?
                .strip_suffix(';')
                .map(str::to_string)
        })
        .collect()
}

/// `text` without comments (doc links name modules they do not import) and without its test
/// module (tests may use anything; a `#[cfg(test)]` item elsewhere still counts).
fn code(text: &str) -> String {
    let text = match text.find("#[cfg(test)]\nmod ") {
        Some(at) => &text[..at],
        None => text,
    };
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The top-level names in the group that starts at `text[0] == '{'` (`{a::b, c::{d, e}}` → a, c).
fn group(text: &str) -> Vec<String> {
    let (mut depth, mut expect, mut names) = (0, true, Vec::new());
    for (i, c) in text.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    break;
                }
            }
            ',' if depth == 1 => expect = true,
            c if depth == 1 && expect && (c.is_alphanumeric() || c == '_') => {
                let name: String = text[i..]
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                names.push(name);
                expect = false;
            }
            _ => {}
        }
    }
    names
}

/// The crate modules a file names after `prefix` (`crate::` anywhere; `super::` in a module's
/// top file, where it is the crate).
fn named_after(code: &str, prefix: &str) -> Vec<String> {
    let mut names = Vec::new();
    for (at, _) in code.match_indices(prefix) {
        let before = &code[..at];
        if prefix == "super::" && before.ends_with("super::") {
            continue;
        }
        let rest = &code[at + prefix.len()..];
        if rest.starts_with('{') {
            names.extend(group(rest));
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            names.push(name);
        }
    }
    names.retain(|n| n != "super" && n != "self");
    names
}

/// Per module, the other modules it imports, each with one file that does.
fn imports() -> BTreeMap<String, BTreeMap<String, String>> {
    let mut found: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    let mut stack = vec![src()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            let relative = path.strip_prefix(src()).unwrap();
            let parts: Vec<String> = relative
                .iter()
                .map(|p| p.to_string_lossy().into_owned())
                .collect();
            if path.extension().is_none_or(|e| e != "rs") || parts == ["lib.rs"] {
                continue;
            }
            let module = parts[0].trim_end_matches(".rs").to_string();
            let top_file = parts.len() == 1 || parts == [module.clone(), "mod.rs".to_string()];
            let code = code(&std::fs::read_to_string(&path).unwrap());
            let mut names = named_after(&code, "crate::");
            if top_file {
                names.extend(named_after(&code, "super::"));
            }
            let entry = found.entry(module.clone()).or_default();
            for name in names.into_iter().filter(|n| *n != module) {
                entry
                    .entry(name)
                    .or_insert_with(|| relative.display().to_string());
            }
        }
    }
    found
}

#[test]
fn every_module_imports_exactly_what_the_map_allows() {
    let rules = rules();
    let modules = declared_modules();
    assert_eq!(
        rules.keys().cloned().collect::<BTreeSet<_>>(),
        modules,
        "ARCHITECTURE.md's import rules and lib.rs's modules differ"
    );
    let imports = imports();
    let mut wrong = Vec::new();
    for (module, allowed) in &rules {
        let used = imports.get(module).cloned().unwrap_or_default();
        for (name, file) in &used {
            if modules.contains(name) && !allowed.contains(name) {
                wrong.push(format!("{file} imports `{name}`, which `{module}` may not"));
            }
        }
        for name in allowed.iter().filter(|n| !used.contains_key(*n)) {
            wrong.push(format!(
                "ARCHITECTURE.md lets `{module}` import `{name}`, which it does not"
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn the_import_rules_have_no_cycle() {
    let rules = rules();
    // Kahn's algorithm: take modules that import nothing not yet taken.
    let mut taken: BTreeSet<&str> = BTreeSet::new();
    while taken.len() < rules.len() {
        let ready: Vec<&str> = rules
            .iter()
            .filter(|(m, uses)| {
                !taken.contains(m.as_str()) && uses.iter().all(|u| taken.contains(u.as_str()))
            })
            .map(|(m, _)| m.as_str())
            .collect();
        assert!(
            !ready.is_empty(),
            "a cycle among {:?}",
            rules
                .keys()
                .filter(|m| !taken.contains(m.as_str()))
                .collect::<Vec<_>>()
        );
        taken.extend(ready);
    }
}

#[test]
fn the_reader_of_imports_sees_groups_paths_and_the_crate_through_super() {
    // Hand-read truth for the parser the two tests above rely on.
    assert_eq!(group("{a::b, c::{d, e}, f}"), ["a", "c", "f"]);
    let code = code("use crate::{model::X, log::{Y, Z}};\n// crate::plan\nfn f() { crate::sim::run(); }\n#[cfg(test)]\nfn g() { crate::html::x(); }\n#[cfg(test)]\nmod tests { use crate::io; }");
    assert_eq!(
        named_after(&code, "crate::"),
        ["model", "log", "sim", "html"]
    );
    assert_eq!(
        named_after("use super::model; use super::super::x;", "super::"),
        ["model"]
    );
}
