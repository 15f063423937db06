//! Judging results: metrics, sequence evaluation, metrics with the reference's own noise taken
//! out, the HTML report, and the data path's throughput.

pub mod bench;
pub mod evaluation;
pub mod metrics;
pub mod reference_noise;
pub mod report;
