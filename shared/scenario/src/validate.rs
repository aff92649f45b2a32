//! Checking a parsed scenario: ranges, consistency between sections, and
//! whether this machine can run its real-time profile. The design step
//! (flexloop-design) checks the maths.

use crate::error::number;
use crate::schema::{DEDICATED_CORES_MIN_CPUS, MODELS, Profile, SENSOR_POSITION_MAX, Scenario};
use crate::{ScenarioError, limits};

impl Scenario {
    /// `loop.command_deadline_us`: inside the period, and only where the
    /// loop can use it (docs/deadline.md); what the design cannot
    /// use it for (the model, the observer) the design step refuses.
    fn validate_command_deadline(&self) -> Result<(), ScenarioError> {
        let Some(deadline) = self.timing.command_deadline_us else {
            return Ok(());
        };
        let field = "loop.command_deadline_us";
        let period_us = 1e6 / self.timing.rate_hz;
        if !(deadline.is_finite() && deadline > 0.0 && deadline < period_us) {
            return Err(self.err(
                field,
                format!(
                    "must lie strictly between 0 and the sample period {} µs, got {}",
                    number(period_us),
                    number(deadline)
                ),
            ));
        }
        if self.controller.extra_delay_samples > 0 {
            return Err(self.err(
                field,
                "a command applied on arrival cannot also wait an extra sample: \
                 remove controller.extra_delay_samples or the deadline",
            ));
        }
        Ok(())
    }

    pub(crate) fn err(&self, field: &str, reason: impl Into<String>) -> ScenarioError {
        ScenarioError::new(&self.source, Some(field), reason)
    }

