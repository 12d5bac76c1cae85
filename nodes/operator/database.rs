//! The operator's durable state in one SQLite file (WAL, synchronous FULL):
//! the order list, the journal, the alarms, every saved version of each
//! recipe file (kept by triggers from being changed or removed) and the
//! versions each run of an order used. Every change is one transaction, so a
//! crash loses nothing that was confirmed; [`Database::recover`] marks an order
//! that was running when the node died as interrupted (never re-run by
//! itself) and journals it.

use falc_factory::figures::{AlarmSpan, FigureInputs, ListChange, ModeChange, RunSpan};
use falc_factory::records::{
    adopted_text, interrupted_text, recovery, EntryQuery, Records, Recovered, INTERRUPTED_RESULT,
    RECORD_ENTRIES,
};
use falc_model::alarm::{Alarm, AlarmClass};
use falc_model::api::Placement;
use falc_model::ids::StationName;
use falc_model::mode::CellMode;
use falc_model::product::{
    JobRecord, OrderRecord, OrderRun, RecipeVersion, UsedRecipe, VersionHash,
};
use falc_model::recipe_file::RecipeFile;
use falc_model::records::{Entry, EntryKind, Order, OrderState};
use rusqlite::{params, Connection, OptionalExtension, Row};
use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

/// A database failure, with the file and what was being done.
#[derive(Debug, thiserror::Error)]
#[error("order list and journal {path}: {what}: {source}")]
pub struct DatabaseError {
    path: String,
    what: &'static str,
    source: Box<dyn std::error::Error + Send + Sync>,
}

/// Milliseconds since the Unix epoch, now.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

