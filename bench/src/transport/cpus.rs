//! Which CPUs a measurement runs on, and threads pinned to one.

use anyhow::{Result, ensure};

/// Which CPUs a measurement's subscriber and publishers run on.
#[derive(Clone, Copy)]
pub(super) enum Cpus {
    /// Wherever the scheduler puts them.
    Any,
    Pinned {
        subscriber: usize,
        publisher: usize,
    },
}

/// Runs `work` on a thread that runs on `cpu` alone.
pub(super) fn on_cpu<T: Send>(cpu: usize, work: impl FnOnce() -> Result<T> + Send) -> Result<T> {
    std::thread::scope(|scope| {
        scope
            .spawn(|| {
                pin_to(cpu)?;
                work()
            })
            .join()
            .expect("a pinned bench thread panicked")
    })
}

pub(super) fn pin_to(cpu: usize) -> Result<()> {
    ensure!(
        core_affinity::set_for_current(core_affinity::CoreId { id: cpu }),
        "cannot run on CPU {cpu}"
    );
    Ok(())
}
