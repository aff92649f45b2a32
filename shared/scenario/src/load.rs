//! Reading a scenario file: TOML into the [`schema`](crate::schema) types,
//! with errors that name the line, the column and the field; then the
//! command line's overrides.

use crate::ScenarioError;
use crate::schema::{Overrides, Scenario};
use std::path::Path;

impl Scenario {
    /// Reads, parses, applies `overrides` and validates `path`.
    pub fn load(path: &Path, overrides: &Overrides) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ScenarioError::new(path, None, format!("cannot read: {e}")))?;
        let mut scenario = Self::parse(path, &text)?;
        scenario.apply(overrides);
        scenario.validate()?;
        Ok(scenario)
    }

    /// Parses `text` as if read from `path` (no validation).
    pub fn parse(path: &Path, text: &str) -> Result<Self, ScenarioError> {
        let mut scenario: Scenario = toml::from_str(text).map_err(|e| {
            let (line, col) = e
                .span()
                .map(|span| line_col(text, span.start))
                .unwrap_or((0, 0));
            let field = field_in_message(e.message())
                .or_else(|| e.span().and_then(|span| key_at(text, span.start)));
            ScenarioError::new(
                path,
                field.as_deref(),
                format!("{} (line {line}, column {col})", e.message().trim()),
            )
        })?;
        scenario.source = path.to_path_buf();
        scenario.plant.output_given = toml::from_str::<toml::Table>(text)
            .ok()
            .and_then(|t| t.get("plant")?.as_table()?.get("output").cloned())
            .is_some();
        Ok(scenario)
    }

    /// Puts the thesis chain's world-fixed sensor at `position` (node units),
    /// in place of whatever output the file named; `validate` checks the range.
    pub fn set_sensor_position(&mut self, position: f64) {
        self.plant.sensor_position = Some(position);
        self.plant.output_given = false;
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
