//! What a live swap may change: the fields in which a replacement's file
//! may differ from the running loop's, and those it may not.
//!
//! A swap hands the loop to another design at a sample boundary; a retuned
//! controller shifts its PID integrator there so that its output continues
//! the old command (docs/architecture.md, "What a swap may change"). That
//! makes a change of gains bumpless, but nothing makes a change of the loop
//! itself bumpless: another set-point or loop delay moves the command by
//! whatever the two trajectories differ by, and the plant, the rate and the
//! number of inputs and outputs are not the controller's to change.

use crate::schema::{PlantSection, ReferenceSection, Scenario};

/// Which component a swap replaces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Swapped {
    Controller,
    Observer,
}

/// The fields of `new` (dotted, as the file names them) that a swap of
/// `swapped` from `running` cannot change; empty when the swap may go ahead.
pub fn swap_conflicts(running: &Scenario, new: &Scenario, swapped: Swapped) -> Vec<&'static str> {
    let mut fields = Vec::new();
    let mut check = |field: &'static str, differs: bool| {
        if differs {
            fields.push(field);
        }
    };
    // The plant's clock: the sample period every block was discretised for.
    check("loop.rate_hz", running.timing.rate_hz != new.timing.rate_hz);
    check("loop.mode", running.timing.mode != new.timing.mode);
    // When each command starts to act: the plant's integration and every
    // block's design.
    check(
        "loop.command_deadline_us",
        running.timing.command_deadline_us != new.timing.command_deadline_us,
    );
    // (loop.duration_s is the plant's alone: it ends the run.)
    // The plant runs the measurement the loop started with; a swapped-in
    // file's would not act.
    check("measure", running.measure != new.measure);
    plant_conflicts(&running.plant, &new.plant, &mut check);
    // The same file name next to another scenario is another file, and the
    // same file by another path (relative, absolute) the same.
    let model_file = |s: &Scenario| {
        s.plant_file_path()
            .map(|p| std::fs::canonicalize(&p).unwrap_or(p))
    };
    check("plant.file", model_file(running) != model_file(new));
    reference_conflicts(&running.reference, &new.reference, &mut check);
    // The loop delay: when each command applies, and so the tick the
    // feedforward is issued for and the observer's inputs.
    check(
        "controller.extra_delay_samples",
        running.controller.extra_delay_samples != new.controller.extra_delay_samples,
    );
    // A program's law is its own: what it continues from is its business
    // (its `load` or `shift_output`), and the built-in fields below do not
    // describe it. Between built-in designs:
    let programs = running.controller.exec.is_some() || new.controller.exec.is_some();
    if swapped == Swapped::Controller && new.controller.feedback == "none" && !programs {
        // No integrator to shift: the new command is the feedforward plus
        // the observer's part, whatever the old one was.
        let (a, b) = (&running.controller, &new.controller);
        check("controller.feedback", a.feedback != b.feedback);
        check("controller.feedforward", a.feedforward != b.feedforward);
        check(
            "controller.feedforward_form",
            a.feedforward_form != b.feedforward_form,
        );
    }
    fields
}

fn plant_conflicts(a: &PlantSection, b: &PlantSection, check: &mut impl FnMut(&'static str, bool)) {
    // Every field by name: a field added to the table must be placed here.
    let PlantSection {
        model,
        mass_kg,
        output: _,
        output_given: _,
        nodes,
        encoders,
        sensor_position,
        sensor_scan,
        input_limit,
        seed,
        force_noise,
        sensor_noise,
        reference_noise,
        masses_kg,
        stiffness_n_per_m,
        actuator_node,
        zeta,
        rayleigh,
        springs,
        dampers,
        forces,
        positions,
        file: _,
        arrays,
        // The observer's and the controller's design model: a swap hands
        // over a design made on another (the plant runs what it runs).
        design_file: _,
    } = a;
    check("plant.masses_kg", *masses_kg != b.masses_kg);
    check(
        "plant.stiffness_n_per_m",
        *stiffness_n_per_m != b.stiffness_n_per_m,
    );
    check("plant.actuator_node", *actuator_node != b.actuator_node);
    check("plant.zeta", *zeta != b.zeta);
    check("plant.rayleigh", *rayleigh != b.rayleigh);
    check("plant.springs", *springs != b.springs);
    check("plant.dampers", *dampers != b.dampers);
    check("plant.forces", *forces != b.forces);
    check("plant.positions", *positions != b.positions);
    check("plant.arrays", *arrays != b.arrays);
    check("plant.model", *model != b.model);
    check("plant.mass_kg", *mass_kg != b.mass_kg);
    check("plant.output", effective_output(a) != effective_output(b));
    check("plant.nodes", *nodes != b.nodes);
    check("plant.encoders", *encoders != b.encoders);
    check(
        "plant.sensor_position",
        *sensor_position != b.sensor_position,
    );
    check("plant.sensor_scan", *sensor_scan != b.sensor_scan);
    check("plant.input_limit", *input_limit != b.input_limit);
    check("plant.seed", *seed != b.seed);
    check("plant.force_noise", *force_noise != b.force_noise);
    check("plant.sensor_noise", *sensor_noise != b.sensor_noise);
    check(
        "plant.reference_noise",
        *reference_noise != b.reference_noise,
    );
}

/// `output` as the model reads it (the two-inertia setup defaults to 1).
fn effective_output(p: &PlantSection) -> usize {
    if p.model == "two-inertia" {
        p.two_inertia_output()
    } else {
        p.output
    }
}

fn reference_conflicts(
    a: &ReferenceSection,
    b: &ReferenceSection,
    check: &mut impl FnMut(&'static str, bool),
) {
    let ReferenceSection {
        shape,
        amplitude,
        frequency_hz,
        repeat_s,
        start_s,
        direction: _,
    } = a;
    check("reference.shape", *shape != b.shape);
    check("reference.amplitude", *amplitude != b.amplitude);
    check("reference.frequency_hz", *frequency_hz != b.frequency_hz);
    check("reference.repeat_s", *repeat_s != b.repeat_s);
    check("reference.start_s", *start_s != b.start_s);
    check(
        "reference.direction",
        effective_direction(a) != effective_direction(b),
    );
}

/// `direction` with the default written out as far as it is given: the
/// profile on the first output, 0 on the others.
fn effective_direction(r: &ReferenceSection) -> Vec<f64> {
    let mut d = r.direction.clone().unwrap_or_else(|| vec![1.0]);
    while d.len() > 1 && d.last() == Some(&0.0) {
        d.pop();
    }
    d
}
