//! Checks of the plant a user describes (`plant_description`): which
//! fields each model takes, list lengths, indices and ranges. Whether the
//! structure itself is sound (symmetric, stable, observable) is the
//! design's check, on the assembled matrices.

use crate::limits;
use crate::plant_description::{Attachment, OWN_MODELS};
use crate::{Scenario, ScenarioError};

// A lumped network's masses are two states each, as many as the loop carries.
const _: () = assert!(2 * limits::LUMPED_MASSES_MAX == flexloop_protocol::MAX_STATES);

impl Scenario {
    pub(crate) fn validate_plant_description(&self) -> Result<(), ScenarioError> {
        let p = &self.plant;
        let model = p.model.as_str();
        let chain = model == "thesis-chain";
        let lumped = model == "lumped";
        let from_arrays = model == "second-order" || model == "state-space";
        let refuse = |field: &str, takes: &str| {
            Err(self.err(
                field,
                format!("does not apply to `{model}`: only {takes} take it"),
            ))
        };
        if p.masses_kg.is_some() && !(chain || lumped) {
            return refuse("plant.masses_kg", "`thesis-chain` and `lumped`");
        }
        self.validate_design_file()?;
        if p.stiffness_n_per_m.is_some() && !chain {
            return refuse(
                "plant.stiffness_n_per_m",
                "`thesis-chain` (lumped networks give `springs`)",
            );
        }
        if p.actuator_node.is_some() && !chain {
            return refuse(
                "plant.actuator_node",
                "`thesis-chain` (lumped networks give `forces`)",
            );
        }
        let zeta_models = chain || lumped || model == "uniform-chain" || model == "second-order";
        if p.zeta.is_some() && !zeta_models {
            return refuse(
                "plant.zeta",
                "`thesis-chain`, `uniform-chain`, `lumped` and `second-order` without D \
                 (a state space brings its own damping)",
            );
        }
        if p.rayleigh.is_some() && !(lumped || model == "second-order") {
            return refuse("plant.rayleigh", "`lumped` and `second-order` without D");
        }
        for (field, given) in [
            ("plant.springs", !p.springs.is_empty()),
            ("plant.dampers", !p.dampers.is_empty()),
            ("plant.forces", !p.forces.is_empty()),
            ("plant.positions", !p.positions.is_empty()),
        ] {
            if given && !lumped {
                return refuse(field, "`lumped` networks");
            }
        }
        for (field, given) in [
            ("plant.file", p.file.is_some()),
            ("plant.arrays", p.arrays.is_some()),
        ] {
            if given && !from_arrays {
                return refuse(field, "`second-order` and `state-space`");
            }
        }
        if let Some(zeta) = &p.zeta {
            if zeta.values().is_empty() {
                return Err(self.err("plant.zeta", "one ζ, or one per flexible mode; got []"));
            }
            for z in zeta.values() {
                if !(z.is_finite() && (0.0..1.0).contains(&z)) {
                    return Err(self.err(
                        "plant.zeta",
                        format!("modal damping lies in [0, 1), got {z}"),
                    ));
                }
            }
        }
        if let Some(r) = &p.rayleigh {
            self.within(
                "plant.rayleigh.alpha",
                r.alpha,
                0.0,
                limits::RAYLEIGH_MAX,
                "1/s",
            )?;
            self.within(
                "plant.rayleigh.beta",
                r.beta,
                0.0,
                limits::RAYLEIGH_MAX,
                "s",
            )?;
        }
        if chain {
            self.validate_chain_parameters()?;
        }
        if lumped {
            self.validate_lumped()?;
        }
        if from_arrays {
            match (&p.file, &p.arrays) {
                (None, None) => {
                    return Err(self.err(
                        "plant.file",
                        format!(
                            "`{model}` reads its arrays from a file (.npz, .mat) or from \
                             [plant.arrays]; give one"
                        ),
                    ));
                }
                (Some(_), Some(_)) => {
                    return Err(self.err(
                        "plant.arrays",
                        "give the arrays in plant.file or in [plant.arrays], not both",
                    ));
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn validate_chain_parameters(&self) -> Result<(), ScenarioError> {
        let p = &self.plant;
        if let Some(masses) = &p.masses_kg {
            if masses.len() != 8 {
                return Err(self.err(
                    "plant.masses_kg",
                    format!(
                        "the thesis chain has 8 masses [ma, m1, …, m7], got {}",
                        masses.len()
                    ),
                ));
            }
            self.masses_in_range(masses)?;
        }
        if let Some(springs) = &p.stiffness_n_per_m {
            if springs.len() != 7 {
                return Err(self.err(
                    "plant.stiffness_n_per_m",
                    format!(
                        "the thesis chain has 7 springs (ma–m1, m1–m2, …, m6–m7), got {}",
                        springs.len()
                    ),
                ));
            }
            for &k in springs {
                self.positive_up_to("plant.stiffness_n_per_m", k, limits::STIFFNESS_MAX)?;
            }
        }
        if let Some(node) = p.actuator_node
            && node > 7
        {
            return Err(self.err(
                "plant.actuator_node",
                format!("the chain's nodes are 0 (ma) to 7 (m7), got {node}"),
            ));
        }
        Ok(())
    }

    fn masses_in_range(&self, masses: &[f64]) -> Result<(), ScenarioError> {
        let (lo, hi) = limits::MASS_KG;
        for &m in masses {
            self.within("plant.masses_kg", m, lo, hi, "kg")?;
        }
        Ok(())
    }

    fn validate_lumped(&self) -> Result<(), ScenarioError> {
        let p = &self.plant;
        let Some(masses) = &p.masses_kg else {
            return Err(self.err(
                "plant.masses_kg",
                "a lumped network needs its masses (kg), numbered from 0",
            ));
        };
        if masses.is_empty() || masses.len() > limits::LUMPED_MASSES_MAX {
            return Err(self.err(
                "plant.masses_kg",
                format!(
                    "1 to {} masses (each is two states; the loop carries at most {}), got {}",
                    limits::LUMPED_MASSES_MAX,
                    flexloop_protocol::MAX_STATES,
                    masses.len()
                ),
            ));
        }
        // Each force is one of the loop's inputs, each position one of its
        // outputs: refused here, before the network is assembled and designed.
        for (field, count, max, what) in [
            (
                "plant.forces",
                p.forces.len(),
                flexloop_protocol::MAX_INPUTS,
                "inputs",
            ),
            (
                "plant.positions",
                p.positions.len(),
                flexloop_protocol::MAX_OUTPUTS,
                "outputs",
            ),
        ] {
            if count > max {
                return Err(self.err(
                    field,
                    format!(
                        "{count} entries, each one of the loop's {what}: it carries at most {max}"
                    ),
                ));
            }
        }
        self.masses_in_range(masses)?;
        let n = masses.len();
        let lists: [(&str, Vec<Attachment>); 4] = [
            (
                "plant.springs",
                p.springs.iter().map(|s| s.attachment).collect(),
            ),
            (
                "plant.dampers",
                p.dampers.iter().map(|d| d.attachment).collect(),
            ),
            ("plant.forces", p.forces.clone()),
            ("plant.positions", p.positions.clone()),
        ];
        for (field, attachments) in &lists {
            if attachments.len() > limits::LUMPED_ELEMENTS_MAX {
                return Err(self.err(
                    field,
                    format!(
                        "at most {} entries, got {}",
                        limits::LUMPED_ELEMENTS_MAX,
                        attachments.len()
                    ),
                ));
            }
            for (entry, a) in attachments.iter().enumerate() {
                if let Some(&i) = a.masses().iter().find(|&&i| i >= n) {
                    return Err(self.err(
                        field,
                        format!("entry {entry} names mass {i}; the network has masses 0..{n}"),
                    ));
                }
                if let Attachment::Between(i, j) = a
                    && i == j
                {
                    return Err(self.err(field, format!("entry {entry} joins mass {i} to itself")));
                }
            }
        }
        for s in &p.springs {
            self.positive_up_to("plant.springs", s.stiffness, limits::STIFFNESS_MAX)?;
        }
        for d in &p.dampers {
            self.positive_up_to("plant.dampers", d.damping, limits::DAMPER_MAX)?;
        }
        if p.forces.is_empty() {
            return Err(self.err(
                "plant.forces",
                "a lumped network needs at least one force input: { at = MASS }",
            ));
        }
        if p.positions.is_empty() {
            return Err(self.err(
                "plant.positions",
                "a lumped network needs at least one position output: { at = MASS }",
            ));
        }
        let damping_given = [
            p.zeta.is_some(),
            p.rayleigh.is_some(),
            !p.dampers.is_empty(),
        ];
        match damping_given.iter().filter(|g| **g).count() {
            1 => Ok(()),
            0 => Err(self.err(
                "plant.zeta",
                "a lumped network needs its damping: zeta (modal), rayleigh or dampers",
            )),
            _ => Err(self.err(
                "plant.zeta",
                "give one of zeta, rayleigh and dampers: each sets the whole damping",
            )),
        }
    }

    pub(crate) fn validate_kalman_weights(&self) -> Result<(), ScenarioError> {
        let o = &self.observer;
        // The IO observer with the Kalman gain as its correction is weighted
        // as the Kalman one; with a K(z) of its own only its model is reduced.
        let kalman = o.design == "kalman" || o.correction.as_deref() == Some("observer-based");
        let modal = o.design == "kalman" || o.design == "io";
        if !modal && o.max_mode_hz.is_some() {
            return Err(self.err(
                "observer.max_mode_hz",
                format!(
                    "does not apply: it reduces the model of a `kalman` or `io` observer; the \
                     observer is `{}`",
                    o.design
                ),
            ));
        }
        for (field, given) in [
            ("observer.process_noise", o.process_noise.is_some()),
            ("observer.measurement_noise", o.measurement_noise.is_some()),
            ("observer.kalman_q", o.kalman_q.is_some()),
            ("observer.kalman_r", o.kalman_r.is_some()),
        ] {
            if given && !kalman {
                return Err(self.err(
                    field,
                    format!(
                        "does not apply: it weights a `kalman` observer; the observer is `{}`",
                        o.design
                    ),
                ));
            }
        }
        if o.process_noise.is_some() && o.kalman_q.is_some() {
            return Err(self.err(
                "observer.kalman_q",
                "give observer.process_noise or observer.kalman_q, not both",
            ));
        }
        if o.measurement_noise.is_some() && o.kalman_r.is_some() {
            return Err(self.err(
                "observer.kalman_r",
                "give observer.measurement_noise or observer.kalman_r, not both",
            ));
        }
        if let Some(q) = o.process_noise {
            self.positive_up_to("observer.process_noise", q, limits::FORCE_NOISE_MAX)?;
        }
        if let Some(r) = o.measurement_noise {
            self.positive_up_to("observer.measurement_noise", r, limits::SENSOR_NOISE_MAX)?;
        }
        if let Some(f) = o.max_mode_hz {
            if !OWN_MODELS.contains(&self.plant.model.as_str()) {
                return Err(self.err(
                    "observer.max_mode_hz",
                    format!(
                        "does not apply to `{}`: the built-in models keep \
                         observer.flexible_modes",
                        self.plant.model
                    ),
                ));
            }
            if o.flexible_modes.is_some() {
                return Err(self.err(
                    "observer.max_mode_hz",
                    "give observer.flexible_modes or observer.max_mode_hz, not both",
                ));
            }
            self.positive_up_to("observer.max_mode_hz", f, self.timing.rate_hz / 2.0)?;
        }
        Ok(())
    }
}

impl Scenario {
    /// `plant.design_file` designs the built-in observer and controller:
    /// where neither is designed from the plant model, it would not act.
    fn validate_design_file(&self) -> Result<(), ScenarioError> {
        let Some(file) = &self.plant.design_file else {
            return Ok(());
        };
        let field = "plant.design_file";
        if self.controller.exec.is_some() && self.observer.exec.is_some() {
            return Err(self.err(
                field,
                "designs the built-in observer and controller, and programs of one's own serve \
                 both",
            ));
        }
        if self.plant.sensor_scan.is_some() {
            return Err(self.err(
                field,
                "a scanned sensor's scheduled observer is designed on the thesis chain itself",
            ));
        }
        let known = file
            .extension()
            .is_some_and(|x| x.eq_ignore_ascii_case("npz") || x.eq_ignore_ascii_case("mat"));
        if !known {
            return Err(self.err(
                field,
                format!(
                    "{}: a `state-space` plant file is an .npz or a .mat (docs/own-plant.md)",
                    file.display()
                ),
            ));
        }
        Ok(())
    }
}
