//! Counting the backend's host reads, so a GPU run can show that a training step waits for the
//! device only where it means to (the logged loss). With burn-fusion's `tracing` feature (on
//! with this crate's `host-read-count` feature, which `cuda` turns on, and in the tests), every
//! `float_into_data`, `int_into_data` and `bool_into_data` of the fusion backend — the front of
//! the CUDA and wgpu backends — opens a span; [`HostReadCounter`] counts those spans. Flex has
//! no fusion front, so on the CPU nothing is counted (and nothing needs to be: there is no
//! device to wait for).

use std::cell::Cell;

use tracing::subscriber::Interest;
use tracing::{Metadata, Subscriber, span};
use tracing_subscriber::layer::{Context, Layer};

thread_local! {
    /// Host reads started on this thread: per thread, so tests running side by side in one
    /// process count only their own.
    static READS: Cell<usize> = const { Cell::new(0) };
}

/// A tracing layer that counts host reads of the fusion backend, per thread. It enables read
/// spans alone, so beside another layer it must go through its own filter ([`layer`]): as a
/// plain layer its `never` for every other callsite disables them for the whole subscriber (the
/// `crestereo` log showed nothing at any level that way).
pub struct HostReadCounter;

/// [`HostReadCounter`] behind a per-layer filter of the read spans, to stack beside a log layer.
pub fn layer<S>() -> impl Layer<S>
where
    S: Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    HostReadCounter.with_filter(tracing_subscriber::filter::filter_fn(is_read))
}

fn is_read(meta: &Metadata<'_>) -> bool {
    meta.is_span()
        && meta.target().starts_with("burn_fusion")
        && meta.name().ends_with("_into_data")
}

impl<S: Subscriber> Layer<S> for HostReadCounter {
    fn register_callsite(&self, meta: &'static Metadata<'static>) -> Interest {
        if is_read(meta) {
            Interest::always()
        } else {
            Interest::never()
        }
    }

    fn enabled(&self, meta: &Metadata<'_>, _: Context<'_, S>) -> bool {
        is_read(meta)
    }

    fn on_new_span(&self, attrs: &span::Attributes<'_>, _: &span::Id, _: Context<'_, S>) {
        if is_read(attrs.metadata()) {
            READS.with(|r| r.set(r.get() + 1));
        }
    }
}

/// Host reads counted so far on this thread.
pub fn count() -> usize {
    READS.with(Cell::get)
}

/// Whether the counter sees `B`'s host reads: reads one small tensor and checks that the count
/// moved. False on Flex, and on a fusion backend built without burn-fusion's `tracing` feature.
pub fn visible<B: burn::tensor::backend::Backend>(device: &B::Device) -> bool {
    let probe = burn::tensor::Tensor::<B, 1>::from_floats([1.0, 2.0], device);
    let before = count();
    let _ = probe.into_data();
    count() > before
}