/// The order list and the journal, as one cell's order list sees them:
/// the orders and the journal are the plant's (one table each, every
/// cell's list reads all), the alarms the cell's own. Each cell's list
/// has a connection of its own to the one file.
pub struct Database {
    conn: Connection,
    path: String,
    /// The cell whose alarms this connection lists and whose journal
    /// entries and alarms it writes.
    cell: String,
    /// The time records are stamped with ([`Records::set_now`]; the wall
    /// clock at open until given).
    now: i64,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS orders (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    recipe TEXT NOT NULL,
    state TEXT NOT NULL,
    added_by TEXT NOT NULL,
    added_ms INTEGER NOT NULL,
    started_ms INTEGER,
    ended_ms INTEGER,
    result TEXT
);
CREATE TABLE IF NOT EXISTS journal (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at_ms INTEGER NOT NULL,
    order_id INTEGER,
    kind TEXT NOT NULL,
    who TEXT NOT NULL,
    text TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS journal_order ON journal(order_id);
CREATE TABLE IF NOT EXISTS alarms (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    station TEXT NOT NULL,
    class TEXT NOT NULL,
    text TEXT NOT NULL,
    order_id INTEGER,
    raised_ms INTEGER NOT NULL,
    acked_by TEXT,
    acked_ms INTEGER,
    cleared_ms INTEGER
);
CREATE TABLE IF NOT EXISTS recipe_versions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    file TEXT NOT NULL,
    version INTEGER NOT NULL,
    hash TEXT NOT NULL,
    author TEXT NOT NULL,
    at_ms INTEGER NOT NULL,
    message TEXT NOT NULL,
    text TEXT NOT NULL,
    UNIQUE (file, version)
);
CREATE TRIGGER IF NOT EXISTS recipe_versions_never_changed
    BEFORE UPDATE ON recipe_versions
    BEGIN SELECT RAISE(ABORT, 'a recipe version is never changed'); END;
CREATE TRIGGER IF NOT EXISTS recipe_versions_never_removed
    BEFORE DELETE ON recipe_versions
    BEGIN SELECT RAISE(ABORT, 'a recipe version is never removed'); END;
CREATE TABLE IF NOT EXISTS order_recipes (
    order_id INTEGER NOT NULL,
    started_ms INTEGER NOT NULL,
    position INTEGER NOT NULL,
    domain TEXT NOT NULL,
    file TEXT NOT NULL,
    version INTEGER NOT NULL,
    hash TEXT NOT NULL,
    starts TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS order_recipes_order ON order_recipes(order_id);
CREATE TABLE IF NOT EXISTS order_runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    order_id INTEGER NOT NULL,
    recipe TEXT NOT NULL,
    cell TEXT NOT NULL,
    started_ms INTEGER NOT NULL,
    ended_ms INTEGER,
    state TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS order_runs_order ON order_runs(order_id);
CREATE INDEX IF NOT EXISTS order_runs_started ON order_runs(started_ms);
CREATE TABLE IF NOT EXISTS jobs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    order_id INTEGER,
    cell TEXT NOT NULL,
    station TEXT NOT NULL,
    program TEXT NOT NULL,
    started_ms INTEGER,
    ended_ms INTEGER NOT NULL,
    outcome TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_order ON jobs(order_id);
CREATE TABLE IF NOT EXISTS modes (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    cell TEXT NOT NULL,
    at_ms INTEGER NOT NULL,
    mode TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS list_states (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    cell TEXT NOT NULL,
    at_ms INTEGER NOT NULL,
    working INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS reports_filed (
    cell TEXT NOT NULL,
    station TEXT NOT NULL,
    run TEXT NOT NULL,
    no INTEGER NOT NULL,
    PRIMARY KEY (cell, station)
);
";

const VERSION_COLUMNS: &str = "file, version, hash, author, at_ms, message";

/// A value the file holds that this version cannot read, as a read error.
fn unreadable(column: usize, why: String) -> rusqlite::Error {
    rusqlite::Error::FromSqlConversionFailure(column, rusqlite::types::Type::Text, why.into())
}

/// `station/file.rcp` as stored.
fn recipe_file_of(text: &str, column: usize) -> rusqlite::Result<RecipeFile> {
    let (station, file) = text
        .split_once('/')
        .ok_or_else(|| unreadable(column, format!("recipe file {text:?} has no station")))?;
    let station = StationName::new(station).map_err(|e| unreadable(column, e.to_string()))?;
    RecipeFile::new(station, file).map_err(|e| unreadable(column, e))
}

fn version_of(row: &Row<'_>) -> rusqlite::Result<RecipeVersion> {
    let file: String = row.get(0)?;
    let hash: String = row.get(2)?;
    Ok(RecipeVersion {
        file: recipe_file_of(&file, 0)?,
        version: row.get(1)?,
        hash: VersionHash::try_from(hash).map_err(|e| unreadable(2, e))?,
        author: row.get(3)?,
        at_ms: row.get(4)?,
        message: row.get(5)?,
    })
}

/// Columns added since the first schema, each with its definition: a file
/// made before gets them at open (`ALTER TABLE … ADD COLUMN`), its orders
/// reading as placed by default (any cell, priority 0, no due time).
/// An alarm or journal entry with no cell is of the one cell there was.
const ADDED_COLUMNS: [(&str, &str, &str); 7] = [
    ("orders", "cell", "TEXT"),
    ("orders", "wanted", "TEXT"),
    ("orders", "priority", "INTEGER NOT NULL DEFAULT 0"),
    ("orders", "due_ms", "INTEGER"),
    ("orders", "job_order", "TEXT"),
    ("journal", "cell", "TEXT"),
    ("alarms", "cell", "TEXT"),
];

/// Made after the columns they index exist.
const INDEXES: &str = "
CREATE INDEX IF NOT EXISTS orders_state ON orders(state);
CREATE INDEX IF NOT EXISTS orders_dispatch ON orders(state, priority DESC, due_ms IS NULL, due_ms, id);
";

/// The queued orders as the dispatch takes them ([`Order::dispatch_key`]).
const DISPATCH_ORDER: &str = "priority DESC, due_ms IS NULL, due_ms, id";

const ALARM_COLUMNS: &str =
    "id, station, class, text, order_id, raised_ms, acked_by, acked_ms, cleared_ms";

fn alarm_of(row: &Row<'_>) -> rusqlite::Result<Alarm> {
    let class: String = row.get(2)?;
    let acked_by: Option<String> = row.get(6)?;
    let acked_ms: Option<i64> = row.get(7)?;
    let station: String = row.get(1)?;
    let station = StationName::new(&station).map_err(|e| unreadable(1, e.to_string()))?;
    Ok(Alarm {
        id: row.get(0)?,
        station,
        // A class this version does not know is kept as the strictest.
        class: AlarmClass::parse(&class).unwrap_or(AlarmClass::Safety),
        text: row.get(3)?,
        order: row.get(4)?,
        raised_ms: row.get(5)?,
        acked: acked_by.zip(acked_ms),
        cleared_ms: row.get(8)?,
    })
}

const ORDER_COLUMNS: &str =
    "id, recipe, state, added_by, started_ms, ended_ms, result, cell, wanted, priority, due_ms, \
     job_order";

fn order_of(row: &Row<'_>) -> rusqlite::Result<Order> {
    let state: String = row.get(2)?;
    Ok(Order {
        id: row.get(0)?,
        recipe: row.get(1)?,
        // A word this version does not know reads as interrupted: shown, never run.
        state: OrderState::parse(&state).unwrap_or(OrderState::Interrupted),
        added_by: row.get(3)?,
        started_ms: row.get(4)?,
        ended_ms: row.get(5)?,
        result: row.get(6)?,
        cell: row.get(7)?,
        wanted: row.get(8)?,
        priority: row.get(9)?,
        due_ms: row.get(10)?,
        job_order: row.get(11)?,
    })
}

/// Adds the columns of [`ADDED_COLUMNS`] a file made before lacks.
fn add_missing_columns(conn: &Connection) -> rusqlite::Result<()> {
    for (table, column, definition) in ADDED_COLUMNS {
        let present: i64 = conn.query_row(
            &format!("SELECT COUNT(*) FROM pragma_table_info('{table}') WHERE name = ?1"),
            params![column],
            |r| r.get(0),
        )?;
        if present == 0 {
            conn.execute_batch(&format!(
                "ALTER TABLE {table} ADD COLUMN {column} {definition}"
            ))?;
        }
    }
    Ok(())
}

fn entry_of(row: &Row<'_>) -> rusqlite::Result<Entry> {
    let kind: String = row.get(3)?;
    Ok(Entry {
        id: row.get(0)?,
        at_ms: row.get(1)?,
        order: row.get(2)?,
        kind: EntryKind::parse(&kind).unwrap_or(EntryKind::System),
        who: row.get(4)?,
        text: row.get(5)?,
        cell: row.get(6)?,
    })
}

impl Database {
    /// Opens (creating if needed) the database at `path` for cell `cell`.
    pub fn open(path: &Path, cell: &str) -> Result<Self, DatabaseError> {
        let name = path.display().to_string();
        let fail = |what: &'static str| {
            let name = name.clone();
            move |source: rusqlite::Error| DatabaseError {
                path: name,
                what,
                source: source.into(),
            }
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.exists() {
                // A directory that cannot be made shows up as the open
                // error below; one made here is private.
                use std::os::unix::fs::DirBuilderExt;
                let _ = std::fs::DirBuilder::new()
                    .recursive(true)
                    .mode(0o700)
                    .create(dir);
            }
            // One made before (or by hand) is made private at every start.
            make_private_dir(dir).map_err(|source| DatabaseError {
                path: dir.display().to_string(),
                what: "cannot make the journal's directory private (chmod 700)",
                source: source.into(),
            })?;
        }
        // The journal is private: the file is made 0600 before SQLite opens
        // it (its -wal and -shm files take the same mode), and one made
        // before that rule is made private.
        if !path.exists() {
            use std::os::unix::fs::OpenOptionsExt;
            let _ = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(path);
        }
        for file in [
            path.to_path_buf(),
            wal_of(path, "-wal"),
            wal_of(path, "-shm"),
        ] {
            make_private(&file).map_err(|source| DatabaseError {
                path: file.display().to_string(),
                what: "cannot make the journal private (chmod 600)",
                source: source.into(),
            })?;
        }
        let conn = Connection::open(path).map_err(fail("cannot open"))?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(fail("cannot switch to WAL"))?;
        conn.pragma_update(None, "synchronous", "FULL")
            .map_err(fail("cannot set synchronous"))?;
        conn.busy_timeout(std::time::Duration::from_secs(5))
            .map_err(fail("cannot set the busy timeout"))?;
        conn.execute_batch(SCHEMA)
            .map_err(fail("cannot create the tables"))?;
        add_missing_columns(&conn).map_err(fail("cannot add the new columns"))?;
        conn.execute_batch(INDEXES)
            .map_err(fail("cannot create the indexes"))?;
        Ok(Self {
            conn,
            path: name,
            cell: cell.to_string(),
            now: now_ms(),
        })
    }

    /// Runs `f` in one transaction: all of it is written, or (an error,
    /// saying `what` was being done) none of it.
    fn in_transaction<T>(
        &mut self,
        what: &'static str,
        f: impl FnOnce(&rusqlite::Transaction<'_>) -> rusqlite::Result<T>,
    ) -> Result<T, DatabaseError> {
        let path = self.path.clone();
        let fail = |source: rusqlite::Error| DatabaseError {
            path: path.clone(),
            what,
            source: source.into(),
        };
        let tx = self.conn.transaction().map_err(&fail)?;
        let out = f(&tx).map_err(&fail)?;
        tx.commit().map_err(&fail)?;
        Ok(out)
    }

    fn fail(&self, what: &'static str) -> impl FnOnce(rusqlite::Error) -> DatabaseError + '_ {
        move |source: rusqlite::Error| DatabaseError {
            path: self.path.clone(),
            what,
            source: source.into(),
        }
    }

    /// One order.
    pub fn order(&self, id: i64) -> Result<Option<Order>, DatabaseError> {
        self.conn
            .query_row(
                &format!("SELECT {ORDER_COLUMNS} FROM orders WHERE id = ?1"),
                params![id],
                order_of,
            )
            .optional()
            .map_err(self.fail("cannot read an order"))
    }

    /// The orders in `state`, in list order.
    fn orders_in(&self, state: OrderState) -> Result<Vec<Order>, DatabaseError> {
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT {ORDER_COLUMNS} FROM orders WHERE state = ?1 ORDER BY id"
            ))
            .map_err(self.fail("cannot list orders"))?;
        let rows = st
            .query_map(params![state.as_str()], order_of)
            .map_err(self.fail("cannot list orders"))?;
        rows.collect::<Result<_, _>>()
            .map_err(self.fail("cannot list orders"))
    }
}

impl Records for Database {
    type Error = DatabaseError;

    /// After a stop or crash: the orders still marked running. The newest
    /// on each of `cells` is adopted (it stays running: a cell runs its
    /// order on without the operator, and is asked how it ended once it is
    /// associated), with a journal entry; every other becomes interrupted,
    /// with a journal entry.
    fn recover(&mut self, cells: &[&str]) -> Result<Recovered, DatabaseError> {
        let recovered = recovery(self.running_orders()?, cells);
        let now = self.now;
        let tx = self.conn.transaction().map_err(|source| DatabaseError {
            path: self.path.clone(),
            what: "cannot begin recovery",
            source: source.into(),
        })?;
        for o in &recovered.adopted {
            tx.execute(
                "INSERT INTO journal (at_ms, order_id, kind, who, text) VALUES (?1, ?2, 'order', 'operator', ?3)",
                params![now, o.id, adopted_text(o)],
            )
            .map_err(|source| DatabaseError {
                path: self.path.clone(),
                what: "cannot journal an adopted order",
                source: source.into(),
            })?;
        }
        for o in &recovered.interrupted {
            tx.execute(
                "UPDATE orders SET state = 'interrupted', ended_ms = ?1, result = ?2 WHERE id = ?3",
                params![now, INTERRUPTED_RESULT, o.id],
            )
            .and_then(|_| {
                tx.execute(
                    "UPDATE order_runs SET ended_ms = ?1, state = 'interrupted' \
                     WHERE order_id = ?2 AND ended_ms IS NULL",
                    params![now, o.id],
                )
            })
            .and_then(|_| {
                tx.execute(
                    "INSERT INTO journal (at_ms, order_id, kind, who, text) VALUES (?1, ?2, 'order', 'operator', ?3)",
                    params![now, o.id, interrupted_text(o)],
                )
            })
            .map_err(|source| DatabaseError {
                path: self.path.clone(),
                what: "cannot mark an order interrupted",
                source: source.into(),
            })?;
        }
        tx.commit().map_err(|source| DatabaseError {
            path: self.path.clone(),
            what: "cannot commit recovery",
            source: source.into(),
        })?;
        Ok(recovered)
    }

    fn now_ms(&self) -> i64 {
        self.now
    }
    fn set_now(&mut self, at_ms: i64) {
        self.now = at_ms;
    }

    /// Adds a queued order, placed as `placement` says.
    fn add_order(
        &mut self,
        recipe: &str,
        who: &str,
        placement: &Placement,
    ) -> Result<Order, Self::Error> {
        self.conn
            .execute(
                "INSERT INTO orders \
                 (recipe, state, added_by, added_ms, wanted, priority, due_ms, job_order) \
                 VALUES (?1, 'queued', ?2, ?3, ?4, ?5, ?6, ?7)",
                params![
                    recipe,
                    who,
                    self.now,
                    placement.cell.as_ref().map(|c| c.as_str()),
                    placement.priority,
                    placement.due_ms,
                    placement.job_order
                ],
            )
            .map_err(self.fail("cannot add an order"))?;
        let id = self.conn.last_insert_rowid();
        self.order(id)?.ok_or_else(|| DatabaseError {
            path: self.path.clone(),
            what: "the order just added is gone",
            source: rusqlite::Error::QueryReturnedNoRows.into(),
        })
    }

    /// Every order, in list order.
    fn running_orders(&self) -> Result<Vec<Order>, Self::Error> {
        self.orders_in(OrderState::Running)
    }

    fn orders(&self) -> Result<Vec<Order>, Self::Error> {
        let mut st = self
            .conn
            .prepare(&format!("SELECT {ORDER_COLUMNS} FROM orders ORDER BY id"))
            .map_err(self.fail("cannot list orders"))?;
        let rows = st
            .query_map([], order_of)
            .map_err(self.fail("cannot list orders"))?;
        rows.collect::<Result<_, _>>()
            .map_err(self.fail("cannot list orders"))
    }

    /// The queued order `cell` runs next: of those it may run, the
    /// highest priority, then the one due first, then the oldest.
    fn next_queued(&self, cell: &str) -> Result<Option<Order>, Self::Error> {
        self.conn
            .query_row(
                &format!(
                    "SELECT {ORDER_COLUMNS} FROM orders WHERE state = 'queued' \
                     AND (wanted IS NULL OR wanted = ?1) ORDER BY {DISPATCH_ORDER} LIMIT 1"
                ),
                params![cell],
                order_of,
            )
            .optional()
            .map_err(self.fail("cannot read the next order"))
    }

    /// The id of the newest journal entry (0 for an empty journal): a
    /// console asks for entries or orders only when it moved.
    fn journal_head(&self) -> Result<i64, Self::Error> {
        self.conn
            .query_row("SELECT COALESCE(MAX(id), 0) FROM journal", [], |r| r.get(0))
            .map_err(self.fail("cannot read the journal"))
    }

    /// How many orders are queued.
    fn queued(&self) -> Result<usize, Self::Error> {
        // Read with every status, and the order list told of each change
        // of it: counted, not listed.
        self.conn
            .query_row(
                "SELECT COUNT(*) FROM orders WHERE state = ?1",
                params![OrderState::Queued.as_str()],
                |r| r.get::<_, i64>(0),
            )
            .map(|n| usize::try_from(n).unwrap_or(0))
            .map_err(self.fail("cannot count the queued orders"))
    }

    /// Removes a queued order; refuses any other.
    fn remove_order(&mut self, id: i64) -> Result<Result<Order, String>, Self::Error> {
        let Some(order) = self.order(id)? else {
            return Ok(Err(format!("there is no order {id}")));
        };
        if order.state != OrderState::Queued {
            return Ok(Err(format!(
                "order {id} is {}: only a queued order can be removed",
                order.state
            )));
        }
        self.conn
            .execute("DELETE FROM orders WHERE id = ?1", params![id])
            .map_err(self.fail("cannot remove an order"))?;
        Ok(Ok(order))
    }

    /// Marks an order running on `cell`; returns the start time it wrote (ms).
    fn set_running(
        &mut self,
        id: i64,
        cell: &str,
        recipes: &[UsedRecipe],
    ) -> Result<i64, Self::Error> {
        let started = self.now;
        self.in_transaction("cannot mark an order running", |tx| {
            tx.execute(
                "UPDATE orders SET state = 'running', started_ms = ?1, cell = ?2 WHERE id = ?3",
                params![started, cell, id],
            )?;
            tx.execute(
                "INSERT INTO order_runs (order_id, recipe, cell, started_ms, state) \
                 SELECT id, recipe, ?2, ?3, 'running' FROM orders WHERE id = ?1",
                params![id, cell, started],
            )?;
            for (position, r) in recipes.iter().enumerate() {
                let starts = serde_json::to_string(&r.starts).unwrap_or_else(|_| "[]".into());
                tx.execute(
                    "INSERT INTO order_recipes (order_id, started_ms, position, domain, file, version, hash, starts) \
                     VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                    params![
                        id,
                        started,
                        position as i64,
                        r.domain,
                        r.file.to_string(),
                        r.version,
                        r.hash.as_str(),
                        starts
                    ],
                )?;
            }
            Ok(started)
        })
    }

    /// Puts an order the cell refused to start back in the queue (it is
    /// marked running before the cell is asked, so that an order the cell
    /// may have started is never queued again; only a refusal undoes it).
    fn requeue(&mut self, id: i64) -> Result<(), Self::Error> {
        // The run that never began goes with it.
        self.in_transaction("cannot put an order back in the queue", |tx| {
            tx.execute(
                "DELETE FROM order_recipes WHERE order_id = ?1 AND started_ms = \
                 (SELECT started_ms FROM orders WHERE id = ?1 AND state = 'running')",
                params![id],
            )?;
            tx.execute(
                "DELETE FROM order_runs WHERE order_id = ?1 AND ended_ms IS NULL",
                params![id],
            )?;
            tx.execute(
                "UPDATE orders SET state = 'queued', started_ms = NULL, cell = NULL \
                 WHERE id = ?1 AND state = 'running'",
                params![id],
            )?;
            Ok(())
        })
    }

    /// Ends an order in `state` with `result` in words.
    fn end_order(&mut self, id: i64, state: OrderState, result: &str) -> Result<(), Self::Error> {
        let at = self.now;
        self.in_transaction("cannot end an order", |tx| {
            tx.execute(
                "UPDATE orders SET state = ?1, ended_ms = ?2, result = ?3 WHERE id = ?4",
                params![state.as_str(), at, result, id],
            )?;
            tx.execute(
                "UPDATE order_runs SET ended_ms = ?1, state = ?2 \
                 WHERE order_id = ?3 AND ended_ms IS NULL",
                params![at, state.as_str(), id],
            )?;
            Ok(())
        })
    }

    /// Appends a journal entry.
    fn journal_at(
        &mut self,
        at_ms: i64,
        kind: EntryKind,
        order: Option<i64>,
        who: &str,
        text: &str,
    ) -> Result<Entry, Self::Error> {
        self.conn
            .execute(
                "INSERT INTO journal (at_ms, order_id, kind, who, text, cell) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![at_ms, order, kind.as_str(), who, text, self.cell],
            )
            .map_err(self.fail("cannot write the journal"))?;
        Ok(Entry {
            id: self.conn.last_insert_rowid(),
            at_ms,
            order,
            kind,
            who: who.to_string(),
            text: text.to_string(),
            cell: Some(self.cell.clone()),
        })
    }

    /// Records a new alarm, active.
    fn raise_alarm(
        &mut self,
        station: &StationName,
        class: AlarmClass,
        text: &str,
        order: Option<i64>,
    ) -> Result<Alarm, Self::Error> {
        let raised_ms = self.now;
        self.conn
            .execute(
                "INSERT INTO alarms (station, class, text, order_id, raised_ms, cell) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![station.as_str(), class.as_str(), text, order, raised_ms, self.cell],
            )
            .map_err(self.fail("cannot record an alarm"))?;
        Ok(Alarm {
            id: self.conn.last_insert_rowid(),
            station: station.clone(),
            class,
            text: text.to_string(),
            order,
            raised_ms,
            acked: None,
            cleared_ms: None,
        })
    }

    /// Records who acknowledged alarm `id`, at `at_ms`.
    fn ack_alarm(&mut self, id: i64, who: &str, at_ms: i64) -> Result<(), Self::Error> {
        self.conn
            .execute(
                "UPDATE alarms SET acked_by = ?1, acked_ms = ?2 WHERE id = ?3 AND acked_by IS NULL",
                params![who, at_ms, id],
            )
            .map_err(self.fail("cannot acknowledge an alarm"))
            .map(|_| ())
    }

    /// Records that alarm `id`'s condition cleared at `at_ms`.
    fn clear_alarm(&mut self, id: i64, at_ms: i64) -> Result<(), Self::Error> {
        self.conn
            .execute(
                "UPDATE alarms SET cleared_ms = ?1 WHERE id = ?2 AND cleared_ms IS NULL",
                params![at_ms, id],
            )
            .map_err(self.fail("cannot clear an alarm"))
            .map(|_| ())
    }

    /// The alarms still in the list (not both acknowledged and cleared),
    /// oldest first.
    fn listed_alarms(&self) -> Result<Vec<Alarm>, Self::Error> {
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT {ALARM_COLUMNS} FROM alarms
                 WHERE (acked_ms IS NULL OR cleared_ms IS NULL) AND (cell IS NULL OR cell = ?1)
                 ORDER BY id"
            ))
            .map_err(self.fail("cannot read the alarms"))?;
        let rows = st
            .query_map(params![self.cell], alarm_of)
            .map_err(self.fail("cannot read the alarms"))?;
        let all = rows
            .collect::<Result<Vec<_>, _>>()
            .map_err(self.fail("cannot read the alarms"))?;
        // The SQL above is a prefilter (history stays on disk); the rule
        // itself is `Alarm::listed`.
        Ok(all.into_iter().filter(Alarm::listed).collect())
    }

