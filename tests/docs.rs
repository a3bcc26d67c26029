//! The README and docs/ link to files and headings that exist: every relative link names a
//! file of the repository, and every `#anchor` a heading of its file, as GitHub writes
//! heading anchors (a renamed heading left two links dead before this test).

use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// GitHub's anchor for a heading: lower case, without what is not a letter, a digit, `-`,
/// `_` or a space, spaces made `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | ' '))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The file's lines outside fenced code blocks.
fn prose(text: &str) -> Vec<&str> {
    let mut fenced = false;
    text.lines()
        .filter(|l| {
            if l.trim_start().starts_with("```") {
                fenced = !fenced;
                return false;
            }
            !fenced
        })
        .collect()
}

/// The anchors of a Markdown file's headings (a repeated heading's later ones with -1, -2…).
fn anchors(text: &str) -> HashSet<String> {
    let mut seen: HashSet<String> = HashSet::new();
    let mut out = HashSet::new();
    for line in prose(text) {
        let Some(heading) = line.strip_prefix('#') else { continue };
        let heading = heading.trim_start_matches('#');
        if !heading.starts_with(' ') {
            continue;
        }
        let base = slug(heading);
        let mut anchor = base.clone();
        let mut k = 0;
        while !seen.insert(anchor.clone()) {
            k += 1;
            anchor = format!("{base}-{k}");
        }
        out.insert(anchor);
    }
    out
}

/// The targets of a Markdown file's inline links and images (`](target)`), outside code.
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in prose(text) {
        // Inline code is not a link: only the text outside backticks is read.
        let outside: String = line.split('`').step_by(2).collect::<Vec<_>>().join(" ");
        let mut rest = outside.as_str();
        while let Some(i) = rest.find("](") {
            rest = &rest[i + 2..];
            let end = rest.find(')').unwrap_or(rest.len());
            let target = rest[..end].split_whitespace().next().unwrap_or("");
            out.push(target.to_string());
            rest = &rest[end..];
        }
    }
    out
}

/// Every broken link of `files` (paths relative to `root`), as "file: target".
fn broken(root: &Path, files: &[PathBuf]) -> Vec<String> {
    let mut bad = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(root.join(file)).expect("a doc");
        for target in links(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = target.split_once('#').map_or((target.as_str(), None), |(p, a)| (p, Some(a)));
            let dest = if path.is_empty() { file.clone() } else { file.parent().unwrap_or(Path::new("")).join(path) };
            let full = root.join(&dest);
            if !full.exists() {
                bad.push(format!("{}: {target} (no such file)", file.display()));
                continue;
            }
            if let Some(anchor) = anchor.filter(|_| dest.extension().is_some_and(|e| e == "md")) {
                let text = std::fs::read_to_string(&full).expect("a linked doc");
                if !anchors(&text).contains(anchor) {
                    bad.push(format!("{}: {target} (no such heading)", file.display()));
                }
            }
        }
    }
    bad
}

fn docs(root: &Path) -> Vec<PathBuf> {
    let mut files = vec![PathBuf::from("README.md")];
    let mut md: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .filter_map(|p| p.strip_prefix(root).ok().map(Path::to_path_buf))
        .collect();
    md.sort();
    files.extend(md);
    files
}

#[test]
fn every_link_of_the_docs_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let files = docs(root);
    assert!(files.len() > 5, "{files:?}");
    let bad = broken(root, &files);
    assert!(bad.is_empty(), "broken links:\n{}", bad.join("\n"));
}

/// The checker itself: GitHub's anchors for headings with punctuation, dashes and repeats,
/// and a dead file, a dead heading, a live one and one in inline code found as such.
#[test]
fn the_checker_finds_dead_links_and_spares_live_ones() {
    assert_eq!(
        slug("71–74: the first real GPU, and the host work (2026-12-04)"),
        "7174-the-first-real-gpu-and-the-host-work-2026-12-04"
    );
    assert_eq!(slug("What `.svo` format 4 cost"), "what-svo-format-4-cost");
    let a = anchors("# A\n\n```\n# not a heading\n```\n## A\n### B_c d\n#no\n");
    let want: HashSet<String> = ["a", "a-1", "b_c-d"].into_iter().map(String::from).collect();
    assert_eq!(a, want);
    let dir = std::env::temp_dir().join(format!("voxray-docs-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("docs")).expect("temp dir");
    std::fs::write(dir.join("docs/b.md"), "# Here\n").expect("b.md");
    std::fs::write(
        dir.join("README.md"),
        "[ok](docs/b.md#here) [gone](docs/c.md) [dead](docs/b.md#there) [web](https://x.org/#y) `[code](x.md)`\n",
    )
    .expect("README");
    let bad = broken(&dir, &[PathBuf::from("README.md")]);
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(bad.len(), 2, "{bad:?}");
    assert!(bad[0].contains("docs/c.md") && bad[1].contains("#there"), "{bad:?}");
}
