//! The loop's tunables as Foxglove parameters and back: a tunable's value is
//! TOML (the scenario's), a parameter's is the protocol's number, integer,
//! string, bool or array. A set arrives as a parameter and leaves as the
//! `FIELD=VALUE` text `flexloop set` takes, so both go through one check.

use foxglove::websocket::{Parameter, ParameterValue};

/// A tunable's TOML value as a parameter (`None`: unset in the scenario).
pub fn parameter(field: &str, value: Option<&toml::Value>) -> Parameter {
    Parameter {
        name: field.to_string(),
        r#type: None,
        value: value.and_then(parameter_value),
    }
}

fn parameter_value(value: &toml::Value) -> Option<ParameterValue> {
    Some(match value {
        toml::Value::Float(f) => ParameterValue::Float64(*f),
        toml::Value::Integer(i) => ParameterValue::Integer(*i),
        toml::Value::Boolean(b) => ParameterValue::Bool(*b),
        toml::Value::String(s) => ParameterValue::String(s.clone()),
        toml::Value::Array(items) => {
            ParameterValue::Array(items.iter().filter_map(parameter_value).collect())
        }
        toml::Value::Table(table) => ParameterValue::Dict(
            table
                .iter()
                .filter_map(|(k, v)| Some((k.clone(), parameter_value(v)?)))
                .collect(),
        ),
        toml::Value::Datetime(d) => ParameterValue::String(d.to_string()),
    })
}

/// A parameter's value as the TOML text of `flexloop set FIELD=VALUE`.
pub fn toml_text(name: &str, value: Option<&ParameterValue>) -> Result<String, String> {
    let value = value.ok_or_else(|| format!("{name}: a parameter cannot be unset"))?;
    Ok(toml_value(value).to_string())
}

fn toml_value(value: &ParameterValue) -> toml::Value {
    match value {
        ParameterValue::Integer(i) => toml::Value::Integer(*i),
        ParameterValue::Float64(f) => toml::Value::Float(*f),
        ParameterValue::Bool(b) => toml::Value::Boolean(*b),
        ParameterValue::String(s) => toml::Value::String(s.clone()),
        ParameterValue::Array(items) => toml::Value::Array(items.iter().map(toml_value).collect()),
        ParameterValue::Dict(map) => toml::Value::Table(
            map.iter()
                .map(|(k, v)| (k.clone(), toml_value(v)))
                .collect(),
        ),
    }
}

/// A parameter as a number (`live.rate_hz` may come as an integer).
pub fn number(name: &str, value: Option<&ParameterValue>) -> Result<f64, String> {
    match value {
        Some(ParameterValue::Float64(f)) => Ok(*f),
        Some(ParameterValue::Integer(i)) => Ok(*i as f64),
        _ => Err(format!("{name}: a number is needed")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_go_to_parameters_and_back_to_the_text_set_takes() {
        let cases = [
            ("60.5", "60.5"),
            ("60.0", "60.0"),
            ("12", "12"),
            ("\"modified\"", "\"modified\""),
            ("[900.0, 1200.0]", "[900.0, 1200.0]"),
            ("true", "true"),
        ];
        for (given, expected) in cases {
            let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {given}"))
                .unwrap()
                .remove("v")
                .unwrap();
            let p = parameter("controller.x", Some(&value));
            assert_eq!(
                toml_text("controller.x", p.value.as_ref()).unwrap(),
                expected
            );
        }
        assert_eq!(parameter("controller.y", None).value, None);
        assert!(
            toml_text("controller.y", None)
                .unwrap_err()
                .contains("controller.y")
        );
    }

    #[test]
    fn a_rate_may_be_an_integer_but_not_a_string() {
        assert_eq!(number("r", Some(&ParameterValue::Integer(100))), Ok(100.0));
        assert_eq!(number("r", Some(&ParameterValue::Float64(2.5))), Ok(2.5));
        assert!(number("r", Some(&ParameterValue::String("x".into()))).is_err());
    }
}
