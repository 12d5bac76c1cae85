//! Editing a recipe of the operator's recipe store in the user's editor,
//! for `falc store edit` and the TUI: fetch the text (or a template for a
//! new file), open `$VISUAL`/`$EDITOR` (else `vi`) on a private copy, and
//! send it back; the operator saves it only if the whole set checks clean
//! and nobody changed the file meanwhile. The copy is kept until the text
//! is saved, so nothing typed is lost when the checker has findings.

use crate::call::CALL_LIMIT;
use falc_bus::operator_service::CallError;
use falc_bus::Bus;
use falc_model::api::{ApiReply, ApiRequest};
use falc_model::ids::StationName;
use falc_model::recipe_file::{RecipeFile, RecipeText};
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The store's text of `file`, or None if there is no such file.
pub async fn fetch(
    bus: &Bus,
    operator: &StationName,
    file: &RecipeFile,
) -> Result<Option<RecipeText>, CallError> {
    match bus
        .api(operator, ApiRequest::RecipeList, CALL_LIMIT)
        .await?
    {
        ApiReply::Recipes(v) if v.iter().any(|r| &r.file == file) => {}
        ApiReply::Recipes(_) => return Ok(None),
        other => {
            return Err(CallError::Refused(format!(
                "unexpected answer to recipe-list: {other:?}"
            )))
        }
    }
    let request = ApiRequest::RecipeGet { file: file.clone() };
    match bus.api(operator, request, CALL_LIMIT).await? {
        ApiReply::Recipe(r) => Ok(Some(r)),
        other => Err(CallError::Refused(format!(
            "unexpected answer to recipe-get: {other:?}"
        ))),
    }
}

/// The text a new recipe starts from.
pub fn template(file: &RecipeFile) -> String {
    let stem = file.file().trim_end_matches(".rcp").to_uppercase();
    let name = if file.station().as_str() == "cell" {
        String::new()
    } else {
        format!("#{stem}\n")
    };
    format!(
        "{name}New recipe {file}. Lines not starting with -N are comments.\n\
         state | command | report (alarm) | criterion | next state (0 ends)\n\
         See recipes/README.md for the commands of each station.\n\n"
    )
}

/// One edit session of one recipe: the private copy and what it started from.
pub struct Session {
    /// The recipe.
    pub file: RecipeFile,
    /// The content hash the edit started from (None: a new file).
    pub base: Option<u64>,
    /// The private copy the editor works on.
    pub copy: PathBuf,
    original: String,
}

/// Why an edit cannot start: the operator API, or this machine.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// Fetching the recipe: no reply, or refused.
    #[error(transparent)]
    Call(#[from] CallError),
    /// The private copy could not be written.
    #[error("{0}")]
    Copy(String),
}

impl Session {
    /// Starts editing `file`: fetches it (or the template) into a copy.
    pub async fn open(
        bus: &Bus,
        operator: &StationName,
        file: &RecipeFile,
    ) -> Result<Self, OpenError> {
        let (text, base) = match fetch(bus, operator, file).await? {
            Some(r) => (r.text, Some(r.hash)),
            None => (template(file), None),
        };
        static EDITS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = EDITS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let copy = std::env::temp_dir().join(format!(
            "falc-{}-{}-{n}-{}",
            file.station(),
            std::process::id(),
            file.file()
        ));
        write_private(&copy, &text)
            .map_err(|e| OpenError::Copy(format!("{}: {e}", copy.display())))?;
        Ok(Self {
            file: file.clone(),
            base,
            copy,
            original: text,
        })
    }

    /// Runs the editor on the copy (the terminal must be the editor's).
    pub fn run_editor(&self) -> Result<(), String> {
        run_editor(&self.copy)
    }

    /// The edited text, or None if unchanged.
    pub fn edited(&self) -> Result<Option<String>, String> {
        let text = std::fs::read_to_string(&self.copy)
            .map_err(|e| format!("{}: {e}", self.copy.display()))?;
        Ok((text != self.original).then_some(text))
    }

    /// Sends the edited text: the operator's answer in words, or its
    /// refusal (the checker's findings, or why else).
    pub async fn save(
        &self,
        bus: &Bus,
        operator: &StationName,
        text: String,
    ) -> Result<String, String> {
        let request = ApiRequest::RecipePut {
            file: self.file.clone(),
            text,
            base: self.base,
            message: String::new(),
        };
        match bus
            .api(operator, request, CALL_LIMIT)
            .await
            .map_err(|e| e.to_string())?
        {
            ApiReply::Done(said) => {
                let _ = std::fs::remove_file(&self.copy);
                Ok(said)
            }
            other => Err(format!("unexpected answer to recipe-put: {other:?}")),
        }
    }

    /// Drops the edit (the copy too).
    pub fn discard(self) {
        let _ = std::fs::remove_file(&self.copy);
    }
}

/// Creates `path` new (never through an existing file or link), readable
/// by its owner only, holding `text`.
fn write_private(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)?;
    f.write_all(text.as_bytes())
}

/// The user's editor: `$VISUAL`, else `$EDITOR`, else `vi`; run through
/// the shell so `EDITOR="code -w"` works.
pub fn run_editor(path: &Path) -> Result<(), String> {
    let editor = std::env::var("VISUAL")
        .or_else(|_| std::env::var("EDITOR"))
        .unwrap_or_else(|_| "vi".into());
    let status = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!("{editor} \"$1\""))
        .arg("falc-editor")
        .arg(path)
        .status()
        .map_err(|e| format!("cannot run the editor `{editor}`: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("the editor `{editor}` ended with {status}"))
    }
}

/// `falc store edit`: edit, save, and on findings offer to edit again.
pub async fn interactive(bus: &Bus, operator: &StationName, file: &RecipeFile) -> ExitCode {
    let session = match Session::open(bus, operator, file).await {
        Ok(s) => s,
        Err(OpenError::Call(e)) => return crate::output::fail(&e),
        Err(e) => {
            eprintln!("falc: {e}");
            return ExitCode::FAILURE;
        }
    };
    loop {
        if let Err(e) = session.run_editor() {
            eprintln!("falc: {e}; your text is in {}", session.copy.display());
            return ExitCode::FAILURE;
        }
        let text = match session.edited() {
            Ok(Some(t)) => t,
            Ok(None) => {
                crate::out!("{file}: nothing changed, nothing saved");
                session.discard();
                return ExitCode::SUCCESS;
            }
            Err(e) => {
                eprintln!("falc: {e}");
                return ExitCode::FAILURE;
            }
        };
        match session.save(bus, operator, text).await {
            Ok(said) => {
                crate::out!("{said}");
                return ExitCode::SUCCESS;
            }
            Err(why) => {
                eprintln!("falc: {why}");
                eprint!("edit again? [Y/n] ");
                let mut line = String::new();
                let _ = std::io::stdin().lock().read_line(&mut line);
                if line.trim().eq_ignore_ascii_case("n") {
                    eprintln!("not saved; your text is in {}", session.copy.display());
                    return ExitCode::FAILURE;
                }
            }
        }
    }
}
