//! Integration tests: the real processes, started by the real `flexloop`.
//!
//! Every test gets its own run directory; every `flexloop` supervisor derives
//! its iceoryx2 prefix from its own pid, so tests run in parallel without
//! seeing each other. No test asserts a timing threshold.

mod accounting;
mod bad_input;
mod bench;
mod chaos;
mod design;
mod hangs;
mod live_measure;
mod live_view;
mod loop_processes;
mod measure;
mod mimo;
mod observer_restart;
mod own_components;
mod own_plant;
mod positions;
mod program_matrix;
mod python_component;
mod python_sdk;
mod recording;
mod report;
mod report_measurement;
mod sensor_scan;
mod swap;
mod thesis;
mod tick;
mod tune;
mod util;
mod verdicts;
