//! Arrays written in the scenario's TOML for small models: each name is a
//! number, an array of numbers (1-D), or an array of rows of numbers (2-D).

use toml::Value;

use crate::array::{Array, signed_to_f64};
use crate::error::ModelFileErrorKind;
use crate::read::{Entry, Fault, NamedArrays};

/// The table's entries as arrays. A value that is not numbers is refused
/// when the array is asked for, like a file's text or complex arrays.
pub(crate) fn read(table: &toml::Table) -> Result<NamedArrays, Fault> {
    let mut arrays = NamedArrays::new();
    for (name, value) in table {
        arrays.insert(name.clone(), array_of(value))?;
    }
    Ok(arrays)
}

fn array_of(value: &Value) -> Entry {
    let (shape, data) = match value {
        Value::Array(items) if items.iter().any(Value::is_array) => matrix(items)?,
        Value::Array(items) => {
            let row = numbers(items, None)?;
            (vec![row.len()], row)
        }
        other => (vec![], vec![number(other, "the value")?]),
    };
    // The shape holds the entries by construction.
    Array::new(shape, data).ok_or(ModelFileErrorKind::InlineTooDeep)
}

/// Rows of numbers of equal length.
fn matrix(rows: &[Value]) -> Result<(Vec<usize>, Vec<f64>), ModelFileErrorKind> {
    let mut data = Vec::new();
    let mut first_len = None;
    for (row, value) in rows.iter().enumerate() {
        let Value::Array(items) = value else {
            return Err(ModelFileErrorKind::InlineMixed);
        };
        if items.iter().any(Value::is_array) {
            return Err(ModelFileErrorKind::InlineTooDeep);
        }
        let numbers = numbers(items, Some(row))?;
        let first = *first_len.get_or_insert(numbers.len());
        if numbers.len() != first {
            return Err(ModelFileErrorKind::InlineRaggedRows {
                row,
                len: numbers.len(),
                first_len: first,
            });
        }
        data.extend(numbers);
    }
    Ok((vec![rows.len(), first_len.unwrap_or(0)], data))
}

/// A row (or a 1-D array) of numbers; `row` is its place in a matrix.
fn numbers(items: &[Value], row: Option<usize>) -> Result<Vec<f64>, ModelFileErrorKind> {
    items
        .iter()
        .enumerate()
        .map(|(i, item)| {
            let at = match row {
                Some(row) => format!("row {}, element {}", row + 1, i + 1),
                None => format!("element {}", i + 1),
            };
            number(item, &at)
        })
        .collect()
}

/// A TOML integer or float as `f64`; integers beyond 2^53 are refused rather
/// than rounded. NaN and infinities pass here and are refused, with their
/// place, when the array is asked for as a matrix.
fn number(value: &Value, at: &str) -> Result<f64, ModelFileErrorKind> {
    match value {
        Value::Float(v) => Ok(*v),
        Value::Integer(i) => Ok(signed_to_f64(&[*i])?[0]),
        other => Err(ModelFileErrorKind::InlineNotANumber {
            at: at.to_string(),
            found: kind_of(other),
        }),
    }
}

fn kind_of(value: &Value) -> &'static str {
    match value {
        Value::String(_) => "a string",
        Value::Integer(_) | Value::Float(_) => "a number",
        Value::Boolean(_) => "a boolean",
        Value::Datetime(_) => "a date",
        Value::Array(_) => "an array",
        Value::Table(_) => "a table",
    }
}
