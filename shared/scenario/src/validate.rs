//! Checking a parsed scenario: ranges, consistency between sections, and
//! whether this machine can run its real-time profile. The design step
//! (flexloop-design) checks the maths.

use crate::ScenarioError;
use crate::schema::{DEDICATED_CORES_MIN_CPUS, MODELS, Profile, SENSOR_POSITION_MAX, Scenario};

impl Scenario {
    fn err(&self, field: &str, reason: impl Into<String>) -> ScenarioError {
        ScenarioError::new(&self.source, Some(field), reason)
    }

    /// Checks ranges and consistency; the design step checks the maths.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let positive = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(self.err(field, format!("must be a positive finite number, got {v}")))
            }
        };
        let non_negative = |field: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(self.err(field, format!("must be zero or positive, got {v}")))
            }
        };
        positive("loop.rate_hz", self.timing.rate_hz)?;
        if self.timing.rate_hz > 100_000.0 {
            return Err(self.err("loop.rate_hz", "above 100 kHz the tick grid is below 10 µs"));
        }
        non_negative("loop.duration_s", self.timing.duration_s)?;
        positive("plant.mass_kg", self.plant.mass_kg)?;
        positive("plant.input_limit", self.plant.input_limit)?;
        non_negative("plant.force_noise", self.plant.force_noise)?;
        non_negative("plant.sensor_noise", self.plant.sensor_noise)?;
        non_negative("plant.reference_noise", self.plant.reference_noise)?;
        for (field, ticks) in [
            (
                "supervision.command_watchdog_ticks",
                self.supervision.command_watchdog_ticks,
            ),
            (
                "supervision.estimate_watchdog_ticks",
                self.supervision.estimate_watchdog_ticks,
            ),
        ] {
            if ticks == 0 {
                return Err(self.err(field, "must be at least 1 tick"));
            }
        }
        if !MODELS.contains(&self.plant.model.as_str()) {
            return Err(self.err(
                "plant.model",
                format!(
                    "unknown model `{}` (expected one of {})",
                    self.plant.model,
                    MODELS.join(", ")
                ),
            ));
        }
        self.validate_outputs()?;
        if let Some(p) = self.plant.sensor_position {
            let field = "plant.sensor_position";
            if self.plant.model != "thesis-chain" {
                return Err(self.err(
                    field,
                    format!(
                        "only the thesis chain has a sensor position, not `{}`",
                        self.plant.model
                    ),
                ));
            }
            if self.plant.output_given {
                return Err(self.err(
                    field,
                    "give either plant.output or plant.sensor_position, not both \
                     (position 5.0 is output 5)",
                ));
            }
            if !(p.is_finite() && (0.0..=SENSOR_POSITION_MAX).contains(&p)) {
                return Err(self.err(
                    field,
                    format!(
                        "must lie in [0, {SENSOR_POSITION_MAX}] (0 = ma, 1..7 = m1..m7), got {p}"
                    ),
                ));
            }
        }
        if let Some(q) = self.observer.q_nu {
            non_negative("observer.q_nu", q)?;
        }
        self.validate_sensor_scan()?;
        self.validate_profile()?;
        non_negative("observer.damping_increase", self.observer.damping_increase)?;
        if let Some(z) = self.observer.damping_target
            && !(z.is_finite() && z > 0.0 && z < 1.0)
        {
            return Err(self.err(
                "observer.damping_target",
                format!("a modal damping ratio must lie in (0, 1), got {z}"),
            ));
        }
        non_negative("observer.bandpass_q", self.observer.bandpass_q)?;
        positive("controller.bandwidth_hz", self.controller.bandwidth_hz)?;
        for (i, hz) in self.controller.notches_hz.iter().enumerate() {
            positive(&format!("controller.notches_hz[{i}]"), *hz)?;
        }
        if let Some(ff) = &self.controller.feedforward {
            for (field, v) in [
                ("controller.feedforward.snap", ff.snap),
                ("controller.feedforward.jerk", ff.jerk),
                ("controller.feedforward.acc", ff.acc),
                ("controller.feedforward.vel", ff.vel),
            ] {
                if !v.is_finite() {
                    return Err(self.err(field, format!("must be finite, got {v}")));
                }
            }
        }
        positive(
            "observer.observer_bandwidth_hz",
            self.observer.observer_bandwidth_hz,
        )?;
        positive(
            "observer.feedback_bandwidth_hz",
            self.observer.feedback_bandwidth_hz,
        )?;
        positive("observer.observer_damping", self.observer.observer_damping)?;
        positive("observer.feedback_damping", self.observer.feedback_damping)?;
        let nyquist = self.timing.rate_hz / 2.0;
        let notches = self
            .controller
            .notches_hz
            .iter()
            .map(|hz| ("controller.notches_hz", *hz));
        for (field, hz) in [
            (
                "observer.observer_bandwidth_hz",
                self.observer.observer_bandwidth_hz,
            ),
            (
                "observer.feedback_bandwidth_hz",
                self.observer.feedback_bandwidth_hz,
            ),
            ("controller.bandwidth_hz", self.controller.bandwidth_hz),
        ]
        .into_iter()
        .chain(notches)
        {
            if hz >= nyquist {
                return Err(self.err(
                    field,
                    format!("{hz} Hz is not below the Nyquist frequency {nyquist} Hz"),
                ));
            }
        }
        if self.controller.extra_delay_samples > 1 {
            return Err(self.err("controller.extra_delay_samples", "must be 0 or 1"));
        }
        non_negative("reference.amplitude", self.reference.amplitude.abs())?;
        positive("reference.frequency_hz", self.reference.frequency_hz)?;
        non_negative("reference.start_s", self.reference.start_s)?;
        non_negative("reference.repeat_s", self.reference.repeat_s)?;
        if let Some(direction) = &self.reference.direction {
            if let Some((i, v)) = direction.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(self.err(
                    &format!("reference.direction[{i}]"),
                    format!("must be finite, got {v}"),
                ));
            }
            if direction.iter().all(|v| *v == 0.0) {
                return Err(self.err(
                    "reference.direction",
                    "needs at least one non-zero entry (the profile drives no output)",
                ));
            }
        }
        for (field, p) in [
            ("realtime.plant.priority", &self.realtime.plant),
            ("realtime.observer.priority", &self.realtime.observer),
            ("realtime.controller.priority", &self.realtime.controller),
            ("realtime.logger.priority", &self.realtime.logger),
        ] {
            if let Some(prio) = p.priority
                && !(1..=99).contains(&prio)
            {
                return Err(self.err(
                    field,
                    format!("SCHED_FIFO priority must be 1..=99, got {prio}"),
                ));
            }
        }
        Ok(())
    }

    /// A spinning profile needs a CPU of its own for each loop process.
    fn validate_profile(&self) -> Result<(), ScenarioError> {
        let rt = &self.realtime;
        if rt.profile != Profile::DedicatedCores {
            return Ok(());
        }
        let mut taken: Vec<(usize, &str)> = Vec::new();
        for (field, p) in [
            ("realtime.plant.cpu", &rt.plant),
            ("realtime.observer.cpu", &rt.observer),
            ("realtime.controller.cpu", &rt.controller),
        ] {
            let Some(cpu) = p.cpu else {
                return Err(self.err(
                    field,
                    "dedicated-cores spins each loop process on a CPU of its own: name it",
                ));
            };
            if let Some((_, other)) = taken.iter().find(|(c, _)| *c == cpu) {
                return Err(self.err(
                    field,
                    format!("dedicated-cores needs a CPU of its own; {cpu} is also {other}"),
                ));
            }
            taken.push((cpu, field));
        }
        if let Some(cpu) = rt.logger.cpu
            && let Some((_, other)) = taken.iter().find(|(c, _)| *c == cpu)
        {
            return Err(self.err(
                "realtime.logger.cpu",
                format!("CPU {cpu} spins for {other} under dedicated-cores"),
            ));
        }
        Ok(())
    }

    /// Whether this machine can run the scenario's profile: a spinning one
    /// is refused below [`DEDICATED_CORES_MIN_CPUS`] CPUs (three spinning
    /// processes would starve everything else, the logger and the kernel's
    /// own threads included) and on CPUs it does not have.
    pub fn check_machine(&self, online_cpus: usize) -> Result<(), ScenarioError> {
        if self.realtime.profile != Profile::DedicatedCores {
            return Ok(());
        }
        if online_cpus < DEDICATED_CORES_MIN_CPUS {
            return Err(self.err(
                "realtime.profile",
                format!(
                    "dedicated-cores spins plant, observer and controller each on a CPU of its \
                     own and needs at least {DEDICATED_CORES_MIN_CPUS} CPUs; this machine has \
                     {online_cpus}: use shared-cores"
                ),
            ));
        }
        let rt = &self.realtime;
        for (field, p) in [
            ("realtime.plant.cpu", &rt.plant),
            ("realtime.observer.cpu", &rt.observer),
            ("realtime.controller.cpu", &rt.controller),
            ("realtime.logger.cpu", &rt.logger),
        ] {
            if let Some(cpu) = p.cpu.filter(|c| *c >= online_cpus) {
                return Err(self.err(
                    field,
                    format!("CPU {cpu} does not exist here (CPUs 0..{online_cpus})"),
                ));
            }
        }
        Ok(())
    }

    /// A sensor the structure scans past: the thesis chain, a scan, two
    /// positions on it, no other way of placing the sensor.
    fn validate_sensor_scan(&self) -> Result<(), ScenarioError> {
        let o = &self.observer;
        if !matches!(o.scheduling.as_str(), "interpolated" | "time-varying") {
            return Err(self.err(
                "observer.scheduling",
                format!(
                    "unknown scheduling `{}` (expected interpolated or time-varying)",
                    o.scheduling
                ),
            ));
        }
        if !(o.scheduling_step.is_finite() && o.scheduling_step > 0.0 && o.scheduling_step <= 7.0) {
            return Err(self.err(
                "observer.scheduling_step",
                format!("must lie in (0, 7] node units, got {}", o.scheduling_step),
            ));
        }
        let Some([from, to]) = self.plant.sensor_scan else {
            return Ok(());
        };
        let field = "plant.sensor_scan";
        if self.plant.model != "thesis-chain" {
            return Err(self.err(
                field,
                format!(
                    "only the thesis chain has a sensor to scan past, not `{}`",
                    self.plant.model
                ),
            ));
        }
        if self.plant.output_given || self.plant.sensor_position.is_some() {
            return Err(self.err(
                field,
                "give one of plant.output, plant.sensor_position and plant.sensor_scan",
            ));
        }
        for p in [from, to] {
            if !(p.is_finite() && (0.0..=SENSOR_POSITION_MAX).contains(&p)) {
                return Err(self.err(
                    field,
                    format!(
                        "positions must lie in [0, {SENSOR_POSITION_MAX}] (0 = ma, 1..7 = m1..m7), got {p}"
                    ),
                ));
            }
        }
        if from == to {
            return Err(self.err(
                field,
                format!("the sensor does not move ({from} to {to}): use plant.sensor_position"),
            ));
        }
        if self.reference.shape != "scan" {
            return Err(self.err(
                field,
                format!(
                    "the sensor follows a scan; reference.shape is `{}`",
                    self.reference.shape
                ),
            ));
        }
        if self.controller.feedforward_form == "modified" {
            return Err(self.err(
                "controller.feedforward_form",
                "the modified feedforward copies a fixed observer; with plant.sensor_scan \
                 use `plain`",
            ));
        }
        Ok(())
    }

    /// Which sensors the model reads: `output`, `sensor_position` and
    /// `encoders` each belong to one model.
    fn validate_outputs(&self) -> Result<(), ScenarioError> {
        let model = self.plant.model.as_str();
        let output = self.plant.output;
        match model {
            "two-inertia" => {
                if !(1..=2).contains(&output) {
                    return Err(self.err(
                        "plant.output",
                        format!("the two-inertia setup measures θ1 (1) or θ2 (2), got {output}"),
                    ));
                }
            }
            "uniform-chain" => {
                if self.plant.output_given {
                    return Err(self.err(
                        "plant.output",
                        "the uniform chain has one sensor, at 5/7 of its length",
                    ));
                }
            }
            "mimo-example" | "oat-like" => {
                if self.plant.output_given {
                    return Err(self.err(
                        "plant.output",
                        format!(
                            "`{model}` measures all its sensors; reference.direction says \
                             which outputs the reference moves"
                        ),
                    ));
                }
            }
            _ => {
                if !(1..=7).contains(&output) {
                    return Err(self.err(
                        "plant.output",
                        format!("the chain has outputs 1..=7, got {output}"),
                    ));
                }
            }
        }
        let nodes_range = flexloop_control::models::UNIFORM_CHAIN_NODES;
        match (model, self.plant.nodes) {
            ("uniform-chain", None) => {
                return Err(self.err(
                    "plant.nodes",
                    format!(
                        "the uniform chain needs its number of masses ({} to {})",
                        nodes_range.start(),
                        nodes_range.end()
                    ),
                ));
            }
            ("uniform-chain", Some(n)) if !nodes_range.contains(&n) => {
                return Err(self.err(
                    "plant.nodes",
                    format!(
                        "must lie in {}..={} (2·nodes states; the loop carries at most {} \
                         observer states), got {n}",
                        nodes_range.start(),
                        nodes_range.end(),
                        flexloop_protocol::MAX_STATES
                    ),
                ));
            }
            ("uniform-chain", Some(_)) | (_, None) => {}
            (_, Some(_)) => {
                return Err(self.err(
                    "plant.nodes",
                    format!("only the uniform chain has a number of nodes, not `{model}`"),
                ));
            }
        }
        if let Some(encoders) = &self.plant.encoders {
            let field = "plant.encoders";
            if model != "oat-like" {
                return Err(self.err(
                    field,
                    format!("only the OAT-like model selects encoders, not `{model}`"),
                ));
            }
            let mut sorted = encoders.clone();
            sorted.sort_unstable();
            sorted.dedup();
            if encoders.len() != 3
                || sorted.len() != 3
                || sorted.iter().any(|e| !(1..=4).contains(e))
            {
                return Err(self.err(
                    field,
                    format!("three different encoders of 1..=4, got {encoders:?}"),
                ));
            }
        }
        Ok(())
    }
}
