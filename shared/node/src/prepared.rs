//! A warm spare's design of the run's scenario, made when the spare starts:
//! an order to serve that same scenario then begins at once instead of
//! designing first (a Kalman design and the PID's tuning take milliseconds,
//! each one a tick or more of held input after a crash at 10 kHz). An order
//! for another file, or for this file changed since, designs as before.

use crate::NodeError;
use crate::args::ServiceArgs;
use flexloop_design::LoopDesign;
use flexloop_scenario::Scenario;
use std::path::PathBuf;

pub struct PreparedDesign {
    path: PathBuf,
    /// The file as it was designed from.
    text: Vec<u8>,
    scenario: Scenario,
    design: LoopDesign,
}

impl PreparedDesign {
    pub fn new(args: &ServiceArgs, scenario: &Scenario, design: &LoopDesign) -> Self {
        Self {
            path: args.scenario.clone(),
            text: std::fs::read(&args.scenario).unwrap_or_default(),
            scenario: scenario.clone(),
            design: design.clone(),
        }
    }

    /// The scenario and design `order` serves: the prepared ones if it names
    /// the same, unchanged file (one read to compare), else designed now.
    pub fn for_order(
        prepared: Option<&Self>,
        order: &ServiceArgs,
    ) -> Result<(Scenario, LoopDesign), NodeError> {
        if let Some(p) = prepared
            && order.scenario == p.path
            && std::fs::read(&order.scenario).is_ok_and(|text| text == p.text)
        {
            return Ok((p.scenario.clone(), p.design.clone()));
        }
        order.load()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_protocol::Joining;

    fn args(scenario: PathBuf) -> ServiceArgs {
        ServiceArgs {
            role: crate::Role::Controller,
            scenario,
            prefix: "p".into(),
            run_dir: ".".into(),
            overrides: Default::default(),
            generation: 0,
            joining: Joining::Spare,
        }
    }

    #[test]
    fn the_prepared_design_serves_an_order_for_the_same_unchanged_file_only() {
        let dir = std::env::temp_dir().join(format!("flexloop-prepared-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let shipped = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenarios/lecture-double-integrator.toml");
        let file = dir.join("loop.toml");
        std::fs::copy(&shipped, &file).unwrap();
        let spare = args(file.clone());
        let (scenario, design) = spare.load().unwrap();
        let mut prepared = PreparedDesign::new(&spare, &scenario, &design);
        // Marked, so that a reuse shows: a fresh design would not carry it.
        prepared.scenario.name = "prepared".into();
        let order = ServiceArgs {
            generation: 1,
            joining: Joining::Restart,
            ..spare.clone()
        };
        let served = PreparedDesign::for_order(Some(&prepared), &order).unwrap();
        assert_eq!(served.0.name, "prepared");
        // Changed since: designed again from the file.
        let text = std::fs::read_to_string(&file).unwrap();
        std::fs::write(&file, format!("{text}\n# edited\n")).unwrap();
        let served = PreparedDesign::for_order(Some(&prepared), &order).unwrap();
        assert_ne!(served.0.name, "prepared");
        // Another file: designed from it.
        let other = ServiceArgs {
            scenario: shipped,
            ..order
        };
        let served = PreparedDesign::for_order(Some(&prepared), &other).unwrap();
        assert_ne!(served.0.name, "prepared");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
