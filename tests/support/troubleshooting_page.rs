// The check that every message a user can meet is listed in
// docs/guide/troubleshooting.md, `include!`d by the tests of ndr-core,
// ndr-net and the CLI that build each of their messages: one reading of
// the page for all three.
mod troubleshooting_page {
    // ndr-core is no_std: its tests have std, not its prelude.
    use std::string::{String, ToString};
    use std::vec::Vec;

    /// Panics naming the first of `messages` that no row of the page at
    /// `path` fits.
    pub(super) fn assert_listed(path: &str, messages: impl IntoIterator<Item = String>) {
        let page = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let patterns = patterns(&page);
        assert!(patterns.len() > 30, "{patterns:?}");
        for msg in messages {
            assert!(
                patterns.iter().any(|p| fits(&msg, p)),
                "not in docs/guide/troubleshooting.md: {msg}"
            );
        }
    }

    /// The starts of the messages the page lists: each backticked pattern
    /// of a table row's first cell, split at `…`.
    fn patterns(page: &str) -> Vec<Vec<String>> {
        page.lines()
            .filter(|l| l.starts_with("| `"))
            .filter_map(|l| l.split('|').nth(1))
            .flat_map(|cell| cell.split('`').skip(1).step_by(2))
            .map(|p| p.split('…').map(|s| s.trim().to_string()).collect())
            .collect()
    }

    /// Whether `msg` starts with the pattern's first piece (unless it is
    /// empty) and holds the others in order.
    fn fits(msg: &str, pieces: &[String]) -> bool {
        let mut at = 0;
        for (i, piece) in pieces.iter().enumerate() {
            if piece.is_empty() {
                continue;
            }
            match msg[at..].find(piece.as_str()) {
                Some(j) if i > 0 || j == 0 => at += j + piece.len(),
                _ => return false,
            }
        }
        true
    }
}
