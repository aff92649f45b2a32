//! flexloop-plot: self-contained SVG line plots for run reports.
//!
//! - [`axis`] holds the scales (linear, log10, HdrHistogram's log-percentile
//!   axis) and the ticks and labels of each.
//! - [`decimate`] keeps the first, lowest, highest and last point per pixel
//!   column, so that a 100 000-sample trace draws as a few thousand points
//!   and keeps every spike.
//! - [`figure`] renders a figure (lines, markers, reference lines, shaded
//!   spans, event marks, legend) as one `<svg>` element with no external
//!   references, and a stack of figures (a Bode plot) as one as well.
//! - [`xml`] checks that markup is well-formed (for the tests).
//!
//! Offline code: it allocates freely and never runs inside the loop.

pub mod axis;
pub mod decimate;
pub mod figure;
pub mod xml;

pub use axis::{Axis, Scale, Tick};
pub use figure::{Figure, Marker, Marks, RefLine, Series, Span, Stack};
