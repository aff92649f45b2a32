//! A measurement ordered on the running loop (`flexloop measure --running`,
//! docs/control.md "Measuring the loop"): the request's `[measure]` fields
//! checked against the loop's scenario exactly as a scenario's own
//! `[measure]` is (the same refusals, naming the field), with the start the
//! supervisor chose, and the order the plant runs.

use anyhow::{Context, Result, bail};
use flexloop_protocol::MeasureOrder;
use flexloop_runfiles::supervision::{MeasureOutcome, MeasureRequest};
use flexloop_scenario::Scenario;
use flexloop_scenario::schema::MeasureSection;

/// What the plant is sent and what the events file says of it.
#[derive(Debug, Clone, PartialEq)]
pub struct Planned {
    pub order: MeasureOrder,
    pub outcome: MeasureOutcome,
}

/// The measurement `request` asks for on the loop running `scenario`,
/// starting at sample `start_seq`.
pub fn plan(scenario: &Scenario, request: &MeasureRequest, start_seq: u64) -> Result<Planned> {
    let rate = scenario.timing.rate_hz;
    let mut table = String::from("[measure]\n");
    for change in &request.fields {
        let field = change
            .field
            .strip_prefix("measure.")
            .unwrap_or(&change.field);
        if field == "start_s" {
            bail!(
                "measure.start_s: on a running loop the supervisor starts the measurement \
                 (about 50 ms ahead); leave it out"
            );
        }
        table += &format!("{field} = {}\n", change.value);
    }
    table += &format!("start_s = {}\n", start_seq as f64 / rate);
    let section = MeasureSection::from_table(&table).context("measure")?;
    let mut checked = scenario.clone();
    checked.measure = Some(section.clone());
    checked.validate()?;
    let plan = checked
        .measurement_plan()?
        .expect("a scenario with [measure] has a plan");
    Ok(Planned {
        order: section.order(rate, start_seq),
        outcome: MeasureOutcome {
            table,
            start_seq,
            end_seq: plan.end_tick(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_runfiles::supervision::FieldValue;
    use flexloop_scenario::Overrides;
    use std::path::Path;

    fn scenario() -> Scenario {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
        Scenario::load(&path, &Overrides::default()).unwrap()
    }

    fn request(fields: &[(&str, &str)]) -> MeasureRequest {
        MeasureRequest {
            fields: fields
                .iter()
                .map(|(field, value)| FieldValue {
                    field: field.to_string(),
                    value: value.to_string(),
                })
                .collect(),
        }
    }

    const PLANT_INPUT: [(&str, &str); 4] = [
        ("point", "\"plant-input\""),
        ("f_min_hz", "5"),
        ("measure.f_max_hz", "2000"),
        ("amplitude", "100"),
    ];

    #[test]
    fn a_request_is_ordered_from_the_sample_the_supervisor_chose() {
        let planned = plan(&scenario(), &request(&PLANT_INPUT), 20_000).unwrap();
        assert_eq!(planned.order.start_seq, 20_000);
        assert_eq!(planned.order.period_samples, 2000);
        assert_eq!(planned.outcome.start_seq, 20_000);
        // Two transient, ten measured, one fade-out period.
        assert_eq!(planned.outcome.end_seq, 20_000 + 13 * 2000);
        assert!(planned.outcome.table.contains("start_s = 2\n"));
        // The order names the same measurement again.
        let back = MeasureSection::from_order(&planned.order, 10_000.0);
        assert_eq!(back.start_s, 2.0);
        assert_eq!(back.amplitude, 100.0);
    }

    #[test]
    fn a_request_is_refused_as_a_scenario_would_be_naming_the_field() {
        let refused = |fields: &[(&str, &str)], words: &str| {
            let e = format!(
                "{:#}",
                plan(&scenario(), &request(fields), 1000).unwrap_err()
            );
            assert!(e.contains(words), "{e}");
        };
        let mut above = PLANT_INPUT;
        above[2] = ("f_max_hz", "6000");
        refused(&above, "measure.f_max_hz");
        let mut saturating = PLANT_INPUT;
        saturating[3] = ("amplitude", "1500");
        refused(&saturating, "saturate");
        let mut nowhere = PLANT_INPUT;
        nowhere[0] = ("point", "\"actuator\"");
        refused(&nowhere, "unknown variant `actuator`");
        refused(&PLANT_INPUT[..3], "missing field `amplitude`");
        let mut start = PLANT_INPUT.to_vec();
        start.push(("start_s", "1"));
        refused(&start, "the supervisor starts the measurement");
        // Past the run's end (10 s): a start at 8 s leaves 2 s, it needs 2.6.
        let e = plan(&scenario(), &request(&PLANT_INPUT), 80_000).unwrap_err();
        assert!(format!("{e:#}").contains("loop.duration_s"), "{e:#}");
    }
}
