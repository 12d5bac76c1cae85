//! A recipe file of the operator's store as the API names it: a station's
//! directory and a file name, validated so it never leaves its
//! directory; a recipe as listed, and one with its text and content hash.
//! The store's `robot/` directory holds the robot programs (`065.prg`),
//! kept and versioned like the recipes.

use crate::ids::{RobotProgram, StationName};
use serde::{Deserialize, Serialize};
use std::fmt;

/// A recipe file of the store: a station's directory and a file name
/// (`welding`, `droog_dik.rcp`); validated so it never leaves its
/// directory.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(try_from = "RecipeFileWire", into = "RecipeFileWire")]
pub struct RecipeFile {
    station: StationName,
    file: String,
}

#[derive(Serialize, Deserialize)]
struct RecipeFileWire {
    station: StationName,
    file: String,
}

impl TryFrom<RecipeFileWire> for RecipeFile {
    type Error = String;
    fn try_from(w: RecipeFileWire) -> Result<Self, String> {
        RecipeFile::new(w.station, &w.file)
    }
}

impl From<RecipeFile> for RecipeFileWire {
    fn from(r: RecipeFile) -> Self {
        Self {
            station: r.station,
            file: r.file,
        }
    }
}

/// The store's directory of robot programs (no station may be named so).
pub const ROBOT_DIR: &str = "robot";

impl RecipeFile {
    /// `file` must be `name.rcp` with a name of lowercase letters, digits,
    /// `_` and `-` (at most 40); a name without `.rcp` gets it. In
    /// [`ROBOT_DIR`] it is a robot program, `NNN.prg` (`65`, `065` and
    /// `065.prg` are all `065.prg`).
    pub fn new(station: StationName, file: &str) -> Result<Self, String> {
        if station.as_str() == ROBOT_DIR {
            let number = file.trim().to_lowercase();
            let number = number.strip_suffix(".prg").unwrap_or(&number);
            return match RobotProgram::parse(number) {
                Ok(p) if number.len() <= 3 => Ok(Self::robot(p)),
                _ => Err(format!(
                    "robot program file name \"{}\": use the program's number, 1–999 (065.prg)",
                    crate::ids::excerpt(file)
                )),
            };
        }
        let file = file.trim().to_lowercase();
        let file = if file.ends_with(".rcp") {
            file
        } else {
            format!("{file}.rcp")
        };
        let stem = &file[..file.len() - 4];
        let ok = !stem.is_empty()
            && stem.len() <= 40
            && stem
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '-');
        if ok {
            Ok(Self { station, file })
        } else {
            Err(format!(
                "recipe file name \"{}\": use letters, digits, _ and - (at most 40), ending in .rcp",
                crate::ids::excerpt(&file)
            ))
        }
    }

    /// Robot program `p`'s file (`robot/065.prg`).
    pub fn robot(p: RobotProgram) -> Self {
        Self {
            station: StationName::new(ROBOT_DIR).unwrap_or_else(|_| unreachable!("a valid name")),
            file: format!("{:03}.prg", p.number()),
        }
    }

    /// The robot program it holds, if it is one.
    pub fn robot_program(&self) -> Option<RobotProgram> {
        if self.station.as_str() != ROBOT_DIR {
            return None;
        }
        RobotProgram::parse(self.file.strip_suffix(".prg")?).ok()
    }

    /// The station whose directory holds it.
    pub fn station(&self) -> &StationName {
        &self.station
    }

    /// The file name (`droog_dik.rcp`).
    pub fn file(&self) -> &str {
        &self.file
    }
}

impl fmt::Display for RecipeFile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.station, self.file)
    }
}

/// One recipe of the store, as listed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecipeInfo {
    /// Its file.
    pub file: RecipeFile,
    /// Its name (`#NAME`, else the file name), if the text says.
    pub name: Option<String>,
}

/// One recipe's text.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecipeText {
    /// Its file.
    pub file: RecipeFile,
    /// The text.
    pub text: String,
    /// Its content hash (the `base` of a later `RecipePut`).
    pub hash: u64,
}

/// The largest recipe file, in bytes (the thesis' recipes are under 2 KiB).
pub const MAX_RECIPE_BYTES: usize = 64 * 1024;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recipe_files_stay_in_their_directory() {
        let w = StationName::new("welding").expect("valid");
        let f = RecipeFile::new(w.clone(), "Droog_Dik").expect("valid");
        assert_eq!(f.to_string(), "welding/droog_dik.rcp");
        for bad in [
            "../x.rcp",
            "a/b.rcp",
            ".rcp",
            "",
            "x y.rcp",
            "x.rcp.rcp.",
            "ü.rcp",
        ] {
            assert!(RecipeFile::new(w.clone(), bad).is_err(), "{bad}");
        }
        // The same rule holds for what arrives on the wire.
        let wire = r#"{"station":"welding","file":"../../etc/passwd"}"#;
        assert!(serde_json::from_str::<RecipeFile>(wire).is_err());
        let ok = r#"{"station":"welding","file":"store.rcp"}"#;
        assert!(serde_json::from_str::<RecipeFile>(ok).is_ok());
    }

    #[test]
    fn a_robot_program_file_is_its_number() {
        let r = StationName::new(ROBOT_DIR).expect("valid");
        for ok in ["65", "065", "065.prg", " 65.PRG "] {
            let f = RecipeFile::new(r.clone(), ok).expect(ok);
            assert_eq!(f.to_string(), "robot/065.prg");
            assert_eq!(f.robot_program().map(RobotProgram::number), Some(65));
        }
        for bad in ["0", "1000", "0065", "x.prg", "../065.prg", "65.rcp", ""] {
            assert!(RecipeFile::new(r.clone(), bad).is_err(), "{bad}");
        }
        let w = StationName::new("welding").expect("valid");
        assert_eq!(
            RecipeFile::new(w, "065").expect("a recipe").robot_program(),
            None
        );
    }
}
