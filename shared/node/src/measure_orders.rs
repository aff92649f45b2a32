//! The plant's side of a measurement ordered on a running loop
//! (docs/control.md, "Measuring the loop"): it polls the order channel at
//! every tick (no syscall while none comes), designs the excitation on a
//! thread of its own (the crest factor's iterations take milliseconds and
//! allocate: not on the loop thread), which first leaves the plant's real-time
//! priority and CPU (it inherits both, and at the plant's priority on its CPU
//! it would hold the ticks back), and hands it to the plant's core from the
//! first tick it is ready for, no earlier than the order's sample.
//! The measurement's `EXCITING` flag marks the ticks it actually ran.

use crate::NodeError;
use flexloop_components::ScheduledExcitation;
use flexloop_protocol::MeasureOrder;
use flexloop_protocol::channels::MEASURE_ORDER;
use flexloop_scenario::Scenario;
use flexloop_scenario::schema::MeasureSection;
use flexloop_transport::{Inlet, LoopNode};
use std::sync::mpsc::{Receiver, TryRecvError, channel};

/// Made whole on the design thread (its sources hold every segment's
/// period): the loop thread only moves it in.
type Designed = Result<ScheduledExcitation, String>;

pub struct MeasureOrders {
    inlet: Inlet<MeasureOrder>,
    scenario: Scenario,
    /// The plant's CPU, which the design thread leaves.
    loop_cpu: Option<usize>,
    designing: Option<Receiver<Designed>>,
}

impl MeasureOrders {
    pub fn open(
        node: &LoopNode,
        scenario: &Scenario,
        loop_cpu: Option<usize>,
    ) -> Result<Self, NodeError> {
        Ok(Self {
            inlet: Inlet::open_polling(node, &MEASURE_ORDER, MEASURE_ORDER.qos.loop_buffer_size)?,
            scenario: scenario.clone(),
            loop_cpu,
            designing: None,
        })
    }

    /// An excitation to add from tick `k` on, once one ordered is designed.
    pub fn poll(&mut self, k: u64) -> Result<Option<ScheduledExcitation>, NodeError> {
        while let Some(order) = self.inlet.receive()? {
            self.design(*order);
        }
        let Some(designing) = &self.designing else {
            return Ok(None);
        };
        match designing.try_recv() {
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => {
                self.designing = None;
                eprintln!("flexloop-plant: the measurement's design ended without a result");
                Ok(None)
            }
            Ok(designed) => {
                self.designing = None;
                match designed {
                    Ok(mut excitation) => {
                        excitation.start_no_earlier_than(k);
                        Ok(Some(excitation))
                    }
                    Err(e) => {
                        // The supervisor checked the order: this is not expected.
                        eprintln!("flexloop-plant: the measurement ordered cannot be made: {e}");
                        Ok(None)
                    }
                }
            }
        }
    }

    /// Starts the design of `order` (a newer order replaces one not ready yet).
    fn design(&mut self, order: MeasureOrder) {
        let mut scenario = self.scenario.clone();
        let (send, receive) = channel();
        self.designing = Some(receive);
        let loop_cpu = self.loop_cpu;
        std::thread::spawn(move || {
            flexloop_runtime::realtime::step_aside(loop_cpu);
            scenario.measure = Some(MeasureSection::from_order(&order, scenario.timing.rate_hz));
            let designed = scenario
                .measurement_plan()
                .map_err(|e| e.to_string())
                .and_then(|plan| plan.ok_or_else(|| "no plan".to_string()))
                .map(|plan| ScheduledExcitation::new(&plan));
            // The plant may have ended meanwhile: nothing to tell it then.
            let _ = send.send(designed);
        });
    }
}
