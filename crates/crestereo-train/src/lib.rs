//! Training and evaluation of CREStereo (work in progress: the evaluation metrics come first).
//!
//! - [`metrics`]: the stereo error metrics of the paper and the public benchmarks.
//! - [`schedule`]: the learning-rate schedule (warm-up, constant, linear decay).

pub mod metrics;
pub mod schedule;
