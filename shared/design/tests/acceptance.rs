//! The one check every command makes (`flexloop design` and `flexloop up`
//! alike): the files `design` used to accept and `up` refused, and the
//! sensor scan's grid at steps whose arithmetic rounds past the chain.

use flexloop_design::acceptance::accept_text;
use flexloop_scenario::Overrides;
use std::path::Path;

fn shipped_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(path).unwrap()
}

/// The field and the message of the refusal of `text`.
fn refusal(text: &str) -> (String, String) {
    let e =
        accept_text(Path::new("bad.toml"), text, &Overrides::default(), 4).expect_err("accepted");
    let message = e.to_string();
    assert!(message.contains("bad.toml"), "{message}");
    (e.field.unwrap_or_default(), message)
}

#[test]
fn the_files_design_accepted_and_up_refused_are_refused_by_the_one_check() {
    // The thesis chain with its sensor on a mass: `design` printed the
    // thesis report without designing the scenario's own loop.
    let default = shipped_text("default");
    for (from, to, field) in [
        (
            "design = \"kalman\"",
            "design = \"magic\"",
            "observer.design",
        ),
        ("shape = \"scan\"", "shape = \"square\"", "reference.shape"),
        (
            "bandwidth_hz = 43.5",
            "bandwidth_hz = 4999",
            "controller.bandwidth_hz",
        ),
        (
            "snap = 1.6704035112986372e-6",
            "snap = 1e300",
            "controller.feedforward.snap",
        ),
    ] {
        assert!(default.contains(from), "{from}");
        let (got, message) = refusal(&default.replacen(from, to, 1));
        assert_eq!(got, field, "{message}");
    }
}

#[test]
fn more_flexible_modes_than_the_chain_has_are_refused() {
    let text = shipped_text("default").replacen(
        "design = \"kalman\"",
        "design = \"kalman\"\nflexible_modes = 100",
        1,
    );
    let (field, message) = refusal(&text);
    assert_eq!(field, "observer.flexible_modes", "{message}");
    assert!(message.contains("cannot keep 100"), "{message}");
}

#[test]
fn a_grid_whose_last_point_rounds_past_the_chain_is_designed() {
    // 7 / 25 · 25 = 7.000000000000001: the last grid point lies past m7 by
    // rounding, which was refused as a position outside [0, 7].
    let scan = shipped_text("thesis-sensor-scan-ad");
    for step in ["0.28", "0.14"] {
        let text = scan.replace(
            "scheduling_step = 0.25",
            &format!("scheduling_step = {step}"),
        );
        if let Err(e) = accept_text(Path::new("scan.toml"), &text, &Overrides::default(), 4) {
            panic!("step {step}: {e}");
        }
    }
}
