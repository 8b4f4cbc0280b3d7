//! Explain's parallel map over the machine's idle cores: a leaf, like `error`, that every part
//! of explain and every effect may import without importing the engine (explain/mod.rs).

/// Helper threads [`in_parallel`] may still start: the machine's cores less the one every
/// caller runs on. Shared by every call, nested ones included, so a call made inside another
/// call's item gets a core only when one is idle (a worker that ran out of items gives its
/// core back at once): the longest item of a round (a candidate's search) can then use the
/// core the shorter ones left, and the process never runs more threads than cores.
fn spare_cores() -> &'static std::sync::atomic::AtomicUsize {
    static SPARE: std::sync::OnceLock<std::sync::atomic::AtomicUsize> = std::sync::OnceLock::new();
    SPARE.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(1, |t| t.get());
        std::sync::atomic::AtomicUsize::new(cores.saturating_sub(1))
    })
}

/// Up to `want` spare cores taken from [`spare_cores`] (none when all are in use).
fn reserve_cores(want: usize) -> usize {
    use std::sync::atomic::Ordering;
    let spare = spare_cores();
    let mut now = spare.load(Ordering::Relaxed);
    loop {
        let take = now.min(want);
        if take == 0 {
            return 0;
        }
        match spare.compare_exchange_weak(now, now - take, Ordering::AcqRel, Ordering::Relaxed) {
            Ok(_) => return take,
            Err(seen) => now = seen,
        }
    }
}

/// One reserved core, given back when dropped (also when its worker panics).
struct CoreLease;

impl Drop for CoreLease {
    fn drop(&mut self) {
        spare_cores().fetch_add(1, std::sync::atomic::Ordering::AcqRel);
    }
}

/// `f` over `items` on the calling thread and as many helper threads as there are idle cores
/// (see [`spare_cores`]; a shared queue: a long item does not hold up the rest), the results
/// in the items' order — as `items.iter().map(f)` gives them when each item's work is its own
/// (which thread works out an item never changes its result).
pub(crate) fn in_parallel<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    if items.len() <= 1 {
        return items.iter().map(f).collect();
    }
    let helpers = reserve_cores(items.len() - 1);
    let leases: Vec<CoreLease> = (0..helpers).map(|_| CoreLease).collect();
    if leases.is_empty() {
        return items.iter().map(f).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let slots: Vec<std::sync::Mutex<Option<R>>> =
        items.iter().map(|_| std::sync::Mutex::new(None)).collect();
    let work = || loop {
        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let Some(item) = items.get(i) else {
            break;
        };
        let r = f(item);
        *slots[i].lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
    };
    std::thread::scope(|scope| {
        for lease in leases {
            let work = &work;
            scope.spawn(move || {
                work();
                // out of items: the core is free for another call at once
                drop(lease);
            });
        }
        work();
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
