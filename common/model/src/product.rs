//! What the records keep of a product and of the recipes that made it
//! (the welding plant's "which procedure, which settings" under ISO 3834):
//! every saved version of a recipe file, the versions an order ran, and an
//! order's record (in the shape of an ISA-95 job response).
//!
//! A version is named by its number (1, 2, … per file, never reused) and
//! identified by its [`VersionHash`]: the SHA-256 of its text, so a record
//! says exactly which text made a product, and a text changed outside the
//! store is a new version, never mistaken for an old one.

use crate::alarm::Alarm;
use crate::recipe_file::RecipeFile;
use crate::records::{Entry, Order};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::fmt;

/// The SHA-256 of a recipe text, as 64 lower-case hex digits.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct VersionHash(String);

impl VersionHash {
    /// The hash of `text`.
    pub fn of(text: &[u8]) -> Self {
        let digest = Sha256::digest(text);
        Self(digest.iter().map(|b| format!("{b:02x}")).collect())
    }

    /// The whole hash.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// Its first 12 digits, as listings show it.
    pub fn short(&self) -> &str {
        &self.0[..12]
    }
}

impl TryFrom<String> for VersionHash {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        if s.len() == 64 && s.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')) {
            Ok(Self(s))
        } else {
            Err(format!(
                "\"{}\" is not a recipe version hash (64 lower-case hex digits)",
                crate::ids::excerpt(&s)
            ))
        }
    }
}

impl From<VersionHash> for String {
    fn from(h: VersionHash) -> Self {
        h.0
    }
}

impl fmt::Display for VersionHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// The longest message a saved version may carry, in characters.
pub const MAX_VERSION_MESSAGE_CHARS: usize = 200;

/// One saved version of a recipe file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecipeVersion {
    /// The file.
    pub file: RecipeFile,
    /// Its number (1 for the first of the file).
    pub version: u32,
    /// The SHA-256 of its text.
    pub hash: VersionHash,
    /// Who saved it (a console user; the operator node for a text found
    /// in the store that no save made).
    pub author: String,
    /// When (ms since the Unix epoch).
    pub at_ms: i64,
    /// Why, as the author said (may be empty).
    pub message: String,
}

/// A recipe an order ran: the domain the cell knows it by, and the
/// version of its file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct UsedRecipe {
    /// The domain (`DIKDROOG`, `WELDING$DROOG_DIK`).
    pub domain: String,
    /// The file and its version.
    pub file: RecipeFile,
    /// Its version number.
    pub version: u32,
    /// The SHA-256 of its text.
    pub hash: VersionHash,
    /// What its text starts one level down: workstation recipes of a cell
    /// recipe, robot programs of a welding recipe (their domains,
    /// `WELDING$PROGRAM_012`, where the store delivers them; else the
    /// robot's own, `program 12`).
    pub starts: Vec<String>,
}

/// One run of an order: when it started, and the recipe versions it ran
/// (a restarted order has a run per start).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OrderRun {
    /// When the run started (ms since the Unix epoch).
    pub started_ms: i64,
    /// The cell recipe first, then the workstation recipes it starts.
    pub recipes: Vec<UsedRecipe>,
}

/// One job of a workstation (a conveyor move at the transport, a weld at
/// the welding station): when it started and ended, and how.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobRecord {
    /// The workstation.
    pub station: String,
    /// Its program invocation (`STORE`, `DROOG_DIK`).
    pub program: String,
    /// When its station first showed it running (None: not seen).
    pub started_ms: Option<i64>,
    /// When it ended.
    pub ended_ms: i64,
    /// How (`done`, `bad product`, `failed safe`, `alarm: …`).
    pub outcome: String,
}

/// What the records say of one order: the order, the recipe versions of
/// each run, each workstation job, its journal (questions and answers
/// with who gave them, reports) and the alarms raised during it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OrderRecord {
    /// The order (its start, end and result).
    pub order: Order,
    /// Each run, first first.
    pub runs: Vec<OrderRun>,
    /// Each workstation job of its runs, in the order they ended.
    #[serde(default)]
    pub jobs: Vec<JobRecord>,
    /// Its journal entries, oldest first.
    pub entries: Vec<Entry>,
    /// The alarms raised while it ran.
    pub alarms: Vec<Alarm>,
}

/// A line diff of two texts: each line of `old` and `new` with `' '`
/// (in both), `'-'` (only in `old`) or `'+'` (only in `new`), in the
/// order a reader follows (a longest common subsequence of lines).
pub fn line_diff<'a>(old: &'a str, new: &'a str) -> Vec<(char, &'a str)> {
    let a: Vec<&str> = old.lines().collect();
    let b: Vec<&str> = new.lines().collect();
    // Common head and tail first: an edit is usually a few lines.
    let head = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let tail = a[head..]
        .iter()
        .rev()
        .zip(b[head..].iter().rev())
        .take_while(|(x, y)| x == y)
        .count();
    let (ma, mb) = (&a[head..a.len() - tail], &b[head..b.len() - tail]);
    // lcs[i][j]: the longest common subsequence of ma[i..] and mb[j..].
    let mut lcs = vec![vec![0u32; mb.len() + 1]; ma.len() + 1];
    for i in (0..ma.len()).rev() {
        for j in (0..mb.len()).rev() {
            lcs[i][j] = if ma[i] == mb[j] {
                lcs[i + 1][j + 1] + 1
            } else {
                lcs[i + 1][j].max(lcs[i][j + 1])
            };
        }
    }
    let mut out: Vec<(char, &str)> = a[..head].iter().map(|l| (' ', *l)).collect();
    let (mut i, mut j) = (0, 0);
    while i < ma.len() || j < mb.len() {
        if i < ma.len() && j < mb.len() && ma[i] == mb[j] {
            out.push((' ', ma[i]));
            i += 1;
            j += 1;
        } else if i < ma.len() && (j == mb.len() || lcs[i + 1][j] >= lcs[i][j + 1]) {
            out.push(('-', ma[i]));
            i += 1;
        } else {
            out.push(('+', mb[j]));
            j += 1;
        }
    }
    out.extend(a[a.len() - tail..].iter().map(|l| (' ', *l)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_version_hash_is_the_sha256_of_the_text_and_checked_when_read() {
        let h = VersionHash::of(b"abc");
        assert_eq!(
            h.as_str(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(h.short(), "ba7816bf8f01");
        let json = serde_json::to_string(&h).expect("json");
        assert_eq!(serde_json::from_str::<VersionHash>(&json).ok(), Some(h));
        assert!(serde_json::from_str::<VersionHash>("\"BA78\"").is_err());
    }

    #[test]
    fn the_diff_keeps_common_lines_and_marks_the_edit() {
        let old = "a\nb\nc\nd\n";
        let new = "a\nB\nc\nd\ne\n";
        let d = line_diff(old, new);
        assert_eq!(
            d,
            vec![
                (' ', "a"),
                ('-', "b"),
                ('+', "B"),
                (' ', "c"),
                (' ', "d"),
                ('+', "e")
            ]
        );
        // Every line of each side is there, in its order.
        let side = |keep: char| -> Vec<&str> {
            d.iter()
                .filter(|(c, _)| *c == ' ' || *c == keep)
                .map(|(_, l)| *l)
                .collect()
        };
        assert_eq!(side('-'), old.lines().collect::<Vec<_>>());
        assert_eq!(side('+'), new.lines().collect::<Vec<_>>());
        assert!(line_diff(old, old).iter().all(|(c, _)| *c == ' '));
    }
}
