//! The whole loop in one process, tick by tick, exactly as lockstep mode
//! runs it across processes: the same cores exchanging the same messages.
//!
//! Used to check a design before any process starts, to fit feedforward gains
//! on the model, and by tests that need the loop without IPC.

use crate::observer::ObserverSizeError;
use crate::{ControllerCore, ObserverCore, PlantCore};
use flexloop_design::LoopDesign;
use flexloop_protocol::{Command, Estimate, Measurement};

pub struct InProcessLoop {
    pub plant: PlantCore,
    pub observer: ObserverCore,
    pub controller: ControllerCore,
    /// The messages of the last tick: y(k), the estimate for k+1, u(k).
    pub measurement: Measurement,
    pub estimate: Estimate,
    pub command: Command,
    /// The estimate the controller used at the last tick (for tick k).
    pub used_estimate: Estimate,
    k: u64,
}

impl InProcessLoop {
    pub fn new(design: &LoopDesign) -> Result<Self, ObserverSizeError> {
        let mut observer = ObserverCore::for_design(design)?;
        let mut estimate = Estimate::default();
        observer.initial(&mut estimate);
        Ok(Self {
            plant: PlantCore::new(design),
            observer,
            controller: ControllerCore::new(design, 0),
            measurement: Measurement::default(),
            used_estimate: estimate,
            estimate,
            command: Command::default(),
            k: 0,
        })
    }

    /// The tick the next call to [`tick`](Self::tick) runs.
    pub fn next_tick(&self) -> u64 {
        self.k
    }

    /// One lockstep tick k: the plant applies u(k−1) and publishes y(k), the
    /// controller answers u(k), the observer prepares the estimate for k+1.
    pub fn tick(&mut self) {
        let k = self.k;
        if k > 0 {
            self.plant.offer(&self.command, k, u64::MAX);
        }
        self.plant.tick(k, k, k, false, &mut self.measurement);
        self.plant.advance();
        // Double buffer: the estimate for tick k becomes the used one, and the
        // observer writes the one for k+1 over the buffer two ticks old.
        std::mem::swap(&mut self.used_estimate, &mut self.estimate);
        self.controller
            .step(&self.measurement, &self.used_estimate, &mut self.command);
        self.observer.step(&self.measurement, &mut self.estimate);
        self.k += 1;
    }
}
