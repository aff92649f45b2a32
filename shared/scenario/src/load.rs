//! Reading a scenario file: TOML into the [`schema`](crate::schema) types,
//! with errors that name the line, the column and the field; then the
//! command line's overrides.

use crate::ScenarioError;
use crate::schema::{Overrides, Scenario};
use std::collections::BTreeSet;
use std::io::Read;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

/// The largest scenario file read: a scenario is kilobytes, inline model
/// arrays of the largest model the loop takes (128 states) a few hundred.
pub const MAX_SCENARIO_BYTES: u64 = 4 * 1024 * 1024;

/// The text of the scenario file at `path`: a regular file (or a link to
/// one) of at most [`MAX_SCENARIO_BYTES`], checked before it is read and
/// opened without blocking, so that /dev/zero, a FIFO or a huge file named
/// as a scenario is refused at once rather than read until memory runs out
/// or waited on forever.
pub fn read_scenario_text(path: &Path) -> Result<String, ScenarioError> {
    let refuse = |reason: String| Err(ScenarioError::new(path, None, reason));
    let check = |meta: &std::fs::Metadata| -> Result<(), String> {
        if !meta.is_file() {
            return Err(
                "is not a regular file (a directory, a FIFO or a device): give a scenario's \
                 TOML file"
                    .into(),
            );
        }
        if meta.len() > MAX_SCENARIO_BYTES {
            return Err(format!(
                "is {} bytes, beyond the {MAX_SCENARIO_BYTES} a scenario may have",
                meta.len()
            ));
        }
        Ok(())
    };
    let meta = match std::fs::metadata(path) {
        Ok(m) => m,
        Err(e) => return refuse(format!("cannot read: {e}")),
    };
    if let Err(why) = check(&meta) {
        return refuse(why);
    }
    let file = match std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
    {
        Ok(f) => f,
        Err(e) => return refuse(format!("cannot read: {e}")),
    };
    // The file opened may not be the one looked at (replaced in between).
    match file.metadata() {
        Ok(m) => {
            if let Err(why) = check(&m) {
                return refuse(why);
            }
        }
        Err(e) => return refuse(format!("cannot read: {e}")),
    }
    let mut text = String::new();
    match file.take(MAX_SCENARIO_BYTES + 1).read_to_string(&mut text) {
        Ok(n) if n as u64 > MAX_SCENARIO_BYTES => refuse(format!(
            "is longer than the {MAX_SCENARIO_BYTES} bytes a scenario may have"
        )),
        Ok(_) => Ok(text),
        Err(e) => refuse(format!("cannot read: {e}")),
    }
}

impl Scenario {
    /// Reads, parses, applies `overrides` and validates `path`.
    pub fn load(path: &Path, overrides: &Overrides) -> Result<Self, ScenarioError> {
        let text = read_scenario_text(path)?;
        Self::from_text(path, &text, overrides)
    }

    /// What [`load`](Self::load) does once the file is read: parses `text`
    /// as if read from `path`, applies `overrides` and validates.
    pub fn from_text(
        path: &Path,
        text: &str,
        overrides: &Overrides,
    ) -> Result<Self, ScenarioError> {
        let mut scenario = Self::parse(path, text)?;
        scenario.apply(overrides);
        scenario.validate()?;
        Ok(scenario)
    }

    /// Parses `text` as if read from `path` (no validation).
    pub fn parse(path: &Path, text: &str) -> Result<Self, ScenarioError> {
        let mut scenario: Scenario =
            toml::from_str(text).map_err(|e| parse_error(path, text, &e))?;
        scenario.source = path.to_path_buf();
        let mut given = BTreeSet::new();
        if let Ok(table) = toml::from_str::<toml::Table>(text) {
            dotted_keys("", &table, &mut given);
        }
        scenario.plant.output_given = given.contains("plant.output");
        scenario.given = given;
        Ok(scenario)
    }

    /// Puts the thesis chain's world-fixed sensor at `position` (node units),
    /// in place of whatever output or scan the file named (the scan's
    /// scheduling settings go with it); `validate` checks the range.
    pub fn set_sensor_position(&mut self, position: f64) {
        self.plant.sensor_position = Some(position);
        self.plant.output_given = false;
        self.plant.sensor_scan = None;
        for field in [
            "plant.output",
            "plant.sensor_scan",
            "observer.scheduling",
            "observer.scheduling_step",
        ] {
            self.given.remove(field);
        }
    }

    pub fn apply(&mut self, overrides: &Overrides) {
        if let Some(rate) = overrides.rate_hz {
            self.timing.rate_hz = rate;
        }
        if let Some(duration) = overrides.duration_s {
            self.timing.duration_s = duration;
        }
        if let Some(mode) = overrides.mode {
            self.timing.mode = mode;
        }
        if let Some(tick) = overrides.tick {
            // As if the file named it: validation refuses it where it does
            // not act, as it would the file's.
            self.realtime.tick = tick;
            self.given.insert("realtime.tick".into());
        }
        if overrides.no_realtime {
            for p in [
                &mut self.realtime.plant,
                &mut self.realtime.observer,
                &mut self.realtime.controller,
                &mut self.realtime.logger,
            ] {
                p.priority = None;
            }
            self.realtime.hold_cpu_dma_latency = false;
            self.realtime.lock_memory = false;
        }
    }
}

