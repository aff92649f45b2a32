//! A latency histogram's summary as the run files keep it: `count`,
//! `p50_ns` … `max_ns` and, where a budget applies, `over_one_period`.

use serde::{Deserialize, Serialize};

/// The six percentiles every table shows, in ns (the order of
/// `flexloop_runtime::latency::QUANTILE_LABELS`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Percentiles {
    #[serde(rename = "p50_ns")]
    pub p50: u64,
    #[serde(rename = "p90_ns")]
    pub p90: u64,
    #[serde(rename = "p99_ns")]
    pub p99: u64,
    #[serde(rename = "p99.9_ns")]
    pub p99_9: u64,
    #[serde(rename = "p99.99_ns")]
    pub p99_99: u64,
    #[serde(rename = "max_ns")]
    pub max: u64,
}

impl Percentiles {
    /// From the values in `QUANTILE_LABELS` order.
    pub fn from_values([p50, p90, p99, p99_9, p99_99, max]: [u64; 6]) -> Self {
        Self {
            p50,
            p90,
            p99,
            p99_9,
            p99_99,
            max,
        }
    }

    /// The values in `QUANTILE_LABELS` order.
    pub fn values(&self) -> [u64; 6] {
        [
            self.p50,
            self.p90,
            self.p99,
            self.p99_9,
            self.p99_99,
            self.max,
        ]
    }
}

/// One histogram: its sample count, percentiles and, for the loop's own
/// latencies, how many samples took longer than one sample period.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Histogram {
    pub count: u64,
    #[serde(flatten)]
    pub percentiles: Percentiles,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub over_one_period: Option<u64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_the_labels_with_ns() {
        let h = Histogram {
            count: 3,
            percentiles: Percentiles::from_values([1, 2, 3, 4, 5, 6]),
            over_one_period: Some(1),
        };
        let v = serde_json::to_value(h).unwrap();
        assert_eq!(v["p99.99_ns"], 5);
        assert_eq!(v["max_ns"], 6);
        assert_eq!(v["over_one_period"], 1);
        let back: Histogram = serde_json::from_value(v).unwrap();
        assert_eq!(back, h);
        let probe = Histogram {
            over_one_period: None,
            ..h
        };
        assert!(
            serde_json::to_value(probe)
                .unwrap()
                .get("over_one_period")
                .is_none()
        );
    }
}
