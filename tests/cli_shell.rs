//! What a shell user gets besides the subcommands: the version, and
//! completion scripts for the usual shells.

// Its `ndr` only.
#[allow(dead_code)]
mod cli_common;

use cli_common::ndr;

#[test]
fn version_is_the_packages() {
    let out = ndr(&["--version"]);
    assert!(out.status.success());
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        format!("ndr {}", env!("CARGO_PKG_VERSION"))
    );
}

#[test]
fn completions_name_the_subcommands_and_their_options() {
    for (shell, marker) in [
        ("bash", "_ndr()"),
        ("zsh", "#compdef ndr"),
        ("fish", "complete -c ndr"),
    ] {
        let out = ndr(&["completions", shell]);
        assert!(out.status.success(), "{shell}");
        let script = String::from_utf8_lossy(&out.stdout);
        assert!(script.contains(marker), "{shell}: {script}");
        for word in ["demo", "control", "--transport", "--regulation"] {
            // Fish spells an option `-l NAME`.
            let word = match (shell, word.strip_prefix("--")) {
                ("fish", Some(name)) => format!("-l {name} "),
                _ => word.to_string(),
            };
            assert!(script.contains(&word), "{shell} lacks {word}");
        }
    }
    let bad = ndr(&["completions", "cmd.exe"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("bash"));
}