/// The parser's error as file, field and reason: the field qualified by
/// its table (`plant.mas_kg`), the position as line and column.
fn parse_error(path: &Path, text: &str, e: &toml::de::Error) -> ScenarioError {
    let message = e.message().trim();
    let Some(at) = e.span().map(|span| span.start) else {
        // The parser's nesting limit comes without a position: find the line.
        if message.contains("recursion") {
            let (line, key) = deepest_line(text);
            return ScenarioError::new(
                path,
                Some(&key),
                format!(
                    "nested too deeply (line {line}): the format's tables go at most three \
                     levels deep"
                ),
            );
        }
        let field = field_in_message(message);
        return ScenarioError::new(path, field.as_deref(), message.to_string());
    };
    let (line, col) = line_col(text, at);
    if let Some(name) = array_of_tables_at(text, at) {
        return ScenarioError::new(
            path,
            Some(&name),
            format!(
                "`[[{name}]]` is an array of tables; the format has one `[{name}]` table \
                 (line {line})"
            ),
        );
    }
    let table = table_at(text, at);
    let field = field_in_message(message)
        .or_else(|| key_at(text, at))
        .map(|key| match &table {
            Some(table) if !key.starts_with(&format!("{table}.")) && key != *table => {
                format!("{table}.{key}")
            }
            _ => key,
        })
        .or(table);
    ScenarioError::new(
        path,
        field.as_deref(),
        format!("{message} (line {line}, column {col})"),
    )
}

/// Every dotted key of `table` that holds a value (tables are walked into).
fn dotted_keys(prefix: &str, table: &toml::Table, out: &mut BTreeSet<String>) {
    for (key, value) in table {
        let dotted = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        match value {
            toml::Value::Table(inner) => dotted_keys(&dotted, inner, out),
            _ => {
                out.insert(dotted);
            }
        }
    }
}

/// The `[table]` header in force at byte `at`, if any.
fn table_at(text: &str, at: usize) -> Option<String> {
    let line_end = text[at.min(text.len())..]
        .find('\n')
        .map_or(text.len(), |i| at + i);
    text[..line_end].lines().rev().find_map(header)
}

/// `name` of a `[name]` or `[[name]]` line.
fn header(line: &str) -> Option<String> {
    let line = line.trim();
    if !line.starts_with('[') {
        return None;
    }
    let inner = line.trim_start_matches('[');
    let name = inner[..inner.find(']')?].trim();
    (!name.is_empty()).then(|| name.to_string())
}

/// The name of the `[[name]]` header on the line of byte `at`, or of the
/// one in force there: the format has no arrays of tables.
fn array_of_tables_at(text: &str, at: usize) -> Option<String> {
    let line_end = text[at.min(text.len())..]
        .find('\n')
        .map_or(text.len(), |i| at + i);
    let line = text[..line_end]
        .lines()
        .rev()
        .find(|l| l.trim_start().starts_with('['))?;
    line.trim_start()
        .starts_with("[[")
        .then(|| header(line))
        .flatten()
}

/// The line that nests deepest (a dotted header, or brackets and braces in
/// a value) and its key, for the parser's nesting limit.
fn deepest_line(text: &str) -> (usize, String) {
    let depth = |line: &str| -> usize {
        let line = line.trim();
        if let Some(name) = header(line) {
            return name.split('.').count();
        }
        let (mut depth, mut deepest) = (0usize, 0usize);
        for c in line.chars() {
            match c {
                '[' | '{' => {
                    depth += 1;
                    deepest = deepest.max(depth);
                }
                ']' | '}' => depth = depth.saturating_sub(1),
                _ => {}
            }
        }
        deepest
    };
    let (index, line) = text
        .lines()
        .enumerate()
        .max_by_key(|(i, l)| (depth(l), usize::MAX - i))
        .unwrap_or((0, ""));
    let key = match header(line) {
        Some(name) => name
            .split('.')
            .next()
            .unwrap_or_default()
            .trim()
            .to_string(),
        None => line
            .split('=')
            .next()
            .unwrap_or_default()
            .trim()
            .to_string(),
    };
    let key = if key.is_empty() {
        "(top level)".into()
    } else {
        key
    };
    (index + 1, key)
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map(|i| i + 1).unwrap_or(0) + 1;
    (line, col)
}

/// The key of the `key = value` line holding byte `at` (for a bad value,
/// where serde's message names the value, not the field).
fn key_at(text: &str, at: usize) -> Option<String> {
    let line_start = text[..at.min(text.len())].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    (!key.is_empty() && !key.starts_with('[')).then(|| key.to_string())
}

/// Pulls the field name out of serde's "unknown field `x`" / "missing field `x`".
fn field_in_message(message: &str) -> Option<String> {
    if !message.contains("field `") {
        return None;
    }
    let start = message.find("field `")? + "field `".len();
    let end = start + message[start..].find('`')?;
    Some(message[start..end].to_string())
}
