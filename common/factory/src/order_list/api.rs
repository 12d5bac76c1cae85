//! The operator API's dispatch: each console request checked against its
//! user's role and answered from the list, the records and the recipe
//! store (orders, status, journal, alarms, recipes and their versions,
//! modes, steps and manual operations passed to the cell).

use super::*;

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    /// The request passing `mode` to the cell, or why not.
    pub(super) fn mode_request(
        &self,
        mode: CellMode,
        stations: Vec<StationName>,
    ) -> Result<Request, String> {
        if mode != CellMode::Step && !stations.is_empty() {
            return Err("workstations step only in step mode".into());
        }
        for (i, s) in stations.iter().enumerate() {
            if self.topology.commander_of(s) != Some(&self.cell) {
                return Err(format!("{s} is not a workstation of {}", self.cell));
            }
            if stations[..i].contains(s) {
                return Err(format!("{s} is named more than once"));
            }
        }
        let current = self.cell_mode();
        if let Some(r) = &self.running {
            if !current.may_change_running(mode) {
                return Err(format!(
                    "order {} runs: the mode changes from {current} to {mode} only when no \
                     order runs (falc stop first)",
                    r.id
                ));
            }
        }
        let mut stepping = Vec::new();
        if mode == CellMode::Step {
            stepping.push(self.cell.clone());
            stepping.extend(stations);
        }
        Ok(Request::Mode(ModeSetting { mode, stepping }))
    }

    /// The cell this list runs on.
    pub fn cell(&self) -> &CellId {
        self.topology.cell()
    }

    /// Whether the cell has a cell recipe of this name (as delivered, or
    /// saved since).
    pub fn knows_recipe(&self, recipe: &str) -> bool {
        let Ok(name) = ObjectName::new(recipe) else {
            return false;
        };
        self.recipes.cell_recipes().contains(&&name)
            || self
                .source
                .load()
                .is_ok_and(|set| set.cell_recipes().contains(&&name))
    }

    /// Whether alarm `id` is listed here.
    pub fn has_alarm(&self, id: i64) -> bool {
        self.alarms.listed().iter().any(|a| a.id == id)
    }

    /// The alarms listed here.
    pub fn listed_alarms(&self) -> &[Alarm] {
        self.alarms.listed()
    }

    /// Whether order `id` ran (or runs) on this cell.
    pub fn ran(&self, id: i64) -> bool {
        self.db.orders().is_ok_and(|orders| {
            orders
                .iter()
                .any(|o| o.id == id && o.cell.as_deref() == Some(self.cell().as_str()))
        })
    }

    /// Whether the cell's question waits for an answer.
    pub fn question_waiting(&self) -> bool {
        self.questions.prompt().is_some()
    }

    /// The cell at a glance, as `status` answers it.
    pub fn status(&self) -> Result<CellStatus, R::Error> {
        Ok(CellStatus {
            list: self.list_state(),
            cell_associated: self.associated,
            problem: self.problem.clone(),
            alarm: self.alarms.blocking().map(|a| a.line()),
            alarms: self.alarms.listed().to_vec(),
            running: self.running.clone(),
            queued: self.db.queued()?,
            journal_head: self.db.journal_head()?,
            question: self.questions.prompt().map(str::to_string),
            shutdown_pending: self.shutdown_pending,
            mode: self.cell_mode(),
            stations: self
                .topology
                .stations()
                .iter()
                .filter(|s| s.commander.is_some())
                .map(|s| StationView {
                    name: s.name.clone(),
                    status: self.statuses.get(&s.name).cloned(),
                    connected: self.present.contains(&s.name),
                })
                .collect(),
        })
    }

    /// The same for a request a console made for this cell of a plant
    /// (`falc --cell C`): the journal and the messages it reads are this
    /// cell's (with those written before entries had a cell).
    pub fn handle_cell_api(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
    ) {
        let cell = self.cell().to_string();
        self.api_call(now, ticket, user, request, Some(&cell));
    }

    /// One operator API request from console user `user`, answered through
    /// [`Self::poll_reply`] under `ticket`: at once, or (`start`, `stop`) when
    /// the cell confirmed.
    pub fn handle_api(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
    ) {
        self.api_call(now, ticket, user, request, None);
    }

    pub(super) fn api_call(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
        entries_of: Option<&str>,
    ) {
        self.tick(now);
        if let Some(result) = self.api(ticket, user, request, entries_of) {
            self.reply(ticket, result);
        }
        self.pump(now);
    }

    /// Saves `text` as recipe `file` (checked with the whole set; only
    /// over `base`) and keeps it as the file's newest version; `what` the
    /// store did (`changed`, `created`, `rolled back to version 3`).
    pub(super) fn save_recipe(
        &mut self,
        who: &str,
        file: &RecipeFile,
        text: &str,
        base: Option<u64>,
        what: &str,
        message: &str,
    ) -> ApiResult {
        match self.source.put(file, text, base) {
            Ok(()) => {}
            Err(PutError::Findings(f)) => {
                return Err(format!(
                    "recipe {file} NOT saved: the recipe set does not check clean with it:\n{}",
                    f.join("\n")
                ))
            }
            Err(PutError::Refused(why)) => return Err(format!("recipe {file} NOT saved: {why}")),
        }
        // Saved: a version that cannot be written stops the list (the
        // next start keeps the text as a version found in the store).
        let version = match self.db.add_version(file, text, who, message) {
            Ok((v, _)) => v,
            Err(e) => {
                let text = format!("recipe {file} saved, but its version not kept: {e}");
                self.db_failed(&e);
                return Err(text);
            }
        };
        let said = if message.is_empty() {
            String::new()
        } else {
            format!(": {message}")
        };
        self.journal(
            EntryKind::Action,
            None,
            who,
            &format!(
                "recipe {file} {what}: version {} ({}){said} (checked; the cell gets it at the next start)",
                version.version,
                version.hash.short()
            ),
        );
        Ok(ApiReply::Done(format!(
            "recipe {file} saved as version {} ({}): it checks clean; the cell gets it at the next start",
            version.version,
            version.hash.short()
        )))
    }

    /// Saves version `version` of `file` again as its newest version,
    /// checked like any save.
    pub(super) fn roll_back(
        &mut self,
        who: &str,
        file: &RecipeFile,
        version: u32,
        message: &str,
    ) -> ApiResult {
        let (old, text) = match self.db.version(file, version) {
            Ok(Some(v)) => v,
            Ok(None) => {
                return Err(format!(
                    "recipe {file} has no version {version} (falc recipe history {file})"
                ))
            }
            Err(e) => return Err(e.to_string()),
        };
        let now = self.source.get(file).ok();
        if now.as_ref().is_some_and(|n| n.text == text) {
            return Err(format!(
                "recipe {file} is the text of version {version} already: nothing to roll back"
            ));
        }
        let what = format!(
            "rolled back to version {} ({})",
            old.version,
            old.hash.short()
        );
        self.save_recipe(who, file, &text, now.map(|n| n.hash), &what, message)
    }

    /// The answer now, or None when a job answers it later; the journal
    /// and messages it reads are cell `entries_of`'s (None: all).
    pub(super) fn api(
        &mut self,
        ticket: Ticket,
        user: &StationName,
        request: ApiRequest,
        entries_of: Option<&str>,
    ) -> Option<ApiResult> {
        let who = user.as_str();
        let caller = || Caller {
            ticket,
            who: who.to_string(),
        };
        // The router already refused what the user's role does not allow;
        // checked again here so a mis-generated ACL cannot widen a role.
        let call = request.call();
        match self.topology.console(user) {
            Some(c) if c.role >= call.role() => {}
            Some(c) => {
                return Some(Err(format!(
                    "{user} is {:?}, `{call}` needs {:?}",
                    c.role,
                    call.role()
                )))
            }
            None => return Some(Err(format!("{user} is not a console user of this cell"))),
        }
        let db = |e: R::Error| e.to_string();
        Some(match request {
            ApiRequest::Status => self.status().map(ApiReply::Status).map_err(db),
            ApiRequest::OrderList => self
                .db
                .orders()
                .map(|orders| ApiReply::Orders(self.with_unwritten_ends(orders)))
                .map_err(db),
            ApiRequest::Messages { after, last } => self
                .db
                .entries(&EntryQuery {
                    messages_only: true,
                    cell: entries_of,
                    newest: last.is_some(),
                    ..EntryQuery::page(after, last.map_or(PAGE, |n| usize::from(n).min(PAGE)))
                })
                .map(ApiReply::Entries)
                .map_err(db),
            ApiRequest::Journal { order, after, last } => self
                .db
                .entries(&EntryQuery {
                    order,
                    cell: entries_of,
                    newest: last.is_some(),
                    ..EntryQuery::page(after, last.map_or(PAGE, |n| usize::from(n).min(PAGE)))
                })
                .map(ApiReply::Entries)
                .map_err(db),
            ApiRequest::OrderAdd {
                recipe,
                placement,
                count,
            } => self.add_order(who, &recipe, &placement, count),
            ApiRequest::OrderRemove { id } => match self.db.remove_order(id) {
                Err(e) => Err(e.to_string()),
                Ok(Ok(order)) => {
                    self.journal(
                        EntryKind::Action,
                        Some(id),
                        who,
                        &format!("removed order {id} ({})", order.recipe),
                    );
                    Ok(ApiReply::Done(format!("order {id} removed")))
                }
                Ok(Err(why)) => Err(why),
            },
            ApiRequest::Start | ApiRequest::Stop => {
                let by = caller();
                let stop = matches!(request, ApiRequest::Stop);
                self.jobs
                    .push_back(if stop { Job::Stop(by) } else { Job::Start(by) });
                return None;
            }
            ApiRequest::Ack { id } => self.ack(who, id),
            ApiRequest::Answer { text } => {
                let Some(q) = self.questions.take() else {
                    return Some(Err("no question is waiting for an answer".into()));
                };
                let order = self.running_id();
                self.journal(EntryKind::Answer, order, who, &text);
                self.out.push_back(Output::Respond {
                    ticket: q.ticket,
                    result: Ok(Response::Answer(text.clone())),
                });
                Ok(ApiReply::Done(format!("answered {text}")))
            }
            ApiRequest::RecipeList => self.source.list().map(ApiReply::Recipes),
            ApiRequest::RecipeGet { file } => self.source.get(&file).map(ApiReply::Recipe),
            ApiRequest::RecipePut {
                file,
                text,
                base,
                message,
            } => {
                let what = if base.is_none() { "created" } else { "changed" };
                self.save_recipe(who, &file, &text, base, what, &message)
            }
            ApiRequest::RecipeHistory { file } => match self.db.versions(&file) {
                Ok(v) if v.is_empty() => Err(format!(
                    "recipe {file} has no saved version (falc store list shows the recipes)"
                )),
                Ok(v) => Ok(ApiReply::Versions(v)),
                Err(e) => Err(e.to_string()),
            },
            ApiRequest::RecipeVersion { file, version } => match self.db.version(&file, version) {
                Ok(Some((version, text))) => Ok(ApiReply::RecipeAt { version, text }),
                Ok(None) => Err(format!(
                    "recipe {file} has no version {version} (falc recipe history {file})"
                )),
                Err(e) => Err(e.to_string()),
            },
            ApiRequest::RecipeRollback {
                file,
                version,
                message,
            } => self.roll_back(who, &file, version, &message),
            ApiRequest::Figures(query) => {
                let now = self.db.now_ms();
                let until = query.until_ms.unwrap_or(now);
                match self.db.figure_inputs(query.since_ms, until) {
                    Ok(inputs) => {
                        let mut f = crate::figures::compute(
                            &inputs,
                            self.topology.calendar(),
                            &[self.topology.cell().as_str()],
                            &query,
                            now,
                        );
                        crate::figures::keep_newest_runs(&mut f);
                        Ok(ApiReply::Figures(Box::new(f)))
                    }
                    Err(e) => Err(e.to_string()),
                }
            }
            ApiRequest::OrderShow { id } => match self.db.order_record(id) {
                Ok(Some(mut record)) => {
                    if let Some(o) = self.with_unwritten_ends(vec![record.order.clone()]).pop() {
                        record.order = o;
                    }
                    Ok(ApiReply::OrderRecord(Box::new(record)))
                }
                Ok(None) => Err(format!("there is no order {id}")),
                Err(e) => Err(e.to_string()),
            },
            ApiRequest::Mode { mode, stations } => {
                let request = match self.mode_request(mode, stations) {
                    Ok(r) => r,
                    Err(e) => return Some(Err(e)),
                };
                if mode == CellMode::Maintenance {
                    self.list = ListState::Idle;
                }
                let done = match &request {
                    Request::Mode(m) => format!("mode {m}"),
                    _ => format!("mode {mode}"),
                };
                self.jobs.push_back(Job::Pass {
                    by: caller(),
                    request,
                    done,
                });
                return None;
            }
            ApiRequest::Step { station, to } => {
                let on = station.clone().unwrap_or_else(|| self.cell.clone());
                let done = match to {
                    Some(t) => format!("step on {on} up to state {t}"),
                    None => format!("step on {on}"),
                };
                let by = Caller {
                    ticket,
                    who: who.to_string(),
                };
                let request = Request::Step { station, to };
                self.jobs.push_back(Job::Pass { by, request, done });
                return None;
            }
            ApiRequest::Manual { station, action } => {
                if let Err(e) = falc_recipe::check::check_manual(&action) {
                    return Some(Err(format!("manual on {station}: {e}")));
                }
                let done = format!("manual on {station}: {action}");
                let request = Request::Manual {
                    station,
                    action,
                    by: who.to_string(),
                };
                self.jobs.push_back(Job::Pass {
                    by: caller(),
                    request,
                    done,
                });
                return None;
            }
            ApiRequest::Restart { order, from } => {
                self.jobs.push_back(Job::Restart {
                    by: caller(),
                    order,
                    from,
                });
                return None;
            }
            ApiRequest::Shutdown => {
                self.journal(EntryKind::Action, None, who, "shut down requested");
                self.shutdown_pending = true;
                if self.running.is_some() {
                    Ok(ApiReply::Done(
                        "the cell shuts down when the order list is done".into(),
                    ))
                } else {
                    Ok(ApiReply::Done("shutting down".into()))
                }
            }
        })
    }

    /// Adds `count` orders of `recipe`, placed as `placement` says; each
    /// journalled with the user. The list's limit counts them all: none
    /// is added when they do not all fit.
    pub(super) fn add_order(
        &mut self,
        who: &str,
        recipe: &str,
        placement: &Placement,
        count: u16,
    ) -> ApiResult {
        let name = ObjectName::new(recipe).map_err(|e| e.to_string())?;
        if let Some(cell) = placement
            .cell
            .as_ref()
            .filter(|c| *c != self.topology.cell())
        {
            return Err(format!(
                "there is no cell {cell}; the order list runs on cell {}",
                self.topology.cell()
            ));
        }
        if !self.recipes.cell_recipes().contains(&&name) {
            // A recipe saved since the last start is known once the recipe
            // store checks clean with it (delivered at the start).
            let known = match self.source.load() {
                Ok(set) => set.cell_recipes().contains(&&name),
                Err(_) => false,
            };
            if !known {
                let list: Vec<String> = self
                    .recipes
                    .cell_recipes()
                    .iter()
                    .map(|n| n.as_str().to_lowercase())
                    .collect();
                return Err(format!(
                    "there is no cell recipe {recipe}; the cell knows {}",
                    list.join(", ")
                ));
            }
        }
        match self.db.queued() {
            Ok(queued) if queued + usize::from(count) > self.max_queued => {
                let more = if count > 1 {
                    format!("; {count} more do not fit")
                } else {
                    String::new()
                };
                return Err(format!(
                    "the order list holds {queued} queued orders, its limit \
                     (falc-operator --max-queued-orders {}){more}; remove some, or start the list",
                    self.max_queued
                ));
            }
            Ok(_) => {}
            Err(e) => {
                let text = e.to_string();
                self.db_failed(&e);
                return Err(text);
            }
        }
        let mut added = Vec::new();
        for _ in 0..count {
            let order = match self.db.add_order(&recipe.to_lowercase(), who, placement) {
                Ok(o) => o,
                Err(e) => {
                    let text = e.to_string();
                    self.db_failed(&e);
                    return Err(text);
                }
            };
            self.journal(
                EntryKind::Action,
                Some(order.id),
                who,
                &format!(
                    "added order {} ({}{})",
                    order.id,
                    order.recipe,
                    placed(&order)
                ),
            );
            added.push(order);
        }
        match added.pop() {
            Some(only) if added.is_empty() => Ok(ApiReply::Order(only)),
            Some(last) => {
                added.push(last);
                Ok(ApiReply::Orders(added))
            }
            None => Err("no order added".into()),
        }
    }

    /// Acknowledges alarm `id`, or all; journalled with the user.
    pub(super) fn ack(&mut self, who: &str, id: Option<i64>) -> ApiResult {
        let (acked, error) = self.alarms.ack(&mut self.db, id, who)?;
        if acked.is_empty() {
            if let Some(e) = error {
                // Not one could be written: none is acknowledged.
                let text = e.to_string();
                self.db_failed(&e);
                return Err(format!("not acknowledged: {text}"));
            }
            return Ok(ApiReply::Done("no alarm to acknowledge".into()));
        }
        if let Some(s) = self.db_alarm.filter(|s| acked.iter().any(|a| a.id == *s)) {
            // Acknowledged: the order ends held back are written now, not
            // at the next start (there may be none: the list was done), and
            // that write tells whether the records work again (it raises a
            // new alarm if not).
            self.db_alarm = None;
            let _ = self.alarms.clear_where(&mut self.db, |a| a.id == s);
            let _ = self.write_held_ends();
        }
        if let Some(e) = error {
            self.db_failed(&e);
        }
        for a in &acked {
            self.journal(
                EntryKind::Action,
                a.order,
                who,
                &format!("acknowledged alarm {}", a.line()),
            );
        }
        let lines: Vec<String> = acked.iter().map(|a| a.line()).collect();
        Ok(ApiReply::Done(format!(
            "acknowledged: {}",
            lines.join("; ")
        )))
    }
}
