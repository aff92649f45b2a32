//! `observer.design = "io"`: a correction filter that cannot work is refused
//! before any process starts, naming the file or table, the array and why.

use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario};
use std::path::Path;

fn default_text() -> (std::path::PathBuf, String) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    (path, text)
}

/// The default scenario (thesis chain y5, one input, one output) with an
/// `io` observer whose K comes from `[observer.correction_arrays]` `arrays`.
fn with_arrays(arrays: &str) -> (std::path::PathBuf, String) {
    let (path, text) = default_text();
    let text = text
        .replace("design = \"kalman\"", "design = \"io\"")
        .replace(
            "q_nu = 1000.0\ndamping_increase = 0.035\nbandpass_q = 2.0\n",
            &format!("[observer.correction_arrays]\n{arrays}\n"),
        );
    (path, text)
}

fn refusal(path: &Path, text: &str) -> (String, String) {
    let s = Scenario::from_text(path, text, &Overrides::default()).unwrap();
    let e = match LoopDesign::from_scenario(&s) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e,
    };
    (e.field.clone().unwrap_or_default(), e.to_string())
}

#[test]
fn a_static_correction_that_leaves_the_rigid_mode_unstable_is_refused() {
    // D_K alone, innovation to input correction: with the chain's rigid mode
    // a static output feedback cannot stabilise the error, so this is the
    // refusal of an unstable estimation-error loop, named as such.
    let (path, text) = with_arrays("D_K = [[0.5]]");
    let (field, message) = refusal(&path, &text);
    assert_eq!(field, "observer.correction_arrays", "{message}");
    assert!(message.contains("estimation-error loop"), "{message}");
    assert!(message.contains("correction_arrays"), "{message}");
}

#[test]
fn bad_correction_filters_are_refused_with_the_array_and_the_reason() {
    let cases = [
        // Two innovations where the chain has one output.
        ("D_K = [[0.0, 0.0]]", "array `D_K` is 1×2", "1×1"),
        (
            "A_K = [[0.5]]\nB_K = [[1.0]]\nD_K = [[0.0]]",
            "come together",
            "A_K, B_K and C_K",
        ),
        (
            "A_K = [[0.5]]\nB_K = [[1.0, 2.0]]\nC_K = [[1.0]]\nD_K = [[0.0]]",
            "array `B_K` is 1×2",
            "needs 1×1",
        ),
        // An unstable filter.
        (
            "A_K = [[1.5]]\nB_K = [[1.0]]\nC_K = [[1.0]]\nD_K = [[0.0]]\nts = 1e-4",
            "K(z) is unstable",
            "1.5",
        ),
        // A discrete filter at another rate.
        (
            "A_K = [[0.5]]\nB_K = [[1.0]]\nC_K = [[1.0]]\nD_K = [[0.0]]\nts = 1e-3",
            "discrete at 0.001 s",
            "own rate",
        ),
        (
            "L = [[1.0]]\nD_K = [[0.0]]",
            "`L`",
            "not part of a correction filter",
        ),
        ("A_K = [[0.5]]", "array `D_K`: missing", "A_K"),
    ];
    for (arrays, a, b) in cases {
        let (path, text) = with_arrays(arrays);
        let (field, message) = refusal(&path, &text);
        assert_eq!(field, "observer.correction_arrays", "{message}");
        assert!(message.contains(a) && message.contains(b), "{message}");
    }
}

#[test]
fn a_missing_or_empty_correction_file_is_refused_by_name() {
    let (path, text) = default_text();
    let text = text
        .replace("design = \"kalman\"", "design = \"io\"")
        .replace("q_nu = 1000.0\n", "correction_file = \"no-such-k.npz\"\n");
    let (field, message) = refusal(&path, &text);
    assert_eq!(field, "observer.correction_file", "{message}");
    assert!(message.contains("no-such-k.npz"), "{message}");
    // A plant file is not a correction filter: its arrays are named.
    let name = "flexible-joint/k100.npz";
    let text = text.replace("no-such-k.npz", name);
    let (field, message) = refusal(&path, &text);
    assert_eq!(field, "observer.correction_file", "{message}");
    assert!(message.contains(name), "{message}");
    assert!(
        message.contains("`B`, `C`, `K`, `M` are not part of a correction filter"),
        "{message}"
    );
}

#[test]
fn the_flexible_joint_population_is_designed_with_an_io_observer() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
    for name in [
        "flexible-joint",
        "flexible-joint-k080",
        "flexible-joint-k093",
        "flexible-joint-k107",
        "flexible-joint-k120",
    ] {
        let path = dir.join(format!("{name}.toml"));
        let s = Scenario::load(&path, &Overrides::default()).unwrap();
        let d = match LoopDesign::from_scenario(&s) {
            Ok(d) => d,
            Err(e) => panic!("{e}"),
        };
        // Two currents in, two hub angles out; 2 rigid + 2 flexible modes.
        assert_eq!((d.n_inputs, d.output_names.len()), (2, 2), "{name}");
        // The Kalman gain as K: no filter states beyond the model's 8.
        assert_eq!(d.observer.estimate_map.nrows(), 8, "{name}");
    }
}
