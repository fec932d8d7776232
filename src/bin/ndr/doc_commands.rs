//! Every `ndr` command line in the README and the user guide parses, so
//! that a reader who copies one gets the command it shows (a renamed or
//! removed option fails here, not in a user's shell).

use std::path::{Path, PathBuf};

use clap::Parser as _;

use crate::Cli;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The README and every page of the guide.
fn pages() -> Vec<PathBuf> {
    let mut pages = vec![root().join("README.md")];
    let guide = root().join("docs/guide");
    let mut guide_pages: Vec<PathBuf> = std::fs::read_dir(&guide)
        .unwrap_or_else(|e| panic!("{}: {e}", guide.display()))
        .map(|entry| entry.expect("a directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    guide_pages.sort();
    assert!(guide_pages.len() >= 5, "the guide's pages: {guide_pages:?}");
    pages.extend(guide_pages);
    pages
}

/// The `ndr` invocations in `text`'s shell blocks: `(line number, argv)`.
fn command_lines(text: &str) -> Vec<(usize, Vec<String>)> {
    let mut lines = Vec::new();
    let mut in_shell = false;
    for (n, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if let Some(info) = trimmed.strip_prefix("```") {
            in_shell = !in_shell && matches!(info, "sh" | "shell" | "bash" | "console");
            continue;
        }
        if !in_shell {
            continue;
        }
        let command = trimmed.split(" #").next().unwrap_or_default().trim();
        let args = if let Some(rest) = command.strip_prefix("ndr ") {
            rest
        } else if let Some(rest) = command.strip_prefix("cargo run --release -- ") {
            rest
        } else {
            continue;
        };
        let mut argv = vec!["ndr".to_owned()];
        argv.extend(args.split_whitespace().map(str::to_owned));
        lines.push((n + 1, argv));
    }
    lines
}

#[test]
fn every_command_line_in_the_readme_and_the_guide_parses() {
    let mut checked = 0;
    for page in pages() {
        let text = std::fs::read_to_string(&page).expect("a readable page");
        for (line, argv) in command_lines(&text) {
            if let Err(e) = Cli::try_parse_from(&argv) {
                panic!(
                    "{}:{line}: `{}` does not parse:\n{e}",
                    page.display(),
                    argv.join(" ")
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 10, "only {checked} command lines found");
}

#[test]
fn a_command_line_that_does_not_parse_is_caught() {
    let text = "```sh\nndr demo --no-such-option   # a comment\nnot ndr\n```\nndr demo --x\n";
    let lines = command_lines(text);
    assert_eq!(
        lines,
        [(
            2,
            vec!["ndr".into(), "demo".into(), "--no-such-option".into()]
        )]
    );
    assert!(Cli::try_parse_from(&lines[0].1).is_err());
}

#[test]
fn every_guide_page_is_compiled_as_a_doctest() {
    let lib = std::fs::read_to_string(root().join("src/lib.rs")).expect("src/lib.rs");
    for page in pages() {
        let relative = page
            .strip_prefix(root())
            .map(Path::to_path_buf)
            .unwrap_or(page);
        let include = format!("include_str!(\"../{}\")", relative.display());
        assert!(
            lib.contains(&include),
            "src/lib.rs's `docs` module lacks {include}"
        );
    }
}