    fn add_version(
        &mut self,
        file: &RecipeFile,
        text: &str,
        who: &str,
        message: &str,
    ) -> Result<(RecipeVersion, bool), Self::Error> {
        let hash = VersionHash::of(text.as_bytes());
        let newest = self
            .conn
            .query_row(
                &format!(
                    "SELECT {VERSION_COLUMNS} FROM recipe_versions WHERE file = ?1 \
                     ORDER BY version DESC LIMIT 1"
                ),
                params![file.to_string()],
                version_of,
            )
            .optional()
            .map_err(self.fail("cannot read the recipe versions"))?;
        if let Some(v) = newest.as_ref().filter(|v| v.hash == hash) {
            return Ok((v.clone(), false));
        }
        let v = RecipeVersion {
            file: file.clone(),
            version: newest.map_or(1, |v| v.version + 1),
            hash,
            author: who.to_string(),
            at_ms: self.now,
            message: message.to_string(),
        };
        self.conn
            .execute(
                "INSERT INTO recipe_versions (file, version, hash, author, at_ms, message, text) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                params![
                    file.to_string(),
                    v.version,
                    v.hash.as_str(),
                    who,
                    v.at_ms,
                    message,
                    text
                ],
            )
            .map_err(self.fail("cannot keep a recipe version"))?;
        Ok((v, true))
    }

    fn versions(&self, file: &RecipeFile) -> Result<Vec<RecipeVersion>, Self::Error> {
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT {VERSION_COLUMNS} FROM recipe_versions WHERE file = ?1 ORDER BY version"
            ))
            .map_err(self.fail("cannot read the recipe versions"))?;
        let rows = st
            .query_map(params![file.to_string()], version_of)
            .map_err(self.fail("cannot read the recipe versions"))?;
        rows.collect::<Result<Vec<_>, _>>()
            .map_err(self.fail("cannot read the recipe versions"))
    }

    fn version(
        &self,
        file: &RecipeFile,
        version: u32,
    ) -> Result<Option<(RecipeVersion, String)>, Self::Error> {
        self.conn
            .query_row(
                &format!(
                    "SELECT {VERSION_COLUMNS}, text FROM recipe_versions \
                     WHERE file = ?1 AND version = ?2"
                ),
                params![file.to_string(), version],
                |row| Ok((version_of(row)?, row.get(6)?)),
            )
            .optional()
            .map_err(self.fail("cannot read a recipe version"))
    }

    fn order_record(&self, id: i64) -> Result<Option<OrderRecord>, Self::Error> {
        let Some(order) = self.order(id)? else {
            return Ok(None);
        };
        let fail = || self.fail("cannot read an order's record");
        let mut st = self
            .conn
            .prepare(
                "SELECT started_ms, domain, file, version, hash, starts FROM order_recipes \
                 WHERE order_id = ?1 ORDER BY started_ms, position",
            )
            .map_err(fail())?;
        let rows = st
            .query_map(params![id], |row| {
                let file: String = row.get(2)?;
                let hash: String = row.get(4)?;
                let starts: String = row.get(5)?;
                Ok((
                    row.get::<_, i64>(0)?,
                    UsedRecipe {
                        domain: row.get(1)?,
                        file: recipe_file_of(&file, 2)?,
                        version: row.get(3)?,
                        hash: VersionHash::try_from(hash).map_err(|e| unreadable(4, e))?,
                        starts: serde_json::from_str(&starts)
                            .map_err(|e| unreadable(5, e.to_string()))?,
                    },
                ))
            })
            .map_err(fail())?;
        let mut runs: Vec<OrderRun> = Vec::new();
        for row in rows {
            let (started_ms, used) = row.map_err(fail())?;
            match runs.last_mut() {
                Some(run) if run.started_ms == started_ms => run.recipes.push(used),
                _ => runs.push(OrderRun {
                    started_ms,
                    recipes: vec![used],
                }),
            }
        }
        let mut query = EntryQuery::page(0, RECORD_ENTRIES);
        query.order = Some(id);
        let entries = self.entries(&query)?;
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT {ALARM_COLUMNS} FROM alarms WHERE order_id = ?1 ORDER BY id"
            ))
            .map_err(fail())?;
        let alarms = st
            .query_map(params![id], alarm_of)
            .map_err(fail())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(fail())?;
        let mut st = self
            .conn
            .prepare(
                "SELECT station, program, started_ms, ended_ms, outcome FROM jobs \
                 WHERE order_id = ?1 ORDER BY id",
            )
            .map_err(fail())?;
        let jobs = st
            .query_map(params![id], |r| {
                Ok(JobRecord {
                    station: r.get(0)?,
                    program: r.get(1)?,
                    started_ms: r.get(2)?,
                    ended_ms: r.get(3)?,
                    outcome: r.get(4)?,
                })
            })
            .map_err(fail())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(fail())?;
        Ok(Some(OrderRecord {
            order,
            runs,
            jobs,
            entries,
            alarms,
        }))
    }

    fn record_job(&mut self, order: Option<i64>, job: &JobRecord) -> Result<(), Self::Error> {
        self.conn
            .execute(
                "INSERT INTO jobs (order_id, cell, station, program, started_ms, ended_ms, outcome) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                params![
                    order,
                    self.cell,
                    job.station,
                    job.program,
                    job.started_ms,
                    job.ended_ms,
                    job.outcome
                ],
            )
            .map_err(self.fail("cannot keep a workstation's job"))
            .map(|_| ())
    }

    fn record_working(&mut self, working: bool) -> Result<(), Self::Error> {
        let newest: Option<bool> = self
            .conn
            .query_row(
                "SELECT working FROM list_states WHERE cell = ?1 ORDER BY id DESC LIMIT 1",
                params![self.cell],
                |r| r.get(0),
            )
            .optional()
            .map_err(self.fail("cannot read the order list's states"))?;
        if newest == Some(working) {
            return Ok(());
        }
        self.conn
            .execute(
                "INSERT INTO list_states (cell, at_ms, working) VALUES (?1, ?2, ?3)",
                params![self.cell, self.now, working],
            )
            .map_err(self.fail("cannot keep the order list's state"))
            .map(|_| ())
    }

    fn reports_filed(&self) -> Result<Vec<(String, String, u64)>, Self::Error> {
        let mut stmt = self
            .conn
            .prepare("SELECT station, run, no FROM reports_filed WHERE cell = ?1")
            .map_err(self.fail("cannot read the reports filed"))?;
        let rows = stmt
            .query_map(params![self.cell], |r| {
                let no: i64 = r.get(2)?;
                Ok((r.get(0)?, r.get(1)?, u64::try_from(no).unwrap_or(0)))
            })
            .map_err(self.fail("cannot read the reports filed"))?;
        rows.collect::<rusqlite::Result<Vec<_>>>()
            .map_err(self.fail("cannot read the reports filed"))
    }

    fn report_filed(&mut self, station: &str, run: &str, no: u64) -> Result<(), Self::Error> {
        self.conn
            .execute(
                "INSERT INTO reports_filed (cell, station, run, no) VALUES (?1, ?2, ?3, ?4) \
                 ON CONFLICT (cell, station) DO UPDATE SET run = excluded.run, no = excluded.no",
                params![
                    self.cell,
                    station,
                    run,
                    i64::try_from(no).unwrap_or(i64::MAX)
                ],
            )
            .map_err(self.fail("cannot keep the last report filed"))
            .map(|_| ())
    }

    fn record_mode(&mut self, mode: CellMode) -> Result<(), Self::Error> {
        let newest: Option<String> = self
            .conn
            .query_row(
                "SELECT mode FROM modes WHERE cell = ?1 ORDER BY id DESC LIMIT 1",
                params![self.cell],
                |r| r.get(0),
            )
            .optional()
            .map_err(self.fail("cannot read the modes"))?;
        if newest.as_deref() == Some(mode.as_str()) {
            return Ok(());
        }
        self.conn
            .execute(
                "INSERT INTO modes (cell, at_ms, mode) VALUES (?1, ?2, ?3)",
                params![self.cell, self.now, mode.as_str()],
            )
            .map_err(self.fail("cannot keep a mode change"))
            .map(|_| ())
    }

    fn figure_inputs(&self, since: i64, until: i64) -> Result<FigureInputs, Self::Error> {
        let fail = || self.fail("cannot read what the figures are computed from");
        let mut st = self
            .conn
            .prepare(
                "SELECT order_id, recipe, cell, started_ms, ended_ms, state FROM order_runs \
                 WHERE started_ms < ?2 AND (ended_ms IS NULL OR ended_ms > ?1) ORDER BY started_ms",
            )
            .map_err(fail())?;
        let runs = st
            .query_map(params![since, until], |r| {
                let state: String = r.get(5)?;
                Ok(RunSpan {
                    order: r.get(0)?,
                    recipe: r.get(1)?,
                    cell: r.get(2)?,
                    start_ms: r.get(3)?,
                    end_ms: r.get(4)?,
                    state: OrderState::parse(&state).unwrap_or(OrderState::Interrupted),
                })
            })
            .map_err(fail())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(fail())?;
        // An alarm written before alarms had a cell is of this one.
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT {ALARM_COLUMNS}, COALESCE(cell, ?3) FROM alarms WHERE raised_ms < ?2 \
                 AND (cleared_ms IS NULL OR acked_ms IS NULL OR cleared_ms > ?1 OR acked_ms > ?1)"
            ))
            .map_err(fail())?;
        let alarms = st
            .query_map(params![since, until, self.cell], |r| {
                Ok((alarm_of(r)?, r.get::<_, String>(9)?))
            })
            .map_err(fail())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(fail())?
            .into_iter()
            .filter(|(a, _)| a.gone_ms().map_or(true, |g| g > since))
            .map(|(a, cell)| AlarmSpan {
                cell,
                station: a.station.to_string(),
                class: a.class,
                raised_ms: a.raised_ms,
                gone_ms: a.gone_ms(),
            })
            .collect();
        let mut st = self
            .conn
            .prepare("SELECT cell, at_ms, mode FROM modes WHERE at_ms < ?1 ORDER BY id")
            .map_err(fail())?;
        let modes = st
            .query_map(params![until], |r| {
                let mode: String = r.get(2)?;
                Ok(ModeChange {
                    cell: r.get(0)?,
                    at_ms: r.get(1)?,
                    mode: mode.parse::<CellMode>().map_err(|e| unreadable(2, e))?,
                })
            })
            .map_err(fail())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(fail())?;
        let mut st = self
            .conn
            .prepare("SELECT cell, at_ms, working FROM list_states WHERE at_ms < ?1 ORDER BY id")
            .map_err(fail())?;
        let lists = st
            .query_map(params![until], |r| {
                Ok(ListChange {
                    cell: r.get(0)?,
                    at_ms: r.get(1)?,
                    working: r.get(2)?,
                })
            })
            .map_err(fail())?
            .collect::<Result<Vec<_>, _>>()
            .map_err(fail())?;
        Ok(FigureInputs {
            runs,
            alarms,
            modes,
            lists,
        })
    }

    fn entries(&self, q: &EntryQuery) -> Result<Vec<Entry>, Self::Error> {
        // The kinds asked for, in SQL: a page is `limit` matching entries,
        // however many others the journal holds between them.
        let kinds: Vec<&str> = EntryKind::ALL
            .into_iter()
            .filter(|k| !q.messages_only || k.is_message())
            .map(EntryKind::as_str)
            .collect();
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT id, at_ms, order_id, kind, who, text, cell FROM journal
                 WHERE id > ?1 AND (?2 IS NULL OR order_id = ?2) AND kind IN ('{}')
                 AND (?4 IS NULL OR cell IS NULL OR cell = ?4)
                 ORDER BY id {} LIMIT ?3",
                kinds.join("','"),
                if q.newest { "DESC" } else { "ASC" }
            ))
            .map_err(self.fail("cannot read the journal"))?;
        let limit = i64::try_from(q.limit).unwrap_or(i64::MAX);
        let rows = st
            .query_map(params![q.after, q.order, limit, q.cell], entry_of)
            .map_err(self.fail("cannot read the journal"))?;
        let mut out = rows
            .collect::<Result<Vec<_>, _>>()
            .map_err(self.fail("cannot read the journal"))?;
        if q.newest {
            out.reverse();
        }
        Ok(out)
    }
}

