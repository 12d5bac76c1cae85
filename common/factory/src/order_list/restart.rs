//! Restart planning: whether a stopped, failed or interrupted order can
//! run again (from which state), and order ends the records could not
//! take, held until they can.

use super::*;

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    /// Why order `id` cannot be restarted now (from `from`), or the order,
    /// the request that restarts it at the cell and the journal line.
    pub(super) fn restart_plan(
        &self,
        id: i64,
        from: Option<u16>,
    ) -> Result<(Order, CellCall, String), String> {
        if let Some(a) = self.alarms.blocking() {
            return Err(format!(
                "alarm {} waits for acknowledgement (falc ack {})",
                a.line(),
                a.id
            ));
        }
        if let Some(r) = &self.running {
            return Err(format!("order {} runs: falc stop first", r.id));
        }
        if self.shutdown_pending {
            return Err("the cell is shutting down".into());
        }
        if !self.cell_mode().runs_orders() {
            return Err("the cell is in maintenance mode: no order runs (falc mode auto)".into());
        }
        if !self.associated || self.undelivered().next().is_some() {
            return Err(format!(
                "the cell does not hold the recipes yet ({}): try again in a moment",
                self.problem.as_deref().unwrap_or("connecting")
            ));
        }
        let orders = self.db.orders().map_err(|e| e.to_string())?;
        let order = orders
            .into_iter()
            .find(|o| o.id == id)
            .ok_or_else(|| format!("there is no order {id}"))?;
        match order.state {
            OrderState::Failed | OrderState::Stopped | OrderState::Interrupted => {}
            OrderState::Queued => return Err(format!("order {id} is queued: falc start runs it")),
            OrderState::Running => return Err(format!("order {id} runs")),
            OrderState::Done => {
                return Err(format!(
                    "order {id} is done: add a new order to run {} again",
                    order.recipe
                ))
            }
        }
        let name = ObjectName::new(&order.recipe).map_err(|e| e.to_string())?;
        let Some(delivery) = self.recipes.deliveries.iter().find(|d| d.domain == name) else {
            return Err(format!(
                "order {id}'s recipe {} is no longer in the recipe store",
                order.recipe
            ));
        };
        if let Some(f) = from {
            let text = String::from_utf8_lossy(&delivery.content);
            let recipe = falc_recipe::syntax::parse(&text, &order.recipe);
            self.precondition_of(&recipe, f)?;
            let mut states: Vec<u16> = recipe.rows.iter().map(|r| r.state.0).collect();
            states.sort_unstable();
            states.dedup();
            if !states.contains(&f) {
                return Err(format!(
                    "{} has no state {f}: its states are {}",
                    order.recipe,
                    states
                        .iter()
                        .map(u16::to_string)
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
        Ok(match from {
            None if order.state == OrderState::Stopped => {
                let what = format!("resumed order {id} where it stopped");
                (order, CellCall::Pass(Request::Resume { name }), what)
            }
            _ => {
                let f = from.unwrap_or(1);
                let argument = match from {
                    Some(f) => format!("order {id} from {f}"),
                    None => format!("order {id}"),
                };
                let what = format!("restarted order {id} from state {f}");
                (order, CellCall::Start { name, argument }, what)
            }
        })
    }

    /// Refuses a restart from state `f` of cell recipe `recipe` when the
    /// job it starts first has a `#PRE` its station last said does not
    /// hold (the station checks again at the Start: this refuses before
    /// anything runs, with what to set right).
    fn precondition_of(&self, recipe: &falc_recipe::syntax::Recipe, f: u16) -> Result<(), String> {
        let Ok(program) =
            falc_recipe::check::check(recipe, falc_recipe::commands::RecipeKind::Cell)
        else {
            return Ok(());
        };
        let Some((station, job)) = program.job_started_from(falc_recipe::syntax::StateNo(f)) else {
            return Ok(());
        };
        match self.statuses.get(station).and_then(|s| s.unmet.get(job)) {
            Some(why) => Err(format!(
                "state {f} starts {station}'s {job}, and {station} says: {why} (set it right, \
                 or restart from another state)"
            )),
            None => Ok(()),
        }
    }

    pub(super) fn begin_restart(&mut self, by: Caller, id: i64, from: Option<u16>) {
        let (order, call, what) = match self.restart_plan(id, from) {
            Ok(plan) => plan,
            Err(text) => {
                let line = format!("restart of order {id} refused: {text}");
                self.journal(EntryKind::Action, Some(id), &by.who, &line);
                return self.reply(by.ticket, Err(text));
            }
        };
        let used = self.used_by(&order.recipe);
        let cell = self.topology.cell().as_str();
        let started_ms = match self.db.set_running(id, cell, &used) {
            Ok(ms) => ms,
            Err(e) => {
                let text = format!("order {id} not restarted: {e}");
                self.db_failed(&e);
                return self.reply(by.ticket, Err(text));
            }
        };
        self.journal(EntryKind::Action, Some(id), &by.who, &what);
        let busy = Busy::Starting {
            order: order.clone(),
            started_ms,
            by: Some(by),
            previous: Some(Box::new(order)),
        };
        self.call(call, busy);
    }

    /// `orders` as they stand: an end the database could not take yet (a
    /// full disk) shows, not the state written before it.
    pub(super) fn with_unwritten_ends(&self, mut orders: Vec<Order>) -> Vec<Order> {
        for (id, state, result) in &self.unwritten_ends {
            if let Some(o) = orders.iter_mut().find(|o| o.id == *id) {
                o.state = *state;
                o.result = Some(format!(
                    "{result} (not yet written: the journal cannot be written)"
                ));
            }
        }
        orders
    }

    /// Writes the order ends a failed write held back; the error (the
    /// fault raised again) while it still cannot.
    pub(super) fn write_held_ends(&mut self) -> Result<(), String> {
        while let Some((id, state, result)) = self.unwritten_ends.first().cloned() {
            if let Err(e) = self.db.end_order(id, state, &result) {
                let text = e.to_string();
                self.db_failed(&e);
                return Err(text);
            }
            self.unwritten_ends.remove(0);
            self.journal_mine(
                EntryKind::Order,
                Some(id),
                &format!("order {id} {state}: {result} (written late)"),
            );
        }
        Ok(())
    }
}
