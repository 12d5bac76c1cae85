//! The cell's questions and lines to the operator (`input`, `output`): the
//! cell's indications answered, bounded to what an operator can read, one
//! question waiting at a time.

use super::*;

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    /// Answers the waiting question with `why` (its order no longer runs).
    pub(super) fn refuse_question(&mut self, why: &str) {
        if let Some(q) = self.questions.take() {
            self.out.push_back(Output::Respond {
                ticket: q.ticket,
                result: Err(ServiceError::state_conflict(why)),
            });
        }
    }

    /// Drops the waiting question unanswered.
    pub(super) fn forget_question(&mut self) {
        if let Some(q) = self.questions.take() {
            self.out.push_back(Output::Forget(q.ticket));
        }
    }

    // ---- jobs: one call to the cell at a time ----

    /// A request of the cell: operator communication. Answered through
    /// [`Output::Respond`] under `ticket` (an `input` once answered).
    pub fn handle_cell_request(&mut self, now: Duration, ticket: Ticket, request: Request) {
        self.tick(now);
        if let Some(e) = too_long_for_the_operator(&request) {
            self.out.push_back(Output::Respond {
                ticket,
                result: Err(e),
            });
            self.pump(now);
            return;
        }
        match request {
            Request::Output { lines } => {
                for l in &lines {
                    self.journal_cell_message(now, EntryKind::Message, l);
                }
                self.questions.show(lines);
                self.out.push_back(Output::Respond {
                    ticket,
                    result: Ok(Response::Done),
                });
            }
            Request::Input { prompt, .. } => {
                self.journal_cell_message(now, EntryKind::Question, &prompt);
                self.say(format!("EVENT question {prompt}"));
                if let Some(older) = self.questions.ask(&prompt, ticket) {
                    self.out.push_back(Output::Respond {
                        ticket: older.ticket,
                        result: Err(ServiceError::state_conflict(
                            "a newer question replaced this one",
                        )),
                    });
                }
            }
            other => {
                let e = ServiceError::undefined(format!(
                    "the operator serves only input and output to its cell, not {}",
                    other.service()
                ));
                self.out.push_back(Output::Respond {
                    ticket,
                    result: Err(e),
                });
            }
        }
        self.pump(now);
    }

    // ---- the operator API ----
}

/// The refusal of an operator communication that carries more than an
/// operator can read ([`MAX_OUTPUT_LINES`] lines of [`MAX_OUTPUT_CHARS`]
/// characters), before any of it is journalled or shown.
fn too_long_for_the_operator(request: &Request) -> Option<ServiceError> {
    let too_long = |text: &str| text.chars().count() > MAX_OUTPUT_CHARS;
    let why = match request {
        Request::Output { lines } if lines.len() > MAX_OUTPUT_LINES => format!(
            "an output of {} lines; the operator takes at most {MAX_OUTPUT_LINES} at once",
            lines.len()
        ),
        Request::Output { lines } => match lines.iter().find(|l| too_long(l)) {
            Some(l) => format!(
                "an output line `{}`; the operator takes lines of at most {MAX_OUTPUT_CHARS} characters",
                falc_model::ids::excerpt(l)
            ),
            None => return None,
        },
        Request::Input { prompt, .. } if too_long(prompt) => format!(
            "a question `{}`; the operator takes questions of at most {MAX_OUTPUT_CHARS} characters",
            falc_model::ids::excerpt(prompt)
        ),
        _ => return None,
    };
    Some(ServiceError::undefined(why))
}
