//! Explain's error and its parallel map: a leaf every part of explain and every effect may
//! import without importing the engine (explain/mod.rs), which imports the effects.

use crate::data::recording::RecordingError;
use crate::numerics::linalg::LinalgError;

/// Errors of explain.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExplainError {
    /// The recording is not usable.
    #[error("{0}")]
    Input(String),
    /// Reading a recording failed.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// A least-squares problem failed.
    #[error("least squares: {0}")]
    Linalg(#[from] LinalgError),
}

/// `f` over `items` on up to the machine's cores (a shared queue: a long item does not hold up
/// the rest), the results in the items' order — as `items.iter().map(f)` gives them when each
/// item's work is its own.
pub(crate) fn in_parallel<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |t| t.get())
        .min(items.len());
    if threads <= 1 {
        return items.iter().map(f).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let slots: Vec<std::sync::Mutex<Option<R>>> =
        items.iter().map(|_| std::sync::Mutex::new(None)).collect();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(item) = items.get(i) else {
                    break;
                };
                let r = f(item);
                *slots[i].lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
            });
        }
    });
    slots
        .into_iter()
        .map(|m| {
            m.into_inner()
                .unwrap_or_else(|e| e.into_inner())
                .expect("every item was worked out (a worker's panic ends the scope first)")
        })
        .collect()
}