/// `path` with `suffix` appended (`falc.db` → `falc.db-wal`).
fn wal_of(path: &Path, suffix: &str) -> std::path::PathBuf {
    let mut p = path.as_os_str().to_os_string();
    p.push(suffix);
    p.into()
}

/// Takes group and others' permissions off the journal's directory `dir`,
/// if it is this user's own. A shared directory (another user's, or one
/// with the sticky bit, like `/tmp`) is left as it is, with a warning: the
/// journal's files are private in it all the same.
fn make_private_dir(dir: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let Ok(meta) = std::fs::metadata(dir) else {
        return Ok(());
    };
    let mode = meta.permissions().mode();
    if mode & 0o077 == 0 {
        return Ok(());
    }
    if mode & 0o1000 != 0 || meta.uid() != nix::unistd::geteuid().as_raw() {
        tracing::warn!(
            dir = %dir.display(),
            "the journal's directory is shared (mode {:o}); its files are private, \
             but give the journal a directory of its own (falc-operator --db)",
            mode & 0o7777
        );
        return Ok(());
    }
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(mode & 0o700))
}

/// Takes group and others' permissions off `file` if it exists.
fn make_private(file: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    match std::fs::metadata(file) {
        Ok(meta) if meta.permissions().mode() & 0o077 != 0 => {
            let mode = meta.permissions().mode() & 0o700;
            std::fs::set_permissions(file, std::fs::Permissions::from_mode(mode))
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("station name")
    }

    const ANY: Placement = Placement {
        cell: None,
        priority: 0,
        due_ms: None,
        job_order: None,
    };

    /// The file's dispatch order is the model's ([`Order::dispatch_key`]
    /// among the orders a cell may run), for every cell.
    #[test]
    fn the_next_order_is_the_one_the_core_would_take() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut db = Database::open(&dir.path().join("falc.db"), "falc1").expect("open");
        let cells = [None, Some("falc1"), Some("falc2")];
        let mut seed: u64 = 7;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 33) as i64
        };
        for _ in 0..60 {
            let placement = Placement {
                cell: cells[(next() % 3) as usize]
                    .map(|c| falc_model::ids::CellId::new(c).expect("id")),
                priority: (next() % 5) as i32 - 2,
                due_ms: (next() % 2 == 0).then(|| next() % 4),
                job_order: None,
            };
            db.add_order("dikdroog", "ann", &placement).expect("add");
        }
        for round in 0..60 {
            let cell = ["falc1", "falc2", "falc3"][round % 3];
            let a = db.next_queued(cell).expect("next").map(|o| o.id);
            let b = db
                .orders()
                .expect("orders")
                .into_iter()
                .filter(|o| o.state == OrderState::Queued && o.may_run_on(cell))
                .min_by_key(|o| o.dispatch_key())
                .map(|o| o.id);
            assert_eq!(a, b, "round {round}, {cell}");
            if let Some(id) = a {
                db.set_running(id, cell, &[]).expect("run");
            }
        }
        let on = |id| db.order(id).expect("read").and_then(|o| o.cell);
        let ran: Vec<Order> = db
            .orders()
            .expect("orders")
            .into_iter()
            .filter(|o| o.state == OrderState::Running)
            .collect();
        assert!(!ran.is_empty());
        for o in ran {
            assert!(o.may_run_on(on(o.id).as_deref().unwrap_or("")), "{o:?}");
        }
    }

    /// Each cell's list sees its own alarms (and one of the file made
    /// before cells had them), every order, and every journal entry; alarm
    /// numbers are the plant's.
    #[test]
    fn alarms_are_each_cells_own_and_orders_and_journal_the_plants() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("falc.db");
        let mut one = Database::open(&path, "falc1").expect("open");
        let mut two = Database::open(&path, "falc2").expect("open");
        one.conn
            .execute(
                "INSERT INTO alarms (station, class, text, raised_ms) VALUES ('cell', 'process', 'old', 1)",
                [],
            )
            .expect("an alarm of before");
        let a = one
            .raise_alarm(&st("welding"), AlarmClass::Safety, "estop", None)
            .expect("raise");
        let b = two
            .raise_alarm(&st("transport"), AlarmClass::Device, "jam", None)
            .expect("raise");
        assert_ne!(a.id, b.id);
        let texts = |db: &Database| -> Vec<String> {
            db.listed_alarms()
                .expect("list")
                .into_iter()
                .map(|a| a.text)
                .collect()
        };
        assert_eq!(texts(&one), ["old", "estop"]);
        assert_eq!(texts(&two), ["old", "jam"]);
        two.add_order("dikdroog", "ann", &ANY).expect("add");
        one.journal(EntryKind::Action, None, "ann", "in falc1")
            .expect("journal");
        assert_eq!(one.orders().expect("orders").len(), 1);
        assert_eq!(
            two.entries(&EntryQuery::page(0, 10))
                .expect("journal")
                .len(),
            1
        );
        // A cell's own journal: its entries and those of before cells.
        assert!(two
            .entries(&EntryQuery {
                cell: Some("falc2"),
                ..EntryQuery::page(0, 10)
            })
            .expect("journal")
            .is_empty());
        let of_one = one
            .entries(&EntryQuery {
                cell: Some("falc1"),
                ..EntryQuery::page(0, 10)
            })
            .expect("journal");
        assert_eq!(of_one.len(), 1);
        assert_eq!(of_one[0].cell.as_deref(), Some("falc1"));
        // The newest of a cell's entries, oldest first, however many of
        // another cell's came after them.
        for i in 0..5 {
            one.journal(EntryKind::Action, None, "ann", &format!("one {i}"))
                .expect("journal");
        }
        for i in 0..50 {
            two.journal(EntryKind::Action, None, "bob", &format!("two {i}"))
                .expect("journal");
        }
        let newest = |db: &Database, cell: &str| -> Vec<String> {
            db.entries(&EntryQuery {
                cell: Some(cell),
                newest: true,
                ..EntryQuery::page(0, 3)
            })
            .expect("journal")
            .into_iter()
            .map(|e| e.text)
            .collect()
        };
        assert_eq!(newest(&one, "falc1"), ["one 2", "one 3", "one 4"]);
        assert_eq!(newest(&two, "falc2"), ["two 47", "two 48", "two 49"]);
    }

    /// A file made before orders had a cell, a priority and a due time
    /// gets the columns at open; its orders read as placed by default.
    /// An alarm row whose station is no station name (a file edited by
    /// hand) is refused when read, naming the column and the value, not
    /// taken in as a station.
    #[test]
    fn an_alarm_of_no_station_is_refused_naming_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let db = Database::open(&dir.path().join("falc.db"), "falc1").expect("open");
        db.conn
            .execute(
                "INSERT INTO alarms (station, class, text, raised_ms, cell) \
                 VALUES ('Weld ing!', 'device', 'jam', 1, 'falc1')",
                [],
            )
            .expect("a row written by hand");
        let e = db.listed_alarms().expect_err("refused");
        let text = e.to_string();
        assert!(text.contains("Weld ing!"), "{text}");
    }

    #[test]
    fn a_file_of_the_first_schema_gets_the_new_columns() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("falc.db");
        {
            let conn = Connection::open(&path).expect("open");
            conn.execute_batch(
                "CREATE TABLE orders (id INTEGER PRIMARY KEY AUTOINCREMENT, recipe TEXT NOT NULL, \
                 state TEXT NOT NULL, added_by TEXT NOT NULL, added_ms INTEGER NOT NULL, \
                 started_ms INTEGER, ended_ms INTEGER, result TEXT); \
                 INSERT INTO orders (recipe, state, added_by, added_ms) VALUES ('dikdroog', 'queued', 'ann', 1);",
            )
            .expect("the first schema");
        }
        let mut db = Database::open(&path, "falc1").expect("open");
        let o = db
            .next_queued("falc1")
            .expect("next")
            .expect("the old order");
        assert_eq!(
            (
                o.recipe.as_str(),
                o.priority,
                o.due_ms,
                o.wanted,
                o.cell,
                o.job_order
            ),
            ("dikdroog", 0, None, None, None, None)
        );
        db.set_running(o.id, "falc1", &[]).expect("run");
        // An order of a manufacturing execution system's job order keeps
        // its JobOrderID.
        let job = db
            .add_order(
                "dikdroog",
                "opcua",
                &Placement {
                    job_order: Some("MES-4711".into()),
                    ..ANY
                },
            )
            .expect("add");
        drop(db);
        let db = Database::open(&path, "falc1").expect("opened again");
        let o = db.order(o.id).expect("read").expect("there");
        assert_eq!(o.cell.as_deref(), Some("falc1"));
        let job = db.order(job.id).expect("read").expect("there");
        assert_eq!(job.job_order.as_deref(), Some("MES-4711"));
    }

    #[test]
    fn the_journal_and_its_directory_are_private() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("var/falc.db");
        let mut db = Database::open(&path, "falc1").expect("open");
        db.raise_alarm(&st("welding"), AlarmClass::Safety, "estop", Some(1))
            .expect("write");
        let mode = |p: &Path| std::fs::metadata(p).expect("exists").permissions().mode() & 0o777;
        assert_eq!(mode(&path), 0o600);
        assert_eq!(mode(&dir.path().join("var")), 0o700);
        assert_eq!(mode(&dir.path().join("var/falc.db-wal")), 0o600);
        // A journal made before the rule, readable by all, is made private.
        let old = dir.path().join("old.db");
        drop(Database::open(&old, "falc1").expect("open"));
        std::fs::set_permissions(&old, std::fs::Permissions::from_mode(0o644)).expect("chmod");
        drop(Database::open(&old, "falc1").expect("reopen"));
        assert_eq!(mode(&old), 0o600);
        // A directory made before, open to all, is made private too.
        std::fs::set_permissions(
            dir.path().join("var"),
            std::fs::Permissions::from_mode(0o777),
        )
        .expect("chmod");
        drop(Database::open(&path, "falc1").expect("reopen"));
        assert_eq!(mode(&dir.path().join("var")), 0o700);
    }

    #[test]
    fn alarms_survive_a_reopen_until_acknowledged_and_cleared() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("falc.db");
        let (a, b) = {
            let mut s = Database::open(&path, "falc1").expect("open");
            let a = s
                .raise_alarm(&st("welding"), AlarmClass::Safety, "estop", Some(1))
                .expect("raise");
            let b = s
                .raise_alarm(&st("transport"), AlarmClass::Device, "not ready", None)
                .expect("raise");
            s.ack_alarm(a.id, "ann", 5).expect("ack");
            s.clear_alarm(b.id, 6).expect("clear");
            (a, b)
        };
        let mut s = Database::open(&path, "falc1").expect("reopen");
        let listed = s.listed_alarms().expect("list");
        assert_eq!(listed.len(), 2);
        assert_eq!(listed[0].acked, Some(("ann".into(), 5)));
        assert_eq!(listed[1].cleared_ms, Some(6));
        s.clear_alarm(a.id, 7).expect("clear");
        s.ack_alarm(b.id, "bob", 8).expect("ack");
        assert!(s.listed_alarms().expect("list").is_empty());
        // A second acknowledgement does not overwrite the first.
        s.ack_alarm(a.id, "eve", 9).expect("ack");
        let row = s
            .conn
            .query_row("SELECT acked_by FROM alarms WHERE id = ?1", [a.id], |r| {
                r.get::<_, String>(0)
            })
            .expect("row");
        assert_eq!(row, "ann");
    }

    #[test]
    fn the_newest_running_order_of_a_cell_is_adopted_and_an_older_one_interrupted() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("falc.db");
        let mut s = Database::open(&path, "falc1").expect("open");
        let a = s.add_order("dikdroog", "ann", &ANY).expect("add");
        let b = s.add_order("dundroog", "ann", &ANY).expect("add");
        s.set_running(a.id, "falc1", &[]).expect("run");
        s.set_running(b.id, "falc1", &[]).expect("run");
        drop(s);
        let mut s = Database::open(&path, "falc1").expect("reopen");
        let r = s.recover(&["falc1"]).expect("recover");
        assert_eq!(
            r.adopted.iter().map(|o| o.id).collect::<Vec<_>>(),
            vec![b.id]
        );
        assert_eq!(
            r.interrupted.iter().map(|o| o.id).collect::<Vec<_>>(),
            vec![a.id]
        );
        let states: Vec<OrderState> = s
            .orders()
            .expect("orders")
            .iter()
            .map(|o| o.state)
            .collect();
        assert_eq!(states, vec![OrderState::Interrupted, OrderState::Running]);
        let j = s
            .entries(&EntryQuery {
                order: Some(b.id),
                ..EntryQuery::page(0, 100)
            })
            .expect("entries");
        assert!(
            j.iter()
                .any(|e| e.text.contains("the cell is asked how it ended")),
            "{j:?}"
        );
    }

    #[test]
    fn recipe_versions_are_kept_never_changed_and_each_run_records_its_own() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("falc.db");
        let mut s = Database::open(&path, "falc1").expect("open");
        let file =
            RecipeFile::new(StationName::new("welding").expect("v"), "droog_dik").expect("file");
        let (v1, new) = s
            .add_version(&file, "-1 | a | | | 0\n", "falc", "")
            .expect("v1");
        assert!(new && v1.version == 1);
        // The same text again is no new version.
        let (again, new) = s
            .add_version(&file, "-1 | a | | | 0\n", "eva", "x")
            .expect("v1");
        assert!(!new && again == v1);
        let (v2, _) = s
            .add_version(&file, "-1 | b | | | 0\n", "eva", "thicker")
            .expect("v2");
        assert_eq!(
            (v2.version, v2.author.as_str(), v2.message.as_str()),
            (2, "eva", "thicker")
        );
        assert_ne!(v1.hash, v2.hash);
        // Back to the first text: a third version, the first kept as it was.
        let (v3, _) = s
            .add_version(&file, "-1 | a | | | 0\n", "eva", "back")
            .expect("v3");
        assert_eq!((v3.version, &v3.hash), (3, &v1.hash));
        assert_eq!(s.versions(&file).expect("list").len(), 3);
        assert_eq!(
            s.version(&file, 2)
                .expect("read")
                .map(|(v, t)| (v.version, t)),
            Some((2, "-1 | b | | | 0\n".to_string()))
        );
        assert_eq!(s.version(&file, 9).expect("read"), None);
        // Neither changed nor removed, even by hand.
        for sql in [
            "UPDATE recipe_versions SET text = 'x'",
            "DELETE FROM recipe_versions",
        ] {
            let e = s.conn.execute(sql, []).expect_err("refused");
            assert!(e.to_string().contains("never"), "{e}");
        }
        // Each run of an order keeps its versions; a run the cell refused
        // goes with the requeue.
        let used = |v: &RecipeVersion| UsedRecipe {
            domain: "WELDING$DROOG_DIK".into(),
            file: v.file.clone(),
            version: v.version,
            hash: v.hash.clone(),
            starts: vec!["program 12".into()],
        };
        let o = s.add_order("dikdroog", "ann", &ANY).expect("add");
        s.set_running(o.id, "falc1", &[used(&v1)]).expect("run");
        s.requeue(o.id).expect("requeue");
        assert!(s
            .order_record(o.id)
            .expect("read")
            .expect("there")
            .runs
            .is_empty());
        s.set_running(o.id, "falc1", &[used(&v2)]).expect("run");
        s.end_order(o.id, OrderState::Failed, "alarm").expect("end");
        // The records' time is the time they are given.
        let later = s.now_ms() + 2;
        s.set_now(later);
        s.set_running(o.id, "falc1", &[used(&v3)])
            .expect("run again");
        s.journal(EntryKind::Order, Some(o.id), "falc", "order started")
            .expect("j");
        s.raise_alarm(&st("welding"), AlarmClass::Safety, "estop", Some(o.id))
            .expect("alarm");
        drop(s);
        let s = Database::open(&path, "falc1").expect("reopen");
        let r = s.order_record(o.id).expect("read").expect("there");
        let versions: Vec<u32> = r.runs.iter().map(|run| run.recipes[0].version).collect();
        assert_eq!(versions, vec![2, 3]);
        assert_eq!(r.runs[0].recipes[0].starts, vec!["program 12".to_string()]);
        assert_eq!(r.entries.len(), 1);
        assert_eq!(r.alarms.len(), 1);
        assert_eq!(s.order_record(999).expect("read"), None);
    }

    #[test]
    fn the_figures_read_each_run_with_its_end_the_alarms_as_they_held_and_the_modes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut s = Database::open(&dir.path().join("falc.db"), "falc1").expect("open");
        let a = s.add_order("dikdroog", "ann", &ANY).expect("add");
        let b = s.add_order("dunnat", "ann", &ANY).expect("add");
        s.set_running(a.id, "falc1", &[]).expect("run");
        s.end_order(a.id, OrderState::Stopped, "stopped")
            .expect("end");
        s.set_running(a.id, "falc1", &[]).expect("restart");
        s.end_order(a.id, OrderState::Done, "done").expect("end");
        s.set_running(b.id, "falc1", &[]).expect("run");
        s.record_mode(CellMode::Step).expect("mode");
        s.record_mode(CellMode::Step)
            .expect("the same mode: no change");
        s.record_mode(CellMode::Auto).expect("mode");
        let alarm = s
            .raise_alarm(&st("welding"), AlarmClass::Safety, "estop", Some(b.id))
            .expect("alarm");
        s.clear_alarm(alarm.id, now_ms()).expect("clear");
        let i = s.figure_inputs(0, now_ms() + 1000).expect("read");
        let runs: Vec<(i64, &str, OrderState, bool)> = i
            .runs
            .iter()
            .map(|r| (r.order, r.recipe.as_str(), r.state, r.end_ms.is_some()))
            .collect();
        assert_eq!(
            runs,
            vec![
                (a.id, "dikdroog", OrderState::Stopped, true),
                (a.id, "dikdroog", OrderState::Done, true),
                (b.id, "dunnat", OrderState::Running, false),
            ]
        );
        let modes: Vec<CellMode> = i.modes.iter().map(|m| m.mode).collect();
        assert_eq!(modes, vec![CellMode::Step, CellMode::Auto]);
        // Cleared, not acknowledged: it still holds the cell.
        assert_eq!(i.alarms.len(), 1);
        assert_eq!(
            (i.alarms[0].cell.as_str(), i.alarms[0].gone_ms),
            ("falc1", None)
        );
        // A range after everything that ended holds only what still runs
        // or holds.
        let later = s
            .figure_inputs(now_ms() + 500, now_ms() + 1000)
            .expect("read");
        assert_eq!(later.runs.len(), 1);
        assert_eq!(later.alarms.len(), 1);
    }

    #[test]
    fn only_a_running_order_goes_back_to_the_queue() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut s = Database::open(&dir.path().join("falc.db"), "falc1").expect("open");
        let a = s.add_order("dikdroog", "ann", &ANY).expect("add");
        s.set_running(a.id, "falc1", &[]).expect("run");
        s.requeue(a.id).expect("requeue");
        let o = s.order(a.id).expect("read").expect("there");
        assert_eq!(
            (o.state, o.started_ms, o.cell),
            (OrderState::Queued, None, None)
        );
        s.set_running(a.id, "falc1", &[]).expect("run");
        s.end_order(a.id, OrderState::Done, "done").expect("end");
        s.requeue(a.id).expect("a no-op");
        let o = s.order(a.id).expect("read").expect("there");
        assert_eq!(
            o.state,
            OrderState::Done,
            "an order that ran is never queued again"
        );
    }

    #[test]
    fn orders_and_journal_survive_a_reopen_and_running_becomes_interrupted() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("falc.db");
        {
            let mut s = Database::open(&path, "falc1").expect("open");
            let a = s.add_order("dikdroog", "ann", &ANY).expect("add");
            let b = s.add_order("dundroog", "ann", &ANY).expect("add");
            s.set_running(a.id, "falc1", &[]).expect("run");
            s.journal(EntryKind::Order, Some(a.id), "operator", "started")
                .expect("journal");
            assert_eq!(
                s.next_queued("falc1").expect("next").map(|o| o.id),
                Some(b.id)
            );
            assert!(s.remove_order(a.id).expect("db").is_err(), "running");
            // Dropped without ending the order: a crash.
        }
        let mut s = Database::open(&path, "falc1").expect("reopen");
        // Its cell is no cell of the plant now: interrupted.
        let r = s.recover(&["falc2"]).expect("recover");
        assert_eq!((r.adopted.len(), r.interrupted.len()), (0, 1));
        let orders = s.orders().expect("orders");
        assert_eq!(orders[0].state, OrderState::Interrupted);
        assert_eq!(orders[1].state, OrderState::Queued);
        let j = s
            .entries(&EntryQuery {
                order: Some(orders[0].id),
                ..EntryQuery::page(0, 100)
            })
            .expect("entries");
        assert_eq!(j.len(), 2);
        assert!(j[1].text.contains("interrupted"), "{j:?}");
        assert!(s
            .entries(&EntryQuery {
                messages_only: true,
                ..EntryQuery::page(0, 100)
            })
            .expect("m")
            .is_empty());
        assert_eq!(
            s.remove_order(orders[1].id).expect("db").map(|o| o.recipe),
            Ok("dundroog".into())
        );
        assert!(s.remove_order(99).expect("db").is_err());
        // A page holds `limit` matching entries, whatever lies between them.
        for _ in 0..5 {
            s.journal(EntryKind::Action, None, "ann", "x")
                .expect("journal");
        }
        let m = s
            .journal(EntryKind::Message, Some(2), "cell", "einde")
            .expect("journal");
        assert_eq!(
            s.entries(&EntryQuery {
                messages_only: true,
                ..EntryQuery::page(0, 1)
            })
            .expect("page"),
            vec![m.clone()]
        );
        assert_eq!(s.journal_head().expect("head"), m.id);
        let empty = Database::open(&dir.path().join("empty.db"), "falc1").expect("open");
        assert_eq!(empty.journal_head().expect("head"), 0);
    }
}