    /// Checks ranges and consistency; the design step checks the maths.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        self.validate_name()?;
        // The rate first: the deadline is judged against its period.
        let (rate_min, rate_max) = limits::RATE_HZ;
        self.within(
            "loop.rate_hz",
            self.timing.rate_hz,
            rate_min,
            rate_max,
            "Hz",
        )?;
        self.validate_command_deadline()?;
        self.validate_program()?;
        self.validate_measure()?;
        self.within(
            "loop.duration_s",
            self.timing.duration_s,
            0.0,
            limits::DURATION_S_MAX,
            "s (0 runs until stopped)",
        )?;
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
        self.validate_names()?;
        self.validate_applicability()?;
        if self.observer.ad && self.observer.flexible_modes == Some(0) {
            return Err(self.err(
                "observer.flexible_modes",
                "0 leaves active damping (observer.ad) no mode to act on: estimate at least \
                 one flexible mode, or turn AD off",
            ));
        }
        self.validate_plant_description()?;
        self.validate_kalman_weights()?;
        self.validate_correction()?;
        let (mass_min, mass_max) = limits::MASS_KG;
        self.within(
            "plant.mass_kg",
            self.plant.mass_kg,
            mass_min,
            mass_max,
            "kg",
        )?;
        self.positive_up_to(
            "plant.input_limit",
            self.plant.input_limit,
            limits::INPUT_LIMIT_MAX,
        )?;
        self.within(
            "plant.force_noise",
            self.plant.force_noise,
            0.0,
            limits::FORCE_NOISE_MAX,
            "N",
        )?;
        self.within(
            "plant.sensor_noise",
            self.plant.sensor_noise,
            0.0,
            limits::SENSOR_NOISE_MAX,
            "m",
        )?;
        self.within(
            "plant.reference_noise",
            self.plant.reference_noise,
            0.0,
            limits::SENSOR_NOISE_MAX,
            "m",
        )?;
        for (field, ticks) in [
            (
                "supervision.command_watchdog_ticks",
                self.supervision.command_watchdog_ticks,
            ),
            (
                "supervision.estimate_watchdog_ticks",
                self.supervision.estimate_watchdog_ticks,
            ),
            ("supervision.silent_ticks", self.supervision.silent_ticks),
        ] {
            if !(1..=limits::WATCHDOG_TICKS_MAX).contains(&ticks) {
                return Err(self.err(
                    field,
                    format!(
                        "must lie in 1..={} ticks, got {ticks}",
                        limits::WATCHDOG_TICKS_MAX
                    ),
                ));
            }
        }
        if self.supervision.max_restarts > limits::MAX_RESTARTS_MAX {
            return Err(self.err(
                "supervision.max_restarts",
                format!(
                    "at most {}, got {}",
                    limits::MAX_RESTARTS_MAX,
                    self.supervision.max_restarts
                ),
            ));
        }
        if self.supervision.restart_backoff_ms > limits::RESTART_BACKOFF_MS_MAX {
            return Err(self.err(
                "supervision.restart_backoff_ms",
                format!(
                    "at most {} ms, got {}",
                    limits::RESTART_BACKOFF_MS_MAX,
                    self.supervision.restart_backoff_ms
                ),
            ));
        }
        if self.realtime.timer_slack_ns > limits::TIMER_SLACK_NS_MAX {
            return Err(self.err(
                "realtime.timer_slack_ns",
                format!(
                    "at most {} ns (a slack beyond the tick defeats the clock), got {}",
                    limits::TIMER_SLACK_NS_MAX,
                    self.realtime.timer_slack_ns
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
                        "must lie in [0, {SENSOR_POSITION_MAX}] (0 = ma, 1..7 = m1..m7), got {}",
                        number(p)
                    ),
                ));
            }
        }
        if let Some(q) = self.observer.q_nu {
            self.within("observer.q_nu", q, 0.0, limits::Q_NU_MAX, "")?;
        }
        self.validate_sensor_scan()?;
        self.validate_tick()?;
        self.validate_profile()?;
        self.within(
            "observer.damping_increase",
            self.observer.damping_increase,
            0.0,
            1.0,
            "",
        )?;
        if let Some(z) = self.observer.damping_target
            && !(z.is_finite() && z > 0.0 && z < 1.0)
        {
            return Err(self.err(
                "observer.damping_target",
                format!(
                    "a modal damping ratio must lie in (0, 1), got {}",
                    number(z)
                ),
            ));
        }
        self.within(
            "observer.bandpass_q",
            self.observer.bandpass_q,
            0.0,
            limits::BANDPASS_Q_MAX,
            "",
        )?;
        let nyquist = self.timing.rate_hz / 2.0;
        // "auto" is resolved by the design (flexloop-design's pid_bandwidth).
        if let Some(hz) = self.controller.bandwidth_hz.hz() {
            self.positive_up_to("controller.bandwidth_hz", hz, f64::MAX)?;
        }
        if self.controller.notches_hz.len() > limits::NOTCHES_MAX {
            return Err(self.err(
                "controller.notches_hz",
                format!(
                    "at most {} notches, got {}",
                    limits::NOTCHES_MAX,
                    self.controller.notches_hz.len()
                ),
            ));
        }
        for (i, hz) in self.controller.notches_hz.iter().enumerate() {
            self.positive_up_to(&format!("controller.notches_hz[{i}]"), *hz, f64::MAX)?;
        }
        if let Some(ff) = &self.controller.feedforward {
            for (field, v) in [
                ("controller.feedforward.snap", ff.snap),
                ("controller.feedforward.jerk", ff.jerk),
                ("controller.feedforward.acc", ff.acc),
                ("controller.feedforward.vel", ff.vel),
            ] {
                let max = limits::FEEDFORWARD_GAIN_MAX;
                self.within(field, v.abs(), 0.0, max, "in absolute value")
                    .map_err(|_| {
                        self.err(
                            field,
                            format!(
                                "must lie in [-{}, {}], got {}",
                                number(max),
                                number(max),
                                number(v)
                            ),
                        )
                    })?;
            }
        }
        for (field, v) in [
            (
                "observer.observer_bandwidth_hz",
                self.observer.observer_bandwidth_hz,
            ),
            (
                "observer.feedback_bandwidth_hz",
                self.observer.feedback_bandwidth_hz,
            ),
        ] {
            self.positive_up_to(field, v, f64::MAX)?;
        }
        for (field, v) in [
            ("observer.observer_damping", self.observer.observer_damping),
            ("observer.feedback_damping", self.observer.feedback_damping),
        ] {
            self.positive_up_to(field, v, limits::POLE_DAMPING_MAX)?;
        }
        let notches = self
            .controller
            .notches_hz
            .iter()
            .map(|hz| ("controller.notches_hz", *hz));
        // The pole bandwidths act on the state-feedback design only: their
        // defaults must not refuse a slow loop that does not use them.
        let poles = self.observer.design == "state-feedback";
        for (field, hz) in [
            (
                "observer.observer_bandwidth_hz",
                self.observer.observer_bandwidth_hz,
            ),
            (
                "observer.feedback_bandwidth_hz",
                self.observer.feedback_bandwidth_hz,
            ),
        ]
        .into_iter()
        .filter(|_| poles)
        .chain([("reference.frequency_hz", self.reference.frequency_hz)])
        .chain(
            self.controller
                .bandwidth_hz
                .hz()
                .map(|hz| ("controller.bandwidth_hz", hz)),
        )
        .chain(notches)
        {
            if hz >= nyquist {
                return Err(self.err(
                    field,
                    format!(
                        "{} Hz is not below the Nyquist frequency {} Hz",
                        number(hz),
                        number(nyquist)
                    ),
                ));
            }
        }
        if self.controller.extra_delay_samples > 1 {
            return Err(self.err("controller.extra_delay_samples", "must be 0 or 1"));
        }
        let amplitude = self.reference.amplitude;
        if !(amplitude.is_finite() && amplitude.abs() <= limits::AMPLITUDE_MAX) {
            return Err(self.err(
                "reference.amplitude",
                format!(
                    "must lie in [-{max}, {max}] m (or rad), got {}",
                    number(amplitude),
                    max = limits::AMPLITUDE_MAX
                ),
            ));
        }
        self.positive_up_to(
            "reference.frequency_hz",
            self.reference.frequency_hz,
            f64::MAX,
        )?;
        self.within(
            "reference.start_s",
            self.reference.start_s,
            0.0,
            limits::DURATION_S_MAX,
            "s",
        )?;
        self.within(
            "reference.repeat_s",
            self.reference.repeat_s,
            0.0,
            limits::DURATION_S_MAX,
            "s",
        )?;
        if let Some(direction) = &self.reference.direction {
            if direction.len() > flexloop_protocol::MAX_OUTPUTS {
                return Err(self.err(
                    "reference.direction",
                    format!(
                        "has {} entries; the loop carries at most {} outputs",
                        direction.len(),
                        flexloop_protocol::MAX_OUTPUTS
                    ),
                ));
            }
            for (i, v) in direction.iter().enumerate() {
                self.within(
                    &format!("reference.direction[{i}]"),
                    v.abs(),
                    0.0,
                    limits::DIRECTION_MAX,
                    "in absolute value",
                )?;
            }
            if direction.iter().all(|v| *v == 0.0) {
                return Err(self.err(
                    "reference.direction",
                    "needs at least one non-zero entry (the profile drives no output)",
                ));
            }
        }
        for (field, p) in [
            ("realtime.plant", &self.realtime.plant),
            ("realtime.observer", &self.realtime.observer),
            ("realtime.controller", &self.realtime.controller),
            ("realtime.logger", &self.realtime.logger),
        ] {
            if let Some(prio) = p.priority
                && !(1..=99).contains(&prio)
            {
                return Err(self.err(
                    &format!("{field}.priority"),
                    format!("SCHED_FIFO priority must be 1..=99, got {prio}"),
                ));
            }
            if let Some(cpu) = p.cpu
                && cpu > limits::CPU_MAX
            {
                return Err(self.err(
                    &format!("{field}.cpu"),
                    format!("CPUs are numbered 0..={}, got {cpu}", limits::CPU_MAX),
                ));
            }
        }
        Ok(())
    }

    /// The named choices are known ones (before the fields they govern are
    /// judged by them).
    fn validate_names(&self) -> Result<(), ScenarioError> {
        for (field, value, known) in [
            (
                "observer.design",
                self.observer.design.as_str(),
                &["state-feedback", "kalman", "io", "none"][..],
            ),
            (
                "observer.correction",
                self.observer
                    .correction
                    .as_deref()
                    .unwrap_or("observer-based"),
                &["observer-based"][..],
            ),
            (
                "controller.feedback",
                self.controller.feedback.as_str(),
                &["pid", "none"][..],
            ),
            (
                "controller.feedforward_form",
                self.controller.feedforward_form.as_str(),
                &["plain", "modified"][..],
            ),
            (
                "reference.shape",
                self.reference.shape.as_str(),
                &["hold", "step", "sine", "scan"][..],
            ),
        ] {
            if !known.contains(&value) {
                return Err(self.err(
                    field,
                    format!("unknown `{value}` (expected one of {})", known.join(", ")),
                ));
            }
        }
        Ok(())
    }

    /// `v` in [lo, hi] and finite, else an error naming the range.
    pub(crate) fn within(
        &self,
        field: &str,
        v: f64,
        lo: f64,
        hi: f64,
        unit: &str,
    ) -> Result<(), ScenarioError> {
        if v.is_finite() && (lo..=hi).contains(&v) {
            return Ok(());
        }
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        Err(self.err(
            field,
            format!(
                "must lie in [{}, {}]{unit}, got {}",
                number(lo),
                number(hi),
                number(v)
            ),
        ))
    }

    /// `v` in (0, hi] and finite.
    pub(crate) fn positive_up_to(&self, field: &str, v: f64, hi: f64) -> Result<(), ScenarioError> {
        if v.is_finite() && v > 0.0 && v <= hi {
            return Ok(());
        }
        let reason = if hi == f64::MAX {
            format!("must be a positive finite number, got {}", number(v))
        } else {
            format!("must lie in (0, {}], got {}", number(hi), number(v))
        };
        Err(self.err(field, reason))
    }

    /// The name names the run directory: one plain path component.
    fn validate_name(&self) -> Result<(), ScenarioError> {
        let name = &self.name;
        let plain = !name.is_empty()
            && name != "."
            && name != ".."
            && name.len() <= limits::NAME_BYTES_MAX
            && !name
                .chars()
                .any(|c| c == '/' || c == '\\' || c.is_control());
        if plain {
            return Ok(());
        }
        Err(self.err(
            "name",
            format!(
                "names the run directory: one plain path component of 1 to {} bytes, \
                 without `/`, `\\` or control characters, not `.` or `..`; got {name:?}",
                limits::NAME_BYTES_MAX
            ),
        ))
    }

    /// A field the file gives must act: one that the model, the observer's
    /// design, the feedback, the reference's shape or the restart policy at
    /// hand does not use is refused, naming it (a setting silently ignored
    /// would make the run something other than the file says).
    fn validate_applicability(&self) -> Result<(), ScenarioError> {
        let model = self.plant.model.as_str();
        let o = &self.observer;
        // The IO observer runs on the Kalman design's reduced model, with its
        // MC and AD; with `correction = "observer-based"` also its weights.
        let modal = o.design == "kalman" || o.design == "io";
        let kalman = o.design == "kalman" || o.correction.as_deref() == Some("observer-based");
        let shape = self.reference.shape.as_str();
        let rules: [(&[&str], bool, String); 10] = [
            (
                &["plant.mass_kg"],
                model == "double-integrator",
                format!("only the double integrator has a mass to give; `{model}` brings its own"),
            ),
            (
                &["plant.output"],
                model != "double-integrator",
                "the double integrator has one output; there is none to choose".into(),
            ),
            (
                &[
                    "observer.observer_bandwidth_hz",
                    "observer.observer_damping",
                    "observer.feedback_bandwidth_hz",
                    "observer.feedback_damping",
                ],
                o.design == "state-feedback",
                format!(
                    "poles of the `state-feedback` design; the observer is `{}`",
                    o.design
                ),
            ),
            (
                &["observer.mc", "observer.ad", "observer.flexible_modes"],
                modal,
                format!(
                    "acts on a `kalman` or `io` observer; the observer is `{}`",
                    o.design
                ),
            ),
            (
                &["observer.q_nu"],
                kalman && o.mc,
                "the noise model is part of the Kalman model's MC: it needs mc = true and \
                 design = \"kalman\" (or \"io\" with correction = \"observer-based\")"
                    .into(),
            ),
            (
                &[
                    "observer.damping_increase",
                    "observer.damping_target",
                    "observer.bandpass_q",
                ],
                modal && o.ad,
                "tunes active damping: it needs design = \"kalman\" or \"io\" and ad = true".into(),
            ),
            (
                &[
                    "observer.correction",
                    "observer.correction_file",
                    "observer.correction_arrays",
                ],
                o.design == "io",
                format!(
                    "the correction filter of an `io` observer; the observer is `{}`",
                    o.design
                ),
            ),
            (
                &["observer.scheduling", "observer.scheduling_step"],
                self.plant.sensor_scan.is_some(),
                "schedules the observer on a scanned sensor: it needs plant.sensor_scan".into(),
            ),
            (
                &["controller.bandwidth_hz", "controller.notches_hz"],
                self.controller.feedback == "pid",
                format!(
                    "tunes the PID; controller.feedback is `{}`",
                    self.controller.feedback
                ),
            ),
            (
                &["supervision.max_restarts", "supervision.restart_backoff_ms"],
                self.supervision.restart == crate::schema::RestartPolicy::OnCrash,
                "acts on restarts; supervision.restart is `never`".into(),
            ),
        ];
        for (fields, applies, why) in rules {
            if let Some(field) = fields.iter().find(|f| !applies && self.given.contains(**f)) {
                return Err(self.err(field, format!("does not apply: {why}")));
            }
        }
        let reference = [
            ("reference.amplitude", shape != "hold"),
            ("reference.start_s", shape != "hold"),
            ("reference.direction", shape != "hold"),
            ("reference.frequency_hz", shape == "sine"),
            ("reference.repeat_s", shape == "scan"),
        ];
        if let Some((field, _)) = reference
            .iter()
            .find(|(f, applies)| !applies && self.given.contains(*f))
        {
            return Err(self.err(
                field,
                format!("does not apply to reference.shape `{shape}`"),
            ));
        }
        let p = &self.plant;
        let noisy = p.force_noise != 0.0 || p.sensor_noise != 0.0 || p.reference_noise != 0.0;
        if !noisy && self.given.contains("plant.seed") {
            return Err(self.err(
                "plant.seed",
                "does not apply: it seeds the disturbances, and every noise is 0",
            ));
        }
        let gains = ["snap", "jerk", "acc", "vel"].map(|g| format!("controller.feedforward.{g}"));
        if shape == "hold"
            && let Some(field) = gains.iter().find(|f| self.given.contains(*f))
        {
            return Err(self.err(
                field,
                "does not apply: the feedforward acts on the reference's derivatives, and \
                 reference.shape `hold` has none",
            ));
        }
        if !self.logger.enabled
            && let Some(field) = ["realtime.logger.priority", "realtime.logger.cpu"]
                .iter()
                .find(|f| self.given.contains(**f))
        {
            return Err(self.err(field, "does not apply: logger.enabled is false"));
        }
        if o.damping_target.is_some() && self.given.contains("observer.damping_increase") {
            return Err(self.err(
                "observer.damping_increase",
                "does not apply: observer.damping_target replaces it; give one of the two",
            ));
        }
        Ok(())
    }

    /// The IO observer's correction filter: exactly one source, a known
    /// construction, and a plant it can run on.
    fn validate_correction(&self) -> Result<(), ScenarioError> {
        let o = &self.observer;
        let sources = [
            ("observer.correction", o.correction.is_some()),
            ("observer.correction_file", o.correction_file.is_some()),
            ("observer.correction_arrays", o.correction_arrays.is_some()),
        ];
        if o.design != "io" {
            return match sources.iter().find(|(_, given)| *given) {
                Some((field, _)) => Err(self.err(
                    field,
                    format!(
                        "does not apply: the correction filter of an `io` observer; the \
                         observer is `{}`",
                        o.design
                    ),
                )),
                None => Ok(()),
            };
        }
        let given: Vec<&str> = sources
            .iter()
            .filter(|(_, given)| *given)
            .map(|(field, _)| *field)
            .collect();
        match given.as_slice() {
            [_] => {}
            // A program of one's own is the observer, correction included.
            [] if o.exec.is_some() => {}
            [] => {
                return Err(self.err(
                    "observer.correction",
                    "an `io` observer needs its correction filter K(z): correction = \
                     \"observer-based\", correction_file or [observer.correction_arrays]",
                ));
            }
            [_, second, ..] => {
                return Err(self.err(
                    second,
                    format!("give one of {}, not several", given.join(", ")),
                ));
            }
        }
        if self.plant.sensor_scan.is_some() {
            return Err(self.err(
                "observer.design",
                "the observer scheduled on a scanned sensor is a Kalman one: use design = \
                 \"kalman\" with plant.sensor_scan",
            ));
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
        let rt = &self.realtime;
        // Under shared-cores a pin is best effort (a process reports a CPU
        // it could not have and runs anywhere).
        if rt.profile != Profile::DedicatedCores {
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
        let (step_min, step_max) = limits::SCHEDULING_STEP;
        self.within(
            "observer.scheduling_step",
            o.scheduling_step,
            step_min,
            step_max,
            "node units",
        )?;
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
                        "positions must lie in [0, {SENSOR_POSITION_MAX}] (0 = ma, 1..7 = m1..m7), got {}",
                        number(p)
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
            "lumped" | "second-order" | "state-space" => {
                if self.plant.output_given {
                    return Err(self.err(
                        "plant.output",
                        format!(
                            "`{model}` measures the outputs its model defines; \
                             reference.direction says which the reference moves"
                        ),
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
